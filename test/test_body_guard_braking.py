"""The self-collision guard brakes in time on any ticks: no dead stop, nothing in the margin.

The filter's timer is uneven on a loaded computer, and every tick's velocity change is judged
against the acceleration limit times that tick's length. The guard plans each command's braking
path so that braking on any later ticks stays on it: an arm driven at full speed towards the
body slows within the acceleration limit every tick, and the last resort (counted in
``holds``) is never needed. Judged by the commanded positions and velocities of every tick.
"""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import AWAY, INSIDE, RIGHT_AWAY, pose_with
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_body_guard import hand_in_hip
from test_body_guard_pressure import THIN_PASSES, step_clearance

from audio2pose_ros.motion.body_guard import TOLERANCE_M, BodyGuard
from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings
from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.robot.body import BodyModel

SLACK = 1e-9  # rounding allowance of the acceleration check (rad/s)
MARGIN_M = 0.02
FULL_SPEED = LimitSettings(velocity_fraction=1.0)


@pytest.fixture(scope="module")
def body():
    return BodyModel.load()


def mirrored(robot, pose):
    """The pose with each arm's joints taken from the other arm (Pepper is symmetric)."""
    out = pose.copy()
    for joint in ("ShoulderPitch", "ShoulderRoll", "ElbowRoll", "ElbowYaw"):
        sign = 1.0 if joint == "ShoulderPitch" else -1.0
        left, right = robot.names.index("L" + joint), robot.names.index("R" + joint)
        out[left], out[right] = sign * pose[right], sign * pose[left]
    return out


def uneven_ticks(seed, n):
    """``n`` tick lengths between 3 and 20 ms (the filter's period is 10 ms), seeded."""
    return np.random.default_rng(seed).uniform(0.003, 0.02, n)


def drive(body, filt, raws, ticks, raise_at=-1, raised_m=MARGIN_M):
    """Push one raw pose per tick of ``ticks`` (s) and check every command.

    The margin is raised to ``raised_m`` live before tick ``raise_at``. Every command changes
    each joint's velocity by at most the acceleration limit (or the braking one) times its
    tick, and neither it nor the step to it comes within ``MARGIN_M`` (the margin in force
    before a raise) less the braking tolerance.

    Returns:
        The largest velocity change of a tick, in units of its limit.
    """
    previous, velocity = filt.position_rad.copy(), filt.velocity_rad_s.copy()
    worst, t = 0.0, 0.0
    for k, (raw, dt_s) in enumerate(zip(raws, ticks, strict=True)):
        t += dt_s
        if k == raise_at:
            filt.update_settings(MotionFilterSettings(smoothing="none", body_margin_m=raised_m))
        filt.push(raw[None, :], t)
        command, new_velocity = filt.tick(t)
        limiter = filt.limiter
        accel = np.maximum(limiter.max_acceleration_rad_s2, limiter.braking_rad_s2)
        change = np.abs(new_velocity - velocity)
        worst = max(worst, float((change / (accel * dt_s)).max()))
        assert np.all(change <= accel * dt_s + SLACK), (k, change / (accel * dt_s))
        clearance = step_clearance(body, previous, command)
        assert clearance >= MARGIN_M - TOLERANCE_M, (k, clearance)
        previous, velocity = command.copy(), new_velocity.copy()
    return worst


def sweeps(robot):
    """(name, start, goal): a clear start and a goal inside the body (the forearm in the
    belly), every joint of the arm moving."""
    left = (pose_with(robot, **AWAY), pose_with(robot, **INSIDE))
    return [
        ("left arm into the torso", *left),
        ("right arm into the torso", mirrored(robot, left[0]), mirrored(robot, left[1])),
    ]


SWEEPS = [name for name, _, _ in sweeps(BodyModel.load().robot)]


