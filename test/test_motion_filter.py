"""The online motion filter core: pacing, group gains, watchdog to neutral, limits last."""

import numpy as np
import pytest

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.style import StyleSettings

PERIOD = 0.01


def run(filt: MotionFilter, poses: np.ndarray, start_s: float = 0.0, extra_ticks: int = 0):
    """Push one pose per tick (as a live stream does), then tick without input."""
    out, t = [], start_s
    for pose in poses:
        t += PERIOD
        filt.push(pose[None, :], t)
        out.append(filt.tick(t)[0].copy())
    for _ in range(extra_ticks):
        t += PERIOD
        out.append(filt.tick(t)[0].copy())
    return np.array(out)


def test_when_no_input_ever_expect_waiting_at_the_neutral_start_pose(robot):
    filt = MotionFilter(robot)
    out = run(filt, np.empty((0, 11)), extra_ticks=10)
    np.testing.assert_allclose(
        out[-1],
        np.clip(robot.neutral_rad, robot.lower_rad + 0.01, robot.upper_rad - 0.01),
        atol=1e-9,
    )
    assert filt.status.mode == "waiting"  # holds its start pose until the first pose


def test_when_input_stops_expect_glide_to_neutral_within_timeout_plus_settling(robot):
    settings = MotionFilterSettings(watchdog_timeout_s=0.3)
    filt = MotionFilter(robot, settings)
    raised = robot.neutral_rad.copy()
    raised[robot.names.index("LShoulderPitch")] -= 0.8  # forearm up
    raised[robot.names.index("LShoulderRoll")] = 0.4  # and out, clear of the body
    out = run(filt, np.tile(raised, (200, 1)), extra_ticks=300)
    joint = robot.names.index("LShoulderPitch")
    assert out[199, joint] == pytest.approx(raised[joint], abs=0.02)  # tracked while speaking
    assert out[-1, joint] == pytest.approx(robot.neutral_rad[joint], abs=0.01)  # back at rest
    assert filt.status.mode == "neutral"
    steps = np.abs(np.diff(out[:, joint])) / PERIOD
    assert steps.max() <= filt.limiter.max_velocity_rad_s[joint] + 1e-9  # no jump


def test_when_arms_gain_zero_expect_arms_at_neutral_head_moving(robot):
    filt = MotionFilter(robot, MotionFilterSettings(), style=StyleSettings(arms_gain=0.0))
    target = robot.neutral_rad + 0.3 * (robot.upper_rad - robot.neutral_rad)
    out = run(filt, np.tile(target, (150, 1)))
    arms = robot.group_mask("arms")
    np.testing.assert_allclose(out[-1, arms], robot.neutral_rad[arms], atol=1e-6)
    assert np.abs(out[-1, ~arms] - robot.neutral_rad[~arms]).max() > 0.05


def test_when_poses_have_nan_or_wrong_shape_expect_rejected_and_counted(robot):
    filt = MotionFilter(robot)
    bad = np.tile(robot.neutral_rad, (3, 1))
    bad[1, 4] = np.nan
    assert filt.push(bad, 0.0) == 2
    assert filt.push(np.zeros((2, 5)), 0.0) == 0
    assert filt.status.rejected == 2


def test_when_burst_exceeds_buffer_expect_oldest_dropped_and_counted(robot):
    filt = MotionFilter(robot, MotionFilterSettings(max_buffer_s=0.1))  # 10 poses
    filt.push(np.tile(robot.neutral_rad, (25, 1)), 0.0)
    assert filt.status.dropped == 15


def test_when_settings_invalid_expect_configuration_error_naming_parameter_and_range():
    with pytest.raises(ConfigurationError, match="parameter smoothing: value 'median'"):
        MotionFilterSettings(smoothing="median")
    with pytest.raises(ConfigurationError, match=r"arms_gain: value 2.5 .* in \[0, 2\]"):
        StyleSettings(arms_gain=2.5)


def raised_pose(robot):
    """The left arm raised forward and out (clear of the body), the head turned."""
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] -= 0.8
    pose[robot.names.index("LShoulderRoll")] = 0.4
    pose[robot.names.index("HeadYaw")] += 0.4
    return pose


def test_when_poses_stop_expect_neutral_reached_within_timeout_plus_glide(robot):
    settings = MotionFilterSettings(watchdog_timeout_s=0.3, neutral_glide_s=0.8)
    filt = MotionFilter(robot, settings)
    out = run(filt, np.tile(raised_pose(robot), (200, 1)), extra_ticks=200)
    # Last pose at tick 199; neutral due by 0.3 s + 0.8 s later = tick 309 (plus one period).
    np.testing.assert_allclose(out[311], filt.neutral_rad, atol=1e-3)
    assert filt.status.mode == "neutral"


