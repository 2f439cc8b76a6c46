"""The online motion filter core: pacing, group gains, watchdog to neutral, limits last."""

import numpy as np
import pytest

from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings

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


def test_when_no_input_ever_expect_neutral_and_watchdog_active(robot):
    filt = MotionFilter(robot)
    out = run(filt, np.empty((0, 11)), extra_ticks=10)
    np.testing.assert_allclose(
        out[-1],
        np.clip(robot.neutral_rad, robot.lower_rad + 0.01, robot.upper_rad - 0.01),
        atol=1e-9,
    )
    assert filt.status.watchdog_active


def test_when_input_stops_expect_glide_to_neutral_within_timeout_plus_settling(robot):
    settings = MotionFilterSettings(watchdog_timeout_s=0.3)
    filt = MotionFilter(robot, settings)
    raised = robot.neutral_rad.copy()
    raised[robot.names.index("LShoulderPitch")] -= 0.8  # forearm up
    out = run(filt, np.tile(raised, (200, 1)), extra_ticks=300)
    joint = robot.names.index("LShoulderPitch")
    assert out[199, joint] == pytest.approx(raised[joint], abs=0.02)  # tracked while speaking
    assert out[-1, joint] == pytest.approx(robot.neutral_rad[joint], abs=0.01)  # back at rest
    assert filt.status.watchdog_active
    steps = np.abs(np.diff(out[:, joint])) / PERIOD
    assert steps.max() <= filt.limiter.max_velocity_rad_s[joint] + 1e-9  # no jump


def test_when_arms_gain_zero_expect_arms_at_neutral_head_moving(robot):
    filt = MotionFilter(robot, MotionFilterSettings(arms_gain=0.0))
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


def test_when_settings_invalid_expect_value_error():
    with pytest.raises(ValueError, match="smoothing 'median' is not one of"):
        MotionFilterSettings(smoothing="median")
    with pytest.raises(ValueError, match="arms_gain must be in"):
        MotionFilterSettings(arms_gain=2.0)
