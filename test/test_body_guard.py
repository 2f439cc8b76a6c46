"""The self-collision guard in the motion filter and offline: no command inside the margin."""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import pose_with
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from audio2pose_ros.motion.body_guard import (
    LEAD_OUT_SPEED_RAD_S,
    TOLERANCE_M,
    BodyGuard,
    guard_trajectory,
)
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.robot.body import BodyModel

PERIOD = 0.01
MARGIN_M = 0.02


@pytest.fixture(scope="module")
def body():
    return BodyModel.load()


def hand_in_hip(robot):
    """Left hand driven down into the hip, within every joint limit; head and right arm move."""
    return pose_with(
        robot,
        LShoulderPitch=1.3,
        LShoulderRoll=0.13,
        LElbowRoll=-1.24,
        LElbowYaw=0.28,
        HeadYaw=0.6,
        HeadPitch=0.1,
        RShoulderPitch=0.6,
        RShoulderRoll=-0.5,
    )


def drive(filt, poses, t=0.0):
    out = []
    for pose in poses:
        t += PERIOD
        filt.push(pose[None, :], t)
        out.append(filt.tick(t)[0].copy())
    return np.array(out), t


def test_when_raw_poses_drive_left_hand_into_hip_expect_arm_stopped_at_margin(body):
    robot = body.robot
    filt = MotionFilter(robot)
    target = hand_in_hip(robot)
    assert body.clearance(target) < 0.0  # the raw pose is inside the body
    out, _ = drive(filt, np.tile(target, (300, 1)))
    clearance = body.clearance(out)
    assert clearance.min() >= MARGIN_M - TOLERANCE_M
    assert filt.body_guard.status.interventions > 0
    # the head and the right arm kept following
    for name in ("HeadYaw", "HeadPitch", "RShoulderPitch", "RShoulderRoll"):
        joint = robot.names.index(name)
        assert out[-1, joint] == pytest.approx(target[joint], abs=1e-3)
    assert filt.status.faults == 0


def test_when_unguarded_filter_expect_the_same_raw_poses_to_go_inside(body):
    """What the guard prevents: without it, the filter's limits alone command the hip pose."""
    robot = body.robot
    filt = MotionFilter(robot)
    filt.body_guard.margin_m = -1.0  # disabled: nothing is closer than -1 m
    out, _ = drive(filt, np.tile(hand_in_hip(robot), (300, 1)))
    assert body.clearance(out).min() < 0.0


def test_when_raw_poses_clear_again_expect_arm_follows_within_a_second(body):
    robot = body.robot
    filt = MotionFilter(robot)
    inside = hand_in_hip(robot)
    _, t = drive(filt, np.tile(inside, (200, 1)))
    clear = pose_with(robot, LShoulderPitch=0.8, LShoulderRoll=0.5, LElbowRoll=-0.8)
    fraction = np.linspace(0.0, 1.0, 50)[:, None]  # the speaker's arm moves away over 0.5 s
    _, t = drive(filt, inside + fraction * (clear - inside), t)
    out, _ = drive(filt, np.tile(clear, (100, 1)), t)  # then 1 s of clear poses
    np.testing.assert_allclose(out[-1], clear, atol=0.02)


def test_when_started_inside_the_margin_expect_led_out_slowly_within_limits(body):
    robot = body.robot
    inside = hand_in_hip(robot)
    filt = MotionFilter(robot, start_pose_rad=inside)
    start = filt.position_rad.copy()
    assert body.clearance(start) < 0.0
    out, _ = drive(filt, np.tile(inside, (400, 1)))
    clearance = body.clearance(out)
    assert clearance[-1] >= MARGIN_M - TOLERANCE_M  # out within 4 s
    once_out = np.flatnonzero(clearance >= MARGIN_M - TOLERANCE_M)[0]
    speeds = np.abs(np.diff(np.vstack([start, out[:once_out]]), axis=0)) / PERIOD
    left_arm = [robot.names.index(n) for n in robot.names if n.startswith(("LShoulder", "LElbow"))]
    # the arm is led out gently: lead-out speed, not the joints' limits ...
    assert speeds[:, left_arm].max() <= LEAD_OUT_SPEED_RAD_S + 1e-6
    # ... while the joints it does not lead out follow their command (HipRoll, held while its
    # return would bring the arm closer, then back to its command) within the limits
    assert (speeds <= filt.limiter.max_velocity_rad_s + 1e-6).all()
    assert clearance[once_out:].min() >= MARGIN_M - TOLERANCE_M  # and stays out
    assert np.all(np.diff(clearance[:once_out]) >= -1e-6)  # never deeper on the way
    assert filt.status.faults == 0


