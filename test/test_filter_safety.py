"""One regression test per unsafe case observed on the motion filter core (inputs, faults, gaps).

Each test replays the case against MotionFilter and states what the robot may do: one bad input
moves no joint more than 0.1 rad, no NaN survives, a gap does not resume at the old velocity,
a huge message is cut at the cap, a stop with neutral ignores head targets, a restart starts
from the robot's pose, and settings change live or are refused.
"""

import contextlib

import numpy as np
import pytest

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.filter import MotionFilter, online_filter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.motion.style import StyleSettings

PERIOD = 0.01
MAX_DEVIATION_RAD = 0.1


def steady_pose(robot):
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] = 1.0
    pose[robot.names.index("LShoulderRoll")] = 0.4  # clear of the body at every pitch
    pose[robot.names.index("HeadYaw")] = 0.2
    return pose


def settled_filter(robot, settings=None):
    """A filter that has tracked a steady pose for 1.5 s: at rest on it."""
    filt = MotionFilter(robot, settings)
    t = 0.0
    for _ in range(150):
        t += PERIOD
        filt.push(steady_pose(robot)[None, :], t)
        filt.tick(t)
    return filt, t


def worst_deviation_after(filt, t, robot, first_pose, ticks=300):
    """Send ``first_pose`` in one tick, then the steady pose; the worst distance from rest."""
    rest = filt.position_rad.copy()
    worst = 0.0
    for i in range(ticks):
        t += PERIOD
        filt.push((first_pose if i == 0 else steady_pose(robot))[None, :], t)
        worst = max(worst, float(np.abs(filt.tick(t)[0] - rest).max()))
    return worst


@pytest.mark.parametrize("value", [90.0, 1e6, 1e50])
def test_when_one_point_far_outside_range_expect_no_joint_moves_more_than_a_tenth_rad(robot, value):
    filt, t = settled_filter(robot)
    bad = steady_pose(robot)
    bad[robot.names.index("LShoulderPitch")] = value
    assert worst_deviation_after(filt, t, robot, bad) <= MAX_DEVIATION_RAD
    assert filt.status.out_of_range == 1


def test_when_one_in_range_three_rad_spike_expect_no_joint_moves_more_than_a_tenth_rad(robot):
    filt, t = settled_filter(robot)
    spike = steady_pose(robot)
    spike[robot.names.index("LShoulderPitch")] -= 3.0  # 1.0 -> -2.0, inside [-2.09, 2.09]
    assert worst_deviation_after(filt, t, robot, spike) <= MAX_DEVIATION_RAD
    assert filt.status.implausible == 1


def test_when_track_really_jumps_expect_it_reacquired_and_reached(robot):
    """Reached gently: 2 rad at a quarter of the velocity limit take about 3 s."""
    filt, t = settled_filter(robot)
    moved = steady_pose(robot)
    moved[robot.names.index("LShoulderPitch")] = -1.0
    for _ in range(500):
        t += PERIOD
        filt.push(moved[None, :], t)
        filt.tick(t)
    assert filt.position_rad[robot.names.index("LShoulderPitch")] == pytest.approx(-1.0, abs=0.02)


@pytest.mark.parametrize("kind", ["head_target", "head_offset"])
def test_when_one_head_value_of_1e6_expect_head_not_moved_and_input_rejected(robot, kind):
    filt, t = settled_filter(robot)
    rest = filt.position_rad.copy()
    setter = filt.set_head_target if kind == "head_target" else filt.set_head_offset
    with contextlib.suppress(InputError):
        setter({"HeadYaw": 1e6}, t)
    worst = 0.0
    for _ in range(200):
        t += PERIOD
        filt.push(steady_pose(robot)[None, :], t)
        worst = max(worst, float(np.abs(filt.tick(t)[0] - rest).max()))
    assert worst <= MAX_DEVIATION_RAD
    assert filt.status.external_rejected == 1


def test_when_head_offset_beyond_documented_maximum_expect_rejected(robot):
    filt = MotionFilter(robot, MotionFilterSettings(max_head_offset_rad=0.3))
    filt.set_head_offset({"HeadPitch": 0.3}, 0.0)
    with pytest.raises(InputError, match=r"HeadPitch: 0.31 rad is outside \[-0.3, 0.3\]"):
        filt.set_head_offset({"HeadPitch": 0.31}, 0.0)