@pytest.mark.parametrize("name", SWEEPS)
def test_when_an_arm_sweeps_into_the_body_at_full_speed_on_uneven_ticks_expect_no_dead_stop(
    body, name
):
    """An arm swept from a clear pose into the body at the full velocity limit, back and forth,
    on ticks of 3 to 20 ms: every tick within the acceleration limit (the last resort stopped it
    in one tick, 9 times the limit here), never in the margin, no last resort."""
    robot = body.robot
    start, goal = next((a, b) for n, a, b in sweeps(robot) if n == name)
    assert body.clearance(start) > MARGIN_M
    assert body.clearance(goal) < 0.0
    raws = np.array([goal if (k // 60) % 2 == 0 else start for k in range(240)])
    filt = MotionFilter(
        robot, MotionFilterSettings(smoothing="none"), FULL_SPEED, start_pose_rad=start
    )
    drive(body, filt, raws, uneven_ticks(SWEEPS.index(name), len(raws)))
    assert filt.body_guard.status.interventions > 0  # the guard braked the arm
    assert filt.body_guard.status.holds == 0
    assert filt.status.faults == 0


def alternations(robot):
    """(name, a, b, ticks): two clear poses whose straight way passes a thin part of the body
    (the right hand past the pelvis, the right wrist past the head), ``ticks`` ticks each
    way."""
    return [
        (f"thin pass {i}", np.array(a), np.array(b), n)
        for i, (a, b, n) in enumerate(THIN_PASSES)
        if i >= 3
    ]


ALTERNATIONS = [name for name, *_ in alternations(BodyModel.load().robot)]


@pytest.mark.parametrize("name", ALTERNATIONS)
def test_when_poses_alternate_fast_past_the_pelvis_on_uneven_ticks_expect_no_dead_stop(body, name):
    """Raw poses alternate fast between two poses whose straight way passes the body (into
    the hip and out, or past a thin part), on ticks of 3 to 20 ms: within the acceleration
    limit every tick, never in the margin, no last resort."""
    robot = body.robot
    a, b, ticks = next(case[1:] for case in alternations(robot) if case[0] == name)
    phase = np.arange(12 * ticks) % (2 * ticks) / ticks
    fraction = np.where(phase <= 1.0, phase, 2.0 - phase)[:, None]
    raws = a + fraction * (b - a)
    start = a if body.clearance(a) >= MARGIN_M else b
    filt = MotionFilter(
        robot, MotionFilterSettings(smoothing="none"), FULL_SPEED, start_pose_rad=start
    )
    drive(body, filt, raws, uneven_ticks(100 + ALTERNATIONS.index(name), len(raws)))
    assert filt.body_guard.status.holds == 0
    assert filt.status.faults == 0


def random_raws(robot, rng, n):
    """``n`` raw poses: targets held 5 to 30 ticks each, half inside the body (the forearm in
    the belly, the hand in the hip, either arm), half anywhere in the joint ranges."""
    hip, belly = hand_in_hip(robot), pose_with(robot, **INSIDE)
    inside = [hip, belly, mirrored(robot, hip), mirrored(robot, belly)]
    raws = []
    while len(raws) < n:
        if rng.random() < 0.5:
            target = inside[rng.integers(len(inside))]
        else:
            target = rng.uniform(robot.lower_rad, robot.upper_rad)
        raws += [target] * int(rng.integers(5, 31))
    return np.array(raws[:n])


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    velocity_fraction=st.sampled_from([0.5, 1.0]),
    raise_at=st.integers(0, 200),
    raised_m=st.sampled_from([0.02, 0.03, 0.05]),
)
def test_when_random_commands_on_uneven_ticks_and_a_margin_raise_expect_no_dead_stop(
    body, seed, velocity_fraction, raise_at, raised_m
):
    """Random raw poses, half of them inside the body, through the joint limits (full or half
    speed) on ticks of 3 to 20 ms, with the margin raised live at a random tick: every tick
    within the acceleration limit, nothing within the old margin, no last resort."""
    robot = body.robot
    rng = np.random.default_rng(seed)
    start = pose_with(robot, **AWAY, **RIGHT_AWAY)
    filt = MotionFilter(
        robot,
        MotionFilterSettings(smoothing="none"),
        LimitSettings(velocity_fraction=velocity_fraction),
        start_pose_rad=start,
    )
    raws = random_raws(robot, rng, 200)
    drive(body, filt, raws, rng.uniform(0.003, 0.02, len(raws)), raise_at, raised_m)
    assert filt.body_guard.status.holds == 0
    assert filt.status.faults == 0


def test_when_the_last_resort_fires_on_its_own_command_expect_braking_along_the_checked_path(
    body, monkeypatch
):
    """Should braking ever fall short (here: every braked command is reported short), the last
    resort brakes every joint together along the braking path the previous command was
    checked with: counted, within the acceleration limit, out of the margin (it used to stop
    the arm in one tick)."""
    robot = body.robot
    guard = BodyGuard(body, MARGIN_M)
    limiter = JointLimiter(robot, FULL_SPEED)
    start = pose_with(robot, **AWAY)
    goal = pose_with(robot, **INSIDE)
    dt_s = 0.01
    previous, velocity = start.copy(), np.zeros(robot.n_joints)
    guard.reset()

    def step(previous, velocity):
        want, want_velocity = limiter.enforce(goal, previous, velocity, dt_s)
        return guard.enforce(want, want_velocity, previous, velocity, dt_s, limiter)

    while guard.status.interventions == 0:  # at full speed until the guard first brakes
        previous, velocity = step(previous, velocity)
    assert np.abs(velocity).max() > 1.0
    monkeypatch.setattr(guard, "_braking_short_of", lambda pose, *_: body.pair_joints(0))
    accel = limiter.max_acceleration_rad_s2
    for _ in range(30):
        command, new_velocity = step(previous, velocity)
        assert np.all(np.abs(new_velocity - velocity) <= accel * dt_s + SLACK)
        assert step_clearance(body, previous, command) >= MARGIN_M - TOLERANCE_M
        previous, velocity = command, new_velocity
    assert guard.status.holds > 0
