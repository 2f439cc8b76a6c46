"""When the motion filter ticks and publishes each output (motion.pacing), without ROS."""

import numpy as np
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
    assert pacing.spacing_s["joint_angles"] == pytest.approx(0.010)  # documented minimum
    due = [pacing.due(k * PERIOD) for k in range(6)]
    assert [("joint_angles" in d) for d in due] == [True, False, True, False, True, False]
    assert all("joint_states" in d for d in due)
    assert not any("joint_trajectory" in d for d in due)


def test_when_ticks_come_late_expect_the_output_at_the_first_tick_near_its_due_time():
    pacing = OutputPacing({"joint_angles": 50.0}, 100.0)
    assert pacing.due(0.0) == ["joint_angles"]
    assert pacing.due(0.014) == []  # over half a filter period before it is due (0.020)
    assert pacing.due(0.026) == ["joint_angles"]  # a late tick: published; next due 0.040
    assert pacing.due(0.034) == []
    assert pacing.due(0.036) == ["joint_angles"]  # its phase kept: 10 ms after the late one
    assert pacing.due(0.045) == []  # never closer than the period less a filter period


def test_when_every_tick_is_late_expect_the_output_rate_kept_on_average():
    """Ticks every 13 ms (a loaded machine): 50 Hz on average, not every other tick (38 Hz)."""
    pacing = OutputPacing({"joint_angles": 50.0}, 100.0)
    published = [k * 0.013 for k in range(800) if pacing.due(k * 0.013)]
    spacing = np.diff(published)
    assert np.mean(spacing) == pytest.approx(0.020, abs=0.0005)
    assert spacing.min() >= 0.010 - 1e-9


def test_when_the_ticks_stall_expect_no_burst_to_catch_up():
    pacing = OutputPacing({"joint_angles": 50.0}, 100.0)
    assert pacing.due(0.0) == ["joint_angles"]
    assert pacing.due(0.100) == ["joint_angles"]  # after a 100 ms stall
    ticks = [0.110, 0.120, 0.130, 0.140]
    assert [bool(pacing.due(t)) for t in ticks] == [False, True, False, True]


def test_when_an_output_is_faster_than_the_filter_expect_refused_naming_the_parameter():
    with pytest.raises(ConfigurationError, match=r"joint_states_rate_hz.*rate_hz = 100"):
        OutputPacing({"joint_angles": 50.0, "joint_states": 200.0}, 100.0)


def test_when_a_pose_arrives_expect_a_tick_at_once_or_once_the_spacing_allows():
    assert arrival_wait_s(last_tick_s=1.0, arrival_s=1.0 + PERIOD, period_s=PERIOD) == 0.0
    wait = arrival_wait_s(last_tick_s=1.0, arrival_s=1.001, period_s=PERIOD)
    assert wait == pytest.approx(MIN_TICK_SPACING * PERIOD - 0.001)
    assert next_timer_s(PERIOD, queued=True) == PERIOD
    assert next_timer_s(PERIOD, queued=False) == pytest.approx(2.0 * PERIOD)