def test_when_1e308_arrives_expect_state_finite_and_tracking_continues(robot):
    filt, t = settled_filter(robot)
    bad = steady_pose(robot)
    bad[robot.names.index("RElbowRoll")] = 1e308
    t += PERIOD
    filt.push(bad[None, :], t)
    filt.tick(t)
    target = steady_pose(robot)
    target[robot.names.index("HeadYaw")] = 0.6  # then the voice moves the head
    for _ in range(150):
        t += PERIOD
        filt.push(target[None, :], t)
        filt.tick(t)
    assert filt._smoother.is_finite()
    assert filt.position_rad[robot.names.index("HeadYaw")] == pytest.approx(0.6, abs=0.02)


@pytest.mark.parametrize("smoothing", ["lowpass", "kalman"])
def test_when_filter_state_turns_non_finite_expect_reset_from_last_command_and_fault(
    robot, smoothing
):
    filt, t = settled_filter(robot, MotionFilterSettings(smoothing=smoothing))
    commanded = filt.position_rad.copy()
    # a numerical fault inside the smoother's state (the Kalman velocity, a low-pass section)
    state = filt._smoother._x if smoothing == "kalman" else filt._smoother._state[0]
    state[1, 3] = np.inf
    t += PERIOD
    filt.push(steady_pose(robot)[None, :], t)
    position, _ = filt.tick(t)
    np.testing.assert_allclose(position, commanded, atol=1e-9)
    assert filt.status.faults == 1
    assert "non-finite" in filt.status.last_fault
    assert filt._smoother.is_finite()


def test_when_ticks_stop_for_half_a_second_expect_no_resume_at_old_velocity(robot):
    filt, t = settled_filter(robot)
    joint = robot.names.index("LShoulderPitch")
    far = steady_pose(robot)
    step = -0.9 * filt.limiter.max_velocity_rad_s[joint] * PERIOD
    for _ in range(30):  # accelerate along a fast, reachable track...
        t += PERIOD
        far[joint] += step
        filt.push(far[None, :], t)
        filt.tick(t)
    moving = float(np.abs(filt.velocity_rad_s).max())
    assert moving > 1.0
    t += 0.5  # ...then the process is blocked for 0.5 s
    filt.push(far[None, :], t)
    _, velocity = filt.tick(t)
    # Resumes from rest: one tick of acceleration at most, not the old velocity.
    assert np.abs(velocity).max() <= 1.01 * filt.limiter.max_acceleration_rad_s2.max() * 2 * PERIOD
    assert filt.status.gaps == 1


def test_when_one_message_holds_100000_points_expect_cap_applied_and_counted(robot):
    """Only the capped poses are kept (its cost over the live graph: `audio2pose faults`)."""
    filt, t = settled_filter(robot)
    huge = np.tile(steady_pose(robot), (100_000, 1))
    filt.push(huge, t)
    assert filt.status.truncated == 100_000 - filt.settings.max_points_per_message
    assert filt.buffered <= filt.settings.max_points_per_message


def test_when_stopped_with_neutral_behaviour_expect_head_target_ignored(robot):
    settings = MotionFilterSettings(stop_behaviour="neutral", neutral_glide_s=0.5)
    filt, t = settled_filter(robot, settings)
    filt.set_stop(True)
    yaw = robot.names.index("HeadYaw")
    yaws = []
    for _ in range(150):
        t += PERIOD
        filt.set_head_target({"HeadYaw": 1.5}, t)
        yaws.append(filt.tick(t)[0][yaw])
    assert filt.status.mode == "stopped"
    assert max(yaws) <= 0.2 + 1e-9  # never toward the target
    assert yaws[-1] == pytest.approx(filt.neutral_rad[yaw], abs=1e-3)


def test_when_started_from_measured_pose_expect_first_command_within_one_velocity_step(robot):
    measured = robot.neutral_rad.copy()
    measured[robot.names.index("LShoulderPitch")] = -0.3  # the arm is up, far from neutral
    filt = MotionFilter(robot, start_pose_rad=measured)
    position, _ = filt.tick(0.0)
    step = np.abs(position - measured)
    assert np.all(step <= filt.limiter.max_velocity_rad_s * PERIOD + 1e-12)


