"""Run-time settings requests of the motion filter: validated at once, applied when taken."""

import pytest

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.filter import MotionFilter


def test_when_requested_expect_nothing_changed_until_taken(robot):
    filt = MotionFilter(robot)
    filt.request_settings({"velocity_fraction": 0.3, "head_gain": 0.5, "neutral_glide_s": 2.0})
    assert filt.limiter.settings.velocity_fraction != 0.3
    filt.take_requested_settings()
    assert filt.limiter.settings.velocity_fraction == 0.3
    assert filt.style.settings.head_gain == 0.5
    assert filt.settings.neutral_glide_s == 2.0


def test_when_two_requests_come_before_a_take_expect_both_applied_newest_winning(robot):
    filt = MotionFilter(robot)
    filt.request_settings({"velocity_fraction": 0.3, "neutral_glide_s": 2.0})
    filt.request_settings({"velocity_fraction": 0.4})
    applied = []
    update = filt.update_settings
    filt.update_settings = lambda *a: (applied.append(a), update(*a))[1]
    filt.take_requested_settings()
    filt.take_requested_settings()  # nothing pending any more
    assert len(applied) == 1
    assert (filt.limiter.settings.velocity_fraction, filt.settings.neutral_glide_s) == (0.4, 2.0)


def test_when_a_request_restores_the_running_settings_expect_nothing_pending(robot):
    filt = MotionFilter(robot)
    running = filt.limiter.settings.velocity_fraction
    filt.request_settings({"velocity_fraction": 0.3})
    filt.request_settings({"velocity_fraction": running})
    applied = []
    filt.update_settings = lambda *a: applied.append(a)
    filt.take_requested_settings()
    assert applied == []


def test_when_a_request_is_refused_expect_the_pending_one_kept(robot):
    filt = MotionFilter(robot)
    filt.request_settings({"velocity_fraction": 0.3})
    with pytest.raises(ConfigurationError, match="rate_hz"):
        filt.request_settings({"rate_hz": 50.0})  # read-only while running
    filt.take_requested_settings()
    assert filt.limiter.settings.velocity_fraction == 0.3
    assert filt.settings.rate_hz != 50.0