def test_when_voice_silent_expect_glide_to_neutral_although_poses_keep_coming(robot):
    settings = MotionFilterSettings(silence_timeout_s=0.2, neutral_glide_s=0.5)
    filt = MotionFilter(robot, settings)
    pose, t, out = raised_pose(robot), 0.0, []
    for i in range(500):
        t += PERIOD
        filt.set_voice_active(i < 300, t)
        filt.push(pose[None, :], t)
        out.append(filt.tick(t)[0].copy())
    assert np.abs(out[299] - pose).max() < 0.05  # tracking while the voice is active
    np.testing.assert_allclose(out[-1], filt.neutral_rad, atol=1e-3)  # silent since tick 300


def test_when_disabled_expect_neutral_and_queued_motion_discarded(robot):
    filt = MotionFilter(robot)
    run(filt, np.tile(raised_pose(robot), (100, 1)))
    filt.set_enabled(False)
    out = run(filt, np.tile(raised_pose(robot), (150, 1)), start_s=1.0)
    np.testing.assert_allclose(out[-1], filt.neutral_rad, atol=1e-3)
    filt.set_enabled(True)
    out = run(filt, np.tile(raised_pose(robot), (150, 1)), start_s=2.5)
    assert np.abs(out[-1] - raised_pose(robot)).max() < 0.05  # resumes


def test_when_stop_hold_expect_braking_then_standstill(robot):
    filt = MotionFilter(robot, MotionFilterSettings(stop_behaviour="hold"))
    pose = raised_pose(robot)
    run(filt, np.tile(robot.neutral_rad, (20, 1)))
    # Start a fast move along a reachable track, then stop in the middle of it.
    step = 0.9 * filt.limiter.max_velocity_rad_s * PERIOD * np.sign(pose - robot.neutral_rad)
    track = robot.neutral_rad + step * np.arange(1, 16)[:, None]
    out = run(filt, track, start_s=0.2)
    assert np.abs(filt.velocity_rad_s).max() > 0.5
    filt.set_stop(True)
    held = run(filt, np.tile(pose, (100, 1)), start_s=0.35)
    braking_s = filt.limiter.max_velocity_rad_s.max() / filt.limiter.max_acceleration_rad_s2.min()
    settled = int(np.ceil(braking_s / PERIOD)) + 2
    assert np.abs(np.diff(held[settled:], axis=0)).max() < 1e-9  # standing still
    assert np.abs(held[-1] - out[-1]).max() < 0.5  # stopped near where the stop came
    assert filt.status.mode == "stopped"


def test_when_stop_neutral_expect_glide_to_neutral(robot):
    filt = MotionFilter(robot, MotionFilterSettings(stop_behaviour="neutral", neutral_glide_s=0.5))
    run(filt, np.tile(raised_pose(robot), (100, 1)))
    filt.set_stop(True)
    out = run(filt, np.tile(raised_pose(robot), (100, 1)), start_s=1.0)
    np.testing.assert_allclose(out[-1], filt.neutral_rad, atol=1e-3)


def test_when_head_target_given_expect_head_blended_toward_it_then_released(robot):
    settings = MotionFilterSettings(head_target_weight=0.5, external_timeout_s=0.3)
    filt = MotionFilter(robot, settings)
    yaw = robot.names.index("HeadYaw")
    t, out = 0.0, []
    for i in range(300):
        t += PERIOD
        if i < 150:
            filt.set_head_target({"HeadYaw": 1.0}, t)
        filt.push(robot.neutral_rad[None, :], t)
        out.append(filt.tick(t)[0].copy())
    assert out[149][yaw] == pytest.approx(0.5, abs=0.01)  # halfway between generated 0 and 1
    assert filt.status.head_target_active is False
    assert out[-1][yaw] == pytest.approx(0.0, abs=0.01)  # target expired: generated motion again


def test_when_head_offset_given_expect_added_to_generated_head(robot):
    filt = MotionFilter(robot)
    pitch = robot.names.index("HeadPitch")
    t = 0.0
    for _ in range(150):
        t += PERIOD
        filt.set_head_offset({"HeadPitch": 0.1}, t)
        filt.push(robot.neutral_rad[None, :], t)
        filt.tick(t)
    assert filt.position_rad[pitch] == pytest.approx(robot.neutral_rad[pitch] + 0.1, abs=0.005)