def test_when_gain_changed_live_expect_effect_from_next_tick_and_read_only_refused(robot):
    filt, t = settled_filter(robot)
    filt.update_settings(MotionFilterSettings(), style=StyleSettings(arms_gain=0.0))
    arms = robot.group_mask("arms")
    for _ in range(200):
        t += PERIOD
        filt.push(steady_pose(robot)[None, :], t)
        filt.tick(t)
    np.testing.assert_allclose(filt.position_rad[arms], filt.neutral_rad[arms], atol=1e-3)
    with pytest.raises(ConfigurationError, match="rate_hz cannot change while the node runs"):
        filt.update_settings(MotionFilterSettings(rate_hz=50.0))
    with pytest.raises(ConfigurationError, match="position_margin_rad cannot change"):
        filt.update_settings(filt.settings, LimitSettings(position_margin_rad=0.05))


def test_when_default_model_speaks_expect_gate_rejects_none_of_its_poses(speech):
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import predict_normalized
    from audio2pose_ros.resources import default_checkpoint_path

    checkpoint = load_checkpoint(default_checkpoint_path())
    raw = checkpoint.robot.denormalize(predict_normalized(checkpoint, speech))
    filt = MotionFilter(checkpoint.robot)
    online_filter(filt, raw)
    assert filt.status.received == len(raw)  # the gate stops outliers, not the model's motion


def test_when_velocity_fraction_lowered_while_moving_fast_expect_braking_not_a_fault(robot):
    filt, t = settled_filter(robot, MotionFilterSettings(outlier_tolerance_rad=1.0))
    filt.update_settings(filt.settings, LimitSettings(velocity_fraction=1.0))
    far = steady_pose(robot)
    far[robot.names.index("LShoulderPitch")] = -1.5
    for _ in range(30):
        t += PERIOD
        filt.push(far[None, :], t)
        filt.tick(t)
    fast = float(np.abs(filt.velocity_rad_s).max())
    filt.update_settings(filt.settings, LimitSettings(velocity_fraction=0.1))
    speeds = []
    for _ in range(50):
        t += PERIOD
        filt.push(far[None, :], t)
        speeds.append(float(np.abs(filt.tick(t)[1]).max()))
    assert filt.status.faults == 0
    assert speeds[0] >= fast - filt.limiter.max_acceleration_rad_s2.max() * PERIOD - 1e-9
    assert speeds[-1] <= filt.limiter.max_velocity_rad_s.max() + 1e-9  # braked to the new limit


def test_when_started_and_no_pose_arrives_expect_robot_held_not_glided_to_neutral(robot):
    """A restarted filter whose input is late (DDS discovery under load) must not move."""
    start = robot.neutral_rad.copy()
    start[robot.names.index("LShoulderPitch")] -= 0.4
    start[robot.names.index("LShoulderRoll")] = 0.4  # clear of the body: nothing to lead out
    motion = MotionFilter(robot)
    motion.start_from(start)
    for k in range(200):  # 2 s without any pose: beyond the watchdog and a whole glide
        positions, _ = motion.tick(0.01 * k)
        assert np.abs(positions - motion.limiter.clamp_position(start)).max() < 1e-12
    assert motion.status.mode == "waiting"
    motion.push(start[None, :], 2.0)
    motion.tick(2.0)
    assert motion.status.mode == "tracking"


@pytest.mark.parametrize("margin", [0.05, 0.2])
def test_when_the_robot_starts_at_a_joint_limit_expect_it_brought_inside_the_margin_without_a_jump(
    robot, margin
):
    """The measured pose may lie between a limit and the margin: the command starts there."""
    measured = robot.neutral_rad.copy()
    hip = robot.names.index("HipRoll")
    measured[hip] = robot.upper_rad[hip]  # a real reading: HipRoll at its upper limit
    filt = MotionFilter(robot, limits=LimitSettings(position_margin_rad=margin))
    filt.start_from(measured)
    previous, t = measured, 0.0
    for _ in range(300):
        t += PERIOD
        position, _ = filt.tick(t)
        # never faster than the joint's velocity limit, never further out than it started
        step = np.abs(position - previous)
        assert np.all(step <= filt.limiter.max_velocity_rad_s * PERIOD + 1e-9), step / PERIOD
        assert position[hip] <= previous[hip] + 1e-12
        previous = position
    assert position[hip] <= filt.limiter.upper_rad[hip] + 1e-9  # inside the margin in 3 s
    assert filt.status.faults == 0