@pytest.mark.parametrize("fraction", [0.02, 0.03])
def test_when_led_out_under_a_low_velocity_fraction_expect_its_limit_kept_and_no_fault(
    body, fraction
):
    """The lead-out's own speed yields to the configured velocity limit when that is lower."""
    robot = body.robot
    inside = hand_in_hip(robot)
    filt = MotionFilter(robot, limits=LimitSettings(velocity_fraction=fraction))
    filt.start_from(inside)
    previous = filt.position_rad.copy()
    out, _ = drive(filt, np.tile(inside, (1500, 1)))  # 15 s
    steps = np.abs(np.diff(np.vstack([previous, out]), axis=0))
    assert (steps <= filt.limiter.max_velocity_rad_s * PERIOD + 1e-9).all()
    assert filt.status.faults == 0, filt.status.last_fault
    assert body.clearance(out[-1]) >= MARGIN_M - TOLERANCE_M  # led out all the same


def test_when_arm_rests_just_inside_the_margin_expect_it_still_goes_to_neutral(body):
    """Braking may leave an arm up to TOLERANCE_M inside the margin. From there every way out
    that does not approach the body must stay open: the arm pressed against the torso (the
    margin set half a millimetre above its clearance) glides to neutral when disabled, its
    clearance never falling on the way."""
    robot = body.robot
    pressed = pose_with(robot, LShoulderRoll=robot.lower_rad[robot.names.index("LShoulderRoll")])
    margin = float(body.clearance(pressed)) + 0.5e-3
    assert body.clearance(robot.neutral_rad) > margin + 1e-3  # neutral itself is clear
    filt = MotionFilter(robot, MotionFilterSettings(body_margin_m=margin), start_pose_rad=pressed)
    filt.set_enabled(False)
    out = np.array([filt.tick(PERIOD * (k + 1))[0].copy() for k in range(300)])
    assert np.abs(out[-1] - filt.neutral_rad).max() < 1e-3, "held short of neutral"
    clearance = body.clearance(out)
    assert clearance[0] < margin  # the start was in the band
    inside = clearance[:-1] < margin
    # never closer while inside (the guard compares coal's answers, within its 1e-6 m)
    assert np.all(np.diff(clearance)[inside] >= -1e-6)
    assert filt.status.faults == 0


def test_when_straight_way_to_neutral_passes_the_body_expect_the_arm_goes_round(body):
    """The right arm raised behind, elbow across: its straight way down to neutral brings the
    bicep to the torso. Braking alone left it at the margin; it must go round, along the
    margin, and reach neutral, no command inside the margin.

    Riding along the margin, each step's braking decision turns on micrometres, so coal's
    1e-6 m tolerance moves the arrival (357 to 415 ticks for starts 1e-9 to 1e-6 rad apart,
    when braking stopped the left arm outside the band). Now the left arm, braked from full
    speed, stops in the band at the torso too: the arms go round one after the other (the
    detour moves the closest pair's arm), arriving after about 560 ticks; 800 leave room."""
    robot = body.robot
    start = pose_with(
        robot,
        HeadPitch=-0.35,
        HeadYaw=0.92,
        LShoulderRoll=0.72,
        LShoulderPitch=-1.85,
        LElbowRoll=-0.02,
        LElbowYaw=1.62,
        RShoulderRoll=-0.14,
        RShoulderPitch=-1.06,
        RElbowRoll=0.62,
        RElbowYaw=-1.14,
        HipRoll=-0.39,
    )
    assert body.clearance(start) >= MARGIN_M
    filt = MotionFilter(robot, start_pose_rad=start)
    filt.set_enabled(False)
    out = np.array([filt.tick(PERIOD * (k + 1))[0].copy() for k in range(800)])
    assert np.abs(out[-1] - filt.neutral_rad).max() < 1e-3, "held short of neutral"
    assert body.clearance(out).min() >= MARGIN_M - TOLERANCE_M
    assert filt.body_guard.status.detour_steps > 0
    assert filt.status.faults == 0


def test_when_margin_raised_live_expect_arm_led_out_to_the_new_margin_and_kept_there(body):
    robot = body.robot
    filt = MotionFilter(robot)
    filt.update_settings(MotionFilterSettings(body_margin_m=0.03))  # neutral is now inside
    out, _ = drive(filt, np.tile(hand_in_hip(robot), (400, 1)))
    clearance = body.clearance(out)
    once_out = np.flatnonzero(clearance >= 0.03 - TOLERANCE_M)[0]
    assert np.all(np.diff(clearance[:once_out]) >= -1e-6)  # led out, never deeper
    assert clearance[once_out:].min() >= 0.03 - TOLERANCE_M


