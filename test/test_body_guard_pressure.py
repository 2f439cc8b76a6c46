"""The self-collision guard under pressure: live parameter changes, fast motion past thin parts.

Every command is checked here, with the body model's own clearance queries at the commands and
at points of the straight step between two commands: nothing within the margin in force before
a change (less the braking tolerance), and no velocity change beyond the acceleration limit.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from audio2pose_ros.motion.body_guard import TOLERANCE_M, BodyGuard
from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings
from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.robot.body import BodyModel

PERIOD = 0.01
STEP_POINTS = np.linspace(0.0, 1.0, 6)[1:-1, None]  # points of the step between two commands
SLACK = 1e-9  # rounding allowance of the acceleration check (rad/s)


@pytest.fixture(scope="module")
def body():
    return BodyModel.load()


def step_clearance(body, previous, command):
    """Smallest clearance at the command and at points of the straight step to it."""
    points = np.vstack([previous + STEP_POINTS * (command - previous), command])
    return float(body.clearance(points).min())


def sweep_between(robot, a, b, ticks):
    """Raw poses moving back and forth between ``a`` and ``b``, ``ticks`` ticks each way."""
    phase = np.arange(8 * ticks) % (2 * ticks) / ticks
    fraction = np.where(phase <= 1.0, phase, 2.0 - phase)[:, None]
    return a + fraction * (b - a)


# Pairs of poses, each clear of the body by more than the margin, whose straight way passes a
# thin part of it (a gripper, a wrist, the bicep's edge): found by a seeded search of random
# pose pairs whose path enters the body for a short stretch only.
THIN_PASSES = [
    (
        [0.28, 0.51, 0.31, 2.0, -1.46, 1.04, -0.82, 0.96, 0.49, 1.83, -0.3],
        [-0.51, -0.73, 0.39, -0.31, -0.44, -1.87, -0.35, 1.58, 0.13, 1.01, 0.11],
        12,
    ),
    (
        [-0.38, -0.86, 0.41, 1.78, -1.47, 1.01, -0.84, 1.0, 1.23, -0.51, 0.03],
        [0.07, -0.14, 0.37, -1.87, -1.07, -1.25, -0.79, -1.5, 1.07, -0.44, -0.14],
        12,
    ),
    (
        [-0.69, 0.1, 0.22, 1.74, -0.7, 0.41, -1.16, 0.72, 1.29, -0.0, 0.39],
        [0.3, -0.49, 0.52, -1.07, -0.71, -1.66, -0.91, -0.14, 1.4, -1.46, 0.25],
        8,
    ),
    (
        [0.15, -1.37, 0.71, -0.82, -0.58, -0.64, -0.31, -0.23, 0.75, 0.83, 0.15],
        [-0.44, -0.34, 0.59, 0.28, -0.54, -0.38, -0.26, 1.87, 1.15, -1.28, -0.17],
        8,
    ),
    (
        [-0.09, 1.59, 0.37, -0.43, -1.46, 1.98, -0.71, 1.64, 1.35, 0.3, 0.49],
        [-0.48, -1.83, 1.21, 1.78, -0.43, 0.48, -0.29, -1.62, 1.42, 0.61, -0.27],
        12,
    ),
]


@pytest.mark.parametrize(("a", "b", "ticks"), THIN_PASSES)
def test_when_fast_alternation_passes_a_thin_part_expect_braking_within_the_acceleration_limit(
    body, a, b, ticks
):
    """Raw poses alternate fast between two clear poses; the straight way between them passes
    a thin part of the body. The arm must brake in time: every command within the acceleration
    limit (the last-resort hold stopped it in one command, up to 17 times the limit), no hold,
    no command and no step between two inside the margin."""
    robot = body.robot
    a, b = np.array(a), np.array(b)
    assert min(body.clearance(a), body.clearance(b)) > 0.025
    assert body.clearance(a + np.linspace(0.0, 1.0, 50)[:, None] * (b - a)).min() < 0.0
    filt = MotionFilter(robot, MotionFilterSettings(smoothing="none"), start_pose_rad=a)
    margin = filt.settings.body_margin_m
    accel = filt.limiter.max_acceleration_rad_s2
    previous, velocity, t = filt.position_rad.copy(), np.zeros(robot.n_joints), 0.0
    for k, raw in enumerate(sweep_between(robot, a, b, ticks)):
        t += PERIOD
        filt.push(raw[None, :], t)
        command, new_velocity = filt.tick(t)
        change = np.abs(new_velocity - velocity)
        assert np.all(change <= accel * PERIOD + SLACK), (k, change / (accel * PERIOD))
        assert step_clearance(body, previous, command) >= margin - TOLERANCE_M, k
        previous, velocity = command.copy(), new_velocity.copy()
    assert filt.body_guard.status.holds == 0
    assert filt.body_guard.status.interventions > 0  # the guard had something to do
    assert filt.status.faults == 0


def test_when_offline_sweep_passes_a_thin_part_at_full_speed_expect_the_limits_on_every_frame(
    body,
):
    """The offline guard (full velocity and acceleration limits) on the fastest sweeps past a
    thin part: every frame within the acceleration limit, none inside the margin, no hold."""
    robot = body.robot
    guard = BodyGuard(body, 0.02)
    for a, b, ticks in THIN_PASSES[:3]:
        a, b = np.array(a), np.array(b)
        guarded = np.vstack([a, guard_trajectory_of(guard, sweep_between(robot, a, b, ticks))])
        velocity = np.diff(guarded, axis=0) * 100.0
        change = np.abs(np.diff(np.vstack([np.zeros(robot.n_joints), velocity]), axis=0)) * 100.0
        assert np.all(change <= robot.max_acceleration_rad_s2 + 1e-6)
        for previous, command in itertools.pairwise(guarded):
            assert step_clearance(body, previous, command) >= 0.02 - TOLERANCE_M
        assert guard.status.holds == 0


def guard_trajectory_of(guard, trajectory):
    from audio2pose_ros.motion.body_guard import guard_trajectory

    return guard_trajectory(guard, trajectory, 100.0)


def arm_pairs(body, side):
    """Mask of the checked pairs whose first link is of the ``side`` ("L" or "R") arm."""
    return np.array([a.lower().startswith(side.lower()) for a, _ in body.link_pairs])


def resting_arm_and_swing(body, rng):
    """A pose with the left arm resting 2.2-4.5 cm from the body, the right arm clear of it
    by 6 cm or more, and a right-arm goal inside the body (the right arm swings towards it)."""
    robot = body.robot
    left = [i for i, n in enumerate(robot.names) if n.startswith("L")]
    right = [i for i, n in enumerate(robot.names) if n.startswith("R")]
    left_pairs, right_pairs = arm_pairs(body, "L"), arm_pairs(body, "R")
    start = robot.neutral_rad.copy()
    while True:
        start[left] = rng.uniform(robot.lower_rad[left], robot.upper_rad[left])
        if 0.022 < body.pair_distances(start)[left_pairs].min() < 0.045:
            break
    while True:
        start[right] = rng.uniform(robot.lower_rad[right], robot.upper_rad[right])
        if body.pair_distances(start)[right_pairs].min() >= 0.06:
            break
    goal = start.copy()
    while True:
        goal[right] = rng.uniform(robot.lower_rad[right], robot.upper_rad[right])
        if body.pair_distances(goal)[right_pairs].min() < 0.0:
            return start, goal


def test_when_margin_raised_while_an_arm_swings_towards_the_body_expect_nothing_in_the_old(
    body,
):
    """One arm rests between the old and the new margin, the other swings towards the body;
    the margin is raised from 2 to 5 cm as the swinging arm comes near (a random distance).
    No command, and no step between two, comes within the old margin (the arm used to be led
    on until it was the closest pair, then braked too late: up to 3 cm inside the body)."""
    robot = body.robot
    rng = np.random.default_rng(7)
    moving = arm_pairs(body, "R")
    for trial in range(24):
        start, goal = resting_arm_and_swing(body, rng)
        settings = MotionFilterSettings(smoothing="none")
        filt = MotionFilter(robot, settings, start_pose_rad=start)
        trigger, raised, t = rng.uniform(0.03, 0.12), False, 0.0
        previous = filt.position_rad.copy()
        for k in range(120):
            t += PERIOD
            filt.push((start + min(1.0, k / 40) * (goal - start))[None, :], t)
            if not raised and body.pair_distances(filt.position_rad)[moving].min() < trigger:
                filt.update_settings(MotionFilterSettings(smoothing="none", body_margin_m=0.05))
                raised = True
            command, _ = filt.tick(t)
            clearance = step_clearance(body, previous, command)
            assert clearance >= 0.02 - TOLERANCE_M, (trial, k, clearance)
            previous = command.copy()
        assert filt.body_guard.status.holds == 0, trial
        assert filt.status.faults == 0


CHANGES = [
    ("raise margin", dict(body_margin_m=0.02), dict(body_margin_m=0.05), {}, {}),
    ("lower margin", dict(body_margin_m=0.05), dict(body_margin_m=0.02), {}, {}),
    ("raise velocity", {}, {}, dict(velocity_fraction=0.3), dict(velocity_fraction=1.0)),
    ("lower velocity", {}, {}, dict(velocity_fraction=1.0), dict(velocity_fraction=0.1)),
    ("raise acceleration", {}, {}, dict(acceleration_fraction=0.2), {}),
    ("lower acceleration", {}, {}, {}, dict(acceleration_fraction=0.1)),
]


@pytest.mark.parametrize(
    ("name", "before", "after", "limits_before", "limits_after"),
    CHANGES,
    ids=[
        "raise margin",
        "lower margin",
        "raise velocity",
        "lower velocity",
        "raise acceleration",
        "lower acceleration",
    ],
)
def test_when_guard_parameters_change_while_arms_swing_expect_the_guard_kept(
    body, name, before, after, limits_before, limits_after
):
    """Margin, velocity and acceleration fractions changed, either way, while the right arm
    swings towards the body at speed, at a random moment of the swing: no command and no step
    between two within the smaller of the two margins, no hold, and no velocity change beyond
    the larger of the two acceleration limits (the guard brakes at the old limit after a lowered
    one, until the arm can stop at the new one)."""
    robot = body.robot
    rng = np.random.default_rng(11)
    margin = min(before.get("body_margin_m", 0.02), after.get("body_margin_m", 0.02))
    fast = LimitSettings(**{"velocity_fraction": 1.0, **limits_before})
    for trial in range(4):
        start, goal = resting_arm_and_swing(body, rng)
        filt = MotionFilter(
            robot, MotionFilterSettings(smoothing="none", **before), fast, start_pose_rad=start
        )
        accel = filt.limiter.max_acceleration_rad_s2
        change_at = int(rng.integers(10, 40))
        previous, velocity, t = filt.position_rad.copy(), np.zeros(robot.n_joints), 0.0
        for k in range(100):
            t += PERIOD
            filt.push((start + min(1.0, k / 40) * (goal - start))[None, :], t)
            if k == change_at:
                limits = LimitSettings(**{"velocity_fraction": 1.0, **limits_after})
                filt.update_settings(MotionFilterSettings(smoothing="none", **after), limits)
                accel = np.maximum(accel, filt.limiter.max_acceleration_rad_s2)
            command, new_velocity = filt.tick(t)
            assert step_clearance(body, previous, command) >= margin - TOLERANCE_M, (trial, k)
            step = np.abs(new_velocity - velocity)
            assert np.all(step <= accel * PERIOD + SLACK), (trial, k, step / (accel * PERIOD))
            previous, velocity = command.copy(), new_velocity.copy()
        assert filt.body_guard.status.holds == 0, trial
        assert filt.status.faults == 0


def state_that_cannot_stop(body):
    """A pose 1.3 mm outside the margin on the way of the first thin pass, moving along it
    into the body at 5 rad/s (its fastest joint): no braking stops it within one command."""
    a, b = (np.array(pose) for pose in THIN_PASSES[0][:2])
    way = a + np.linspace(0.0, 1.0, 400)[:, None] * (b - a)
    pose = way[int(np.flatnonzero(body.clearance(way) < 0.021)[0]) - 1]
    return pose, (b - a) / np.abs(b - a).max() * 5.0


def test_when_a_caller_hands_the_guard_a_state_that_cannot_stop_expect_a_counted_hold(body):
    """The last resort is counted (motion_filter_node reports it on /diagnostics as
    body_guard_holds) and still keeps the command out of the margin."""
    guard = BodyGuard(body, 0.02)
    limiter = JointLimiter(body.robot, LimitSettings(velocity_fraction=1.0))
    pose, velocity = state_that_cannot_stop(body)
    assert guard.status.holds == 0
    command, _ = guard.enforce(pose + velocity * PERIOD, velocity, pose, velocity, PERIOD, limiter)
    assert guard.status.holds == 1
    assert body.clearance(command) >= 0.02
