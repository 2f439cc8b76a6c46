"""When the motion filter ticks and publishes each output (motion.pacing), without ROS."""

import pytest

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.pacing import (
    MIN_TICK_SPACING,
    OutputPacing,
    arrival_wait_s,
    next_timer_s,
)

PERIOD = 0.01  # 100 Hz filter clock


def test_when_ticking_at_100_hz_expect_a_50_hz_output_every_other_tick_and_off_never():
    pacing = OutputPacing(
        {"joint_angles": 50.0, "joint_states": 100.0, "joint_trajectory": 0.0}, 100.0
    )
    assert pacing.spacing_s["joint_angles"] == pytest.approx(0.015)  # documented minimum
    due = [pacing.due(k * PERIOD) for k in range(6)]
    assert [("joint_angles" in d) for d in due] == [True, False, True, False, True, False]
    assert all("joint_states" in d for d in due)
    assert not any("joint_trajectory" in d for d in due)


def test_when_ticks_come_late_expect_the_output_at_the_tick_nearest_its_period():
    pacing = OutputPacing({"joint_angles": 50.0}, 100.0)
    assert pacing.due(0.0) == ["joint_angles"]
    assert pacing.due(0.014) == []  # under period minus half a filter period
    assert pacing.due(0.016) == ["joint_angles"]  # a late tick: published, counted from there
    assert pacing.due(0.030) == []


def test_when_an_output_is_faster_than_the_filter_expect_refused_naming_the_parameter():
    with pytest.raises(ConfigurationError, match=r"joint_states_rate_hz.*rate_hz = 100"):
        OutputPacing({"joint_angles": 50.0, "joint_states": 200.0}, 100.0)


def test_when_a_pose_arrives_expect_a_tick_at_once_or_once_the_spacing_allows():
    assert arrival_wait_s(last_tick_s=1.0, arrival_s=1.0 + PERIOD, period_s=PERIOD) == 0.0
    wait = arrival_wait_s(last_tick_s=1.0, arrival_s=1.001, period_s=PERIOD)
    assert wait == pytest.approx(MIN_TICK_SPACING * PERIOD - 0.001)
    assert next_timer_s(PERIOD, queued=True) == PERIOD
    assert next_timer_s(PERIOD, queued=False) == pytest.approx(2.0 * PERIOD)