def test_when_offline_trajectory_enters_the_body_expect_guarded_copy_outside(body):
    robot = body.robot
    n = 200
    fraction = np.linspace(0.0, 1.0, n)[:, None]
    trajectory = robot.neutral_rad + fraction * (hand_in_hip(robot) - robot.neutral_rad)
    guarded = guard_trajectory(BodyGuard(body, MARGIN_M), trajectory, 100.0)
    assert body.clearance(trajectory).min() < 0.0
    assert body.clearance(guarded).min() >= MARGIN_M - TOLERANCE_M
    assert np.all(guarded >= robot.lower_rad)
    assert np.all(guarded <= robot.upper_rad)


def test_when_offline_trajectory_leaves_the_body_expect_it_rejoined_within_the_limits(body):
    """Into the hip and straight back out: the guard holds the arm at the margin, and when the
    trajectory is clear again the guarded copy rejoins it within the velocity and acceleration
    limits (it used to jump there in one frame, up to 19 times the velocity limit)."""
    robot = body.robot
    inside = hand_in_hip(robot)
    fraction = np.concatenate([np.linspace(0.0, 1.0, 100), np.linspace(1.0, 0.0, 20)])[:, None]
    trajectory = robot.neutral_rad + fraction * (inside - robot.neutral_rad)
    trajectory = np.vstack([trajectory, np.tile(robot.neutral_rad, (100, 1))])
    guarded = guard_trajectory(BodyGuard(body, MARGIN_M), trajectory, 100.0)
    velocity = np.diff(guarded, axis=0) * 100.0
    assert np.all(np.abs(velocity) <= robot.max_velocity_rad_s + 1e-9)
    assert np.all(np.abs(np.diff(velocity, axis=0)) * 100.0 <= robot.max_acceleration_rad_s2 + 1e-6)
    np.testing.assert_allclose(guarded[-1], robot.neutral_rad, atol=1e-6)  # rejoined


settle = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@settle
@given(
    seed=st.integers(0, 2**31 - 1),
    rate=st.sampled_from([20.0, 50.0, 100.0]),
    restart_at=st.integers(0, 150),
    start_inside=st.booleans(),
)
def test_when_random_raw_poses_rates_and_restarts_expect_no_command_inside_margin(
    body, seed, rate, restart_at, start_inside
):
    """Random poses anywhere in the joint ranges, at random rates, with a restart: after the
    robot has been led out (if it started inside), no command is inside the margin, ever, and
    no command leaves the joint limits."""
    robot = body.robot
    rng = np.random.default_rng(seed)
    start = hand_in_hip(robot) if start_inside else None
    filt = MotionFilter(robot, start_pose_rad=start)
    led_out = body.clearance(filt.position_rad) >= MARGIN_M - TOLERANCE_M
    t = 0.0
    targets = rng.uniform(robot.lower_rad, robot.upper_rad, size=(8, robot.n_joints))
    for k in range(300):
        t += PERIOD
        if k % max(1, round(100.0 / rate)) == 0:
            filt.push(targets[(k // 40) % len(targets)][None, :], t)
        if k == restart_at:
            filt.start_from(filt.position_rad)
        positions, _ = filt.tick(t)
        assert np.all(positions >= filt.limiter.lower_rad - 1e-12)
        assert np.all(positions <= filt.limiter.upper_rad + 1e-12)
        clearance = float(body.clearance(positions))
        if led_out:
            assert clearance >= MARGIN_M - TOLERANCE_M, (k, body.closest_pair(positions))
        led_out = led_out or clearance >= MARGIN_M - TOLERANCE_M
    assert filt.status.faults == 0


def test_when_glides_checked_expect_counts_of_a_real_run(body):
    """check-body --glides: random clear start poses left to glide to neutral are counted, and
    no command of theirs comes inside the margin."""
    from audio2pose_ros.offline.body_check import check_glides

    report = check_glides(body, 6, seed=3, margin_m=MARGIN_M, seconds=4.0)
    assert report.poses == 6
    assert report.reached >= 5
    assert report.min_clearance_m >= MARGIN_M - TOLERANCE_M
    assert f"{report.reached} of 6 random start poses" in report.row()
    short = check_glides(body, 6, seed=3, margin_m=MARGIN_M, seconds=0.05)
    assert short.reached < report.reached  # 50 ms is too short to reach neutral from anywhere