def test_when_external_target_names_a_non_head_joint_expect_error(robot):
    filt = MotionFilter(robot)
    with pytest.raises(InputError, match="'LShoulderPitch' is not a head joint"):
        filt.set_head_target({"LShoulderPitch": 0.0}, 0.0)
    with pytest.raises(InputError, match="HeadYaw: nan rad is outside"):
        filt.set_head_offset({"HeadYaw": float("nan")}, 0.0)


def test_when_backlog_stands_in_buffer_expect_it_drained_by_skipping(robot):
    filt = MotionFilter(robot, MotionFilterSettings(backlog_window_s=0.1, max_buffer_s=1.0))
    t = 0.0
    filt.push(np.tile(robot.neutral_rad, (20, 1)), t)  # a burst: 20 poses at once
    for _ in range(100):  # then one pose per tick, as a steady stream
        t += PERIOD
        filt.push(robot.neutral_rad[None, :], t)
        filt.tick(t)
    assert filt.status.skipped >= 10
    assert filt.status.buffered <= 1  # the added latency is gone


def test_when_two_messages_come_together_expect_the_newer_commanded_and_no_backlog(robot):
    filt = MotionFilter(robot)
    t = 0.0
    for _ in range(100):  # a steady stream, a pose commanded at its arrival
        t += PERIOD
        filt.push(robot.neutral_rad[None, :], t)
        filt.tick(t)
    # one message late, the next on time: both wait for the next tick
    t += PERIOD
    filt.push(robot.neutral_rad[None, :], t + 0.2 * PERIOD)
    filt.push(robot.neutral_rad[None, :], t + 0.4 * PERIOD)
    filt.tick(t + 0.5 * PERIOD)
    backlog = [filt.buffered]
    for _ in range(10):  # the stream goes on as before
        t += PERIOD
        filt.push(robot.neutral_rad[None, :], t)
        filt.tick(t)
        backlog.append(filt.buffered)
    assert backlog == [0] * 11  # no pose stands behind the commanded one: no added latency
    assert filt.status.skipped == 1  # the late one, overtaken by the next


def test_when_a_burst_arrives_expect_its_poses_played_one_a_period(robot):
    filt = MotionFilter(robot, MotionFilterSettings(backlog_window_s=1.0))
    filt.push(np.tile(robot.neutral_rad, (10, 1)), 0.0)  # a message of 10 poses
    left = []
    for tick in range(10):  # ticks up to half a period late: still one pose a tick
        filt.tick(tick * PERIOD + 0.5 * PERIOD * (tick % 2))
        left.append(filt.buffered)
    assert left == list(range(9, -1, -1))
    assert filt.status.skipped == 0


def test_when_poses_arrive_in_chunks_expect_nothing_skipped(robot):
    filt = MotionFilter(robot, MotionFilterSettings(backlog_window_s=0.5))
    t = 0.0
    for tick in range(500):  # 5 poses every 5 ticks: bursty but no standing backlog
        t += PERIOD
        if tick % 5 == 0:
            filt.push(np.tile(robot.neutral_rad, (5, 1)), t)
        filt.tick(t)
    assert filt.status.skipped == 0


def test_when_tracking_resumes_after_silence_expect_no_stale_poses_replayed(robot):
    filt = MotionFilter(robot, MotionFilterSettings(silence_timeout_s=0.1))
    stale = raised_pose(robot)
    t = 0.0
    filt.set_voice_active(False, t)
    for _ in range(50):  # the model keeps producing poses of silence
        t += PERIOD
        filt.push(stale[None, :], t)
        filt.tick(t)
    filt.set_voice_active(True, t)
    t += PERIOD
    filt.push(robot.neutral_rad[None, :], t)  # speech starts
    filt.tick(t)
    assert filt.status.buffered == 0
    np.testing.assert_allclose(filt.position_rad, filt.neutral_rad, atol=1e-3)


def test_when_voice_is_reported_on_change_only_expect_silence_counted_from_the_change(robot):
    """audio_features_node reports voice activity when it changes (less traffic), not every chunk.

    Before: silence counted from the last *report* of voice (t=0 here), so the filter glided to
    neutral at once when the voice stopped at t=1 s; after: from the report of silence.
    """
    settings = MotionFilterSettings(silence_timeout_s=0.2, neutral_glide_s=0.5)
    filt = MotionFilter(robot, settings)
    pose, t, modes = raised_pose(robot), 0.0, []
    filt.set_voice_active(True, t)  # the one report while the voice lasts
    for i in range(150):
        t += PERIOD
        if i == 100:
            filt.set_voice_active(False, t)  # the voice stopped at about t = 1 s
        filt.push(pose[None, :], t)
        filt.tick(t)
        modes.append(filt.status.mode)
    assert modes[:119] == ["tracking"] * 119  # tracking until 0.2 s after the change
    assert modes[-1] == "neutral"
