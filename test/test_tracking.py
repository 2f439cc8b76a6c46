"""TrackingWatch: a robot that lags its commands is fine; one that does not follow is found."""

from __future__ import annotations

import numpy as np
import pytest

from audio2pose_ros.motion.tracking import (
    TRACKING_HOLD_S,
    TRACKING_LAG_S,
    TRACKING_TOLERANCE_RAD,
    TrackingWatch,
)

PERIOD = 0.01


def sweep(t: float) -> np.ndarray:
    """A fast gesture: 1 rad amplitude at 1 Hz on joint 1 (6.3 rad/s peak), others still."""
    return np.array([0.0, np.sin(2 * np.pi * t), 0.2])


def run(watch: TrackingWatch, seconds: float, measured_at, start_s: float = 0.0):
    """Command ``sweep`` every period and measure ``measured_at(t)`` every 5th; all findings."""
    findings = []
    for i in range(round(seconds / PERIOD)):
        t = start_s + i * PERIOD
        watch.command(sweep(t), t)
        if i % 5 == 0:
            findings.append(watch.measure(measured_at(t), t))
    return findings


def test_when_robot_follows_with_a_lag_expect_nothing_reported():
    watch = TrackingWatch()
    lag = 0.8 * TRACKING_LAG_S
    findings = run(watch, 5.0, lambda t: sweep(max(t - lag, 0.0)))
    assert findings == [None] * len(findings)
    assert watch.off_rad <= TRACKING_TOLERANCE_RAD


def test_when_robot_stays_put_expect_the_joint_reported_after_the_hold():
    """Joint 1 rests at 1.5 rad (an arm hanging) while commanded within [-1, 1]."""
    watch = TrackingWatch()
    findings = run(watch, 3.0, lambda t: np.array([0.0, 1.5, 0.2]))
    first = next(i for i, f in enumerate(findings) if f is not None)
    assert first * 5 * PERIOD == pytest.approx(TRACKING_HOLD_S, abs=0.06)
    last = findings[-1]
    assert last is not None
    assert last.joint == 1
    assert last.off_rad > TRACKING_TOLERANCE_RAD
    assert last.for_s >= TRACKING_HOLD_S


def test_when_robot_follows_again_expect_the_finding_gone_and_the_hold_restarted():
    watch = TrackingWatch()
    assert run(watch, 2.0, lambda t: np.zeros(3))[-1] is not None
    assert run(watch, 0.5, sweep, start_s=2.0)[-1] is None
    stuck = run(watch, 0.9 * TRACKING_HOLD_S, lambda t: np.array([0.0, 5.0, 0.2]), start_s=2.5)
    assert stuck == [None] * len(stuck)  # off again, but not for a whole hold yet


def test_when_nothing_was_commanded_lately_expect_no_finding():
    watch = TrackingWatch(hold_s=0.05)
    assert watch.measure(np.zeros(3), 0.0) is None  # never commanded
    watch.command(np.ones(3), 0.0)
    assert watch.measure(np.zeros(3), 0.1) is None  # off: the hold starts
    assert watch.measure(np.zeros(3), 0.2) is not None
    assert watch.measure(np.zeros(3), TRACKING_LAG_S + 0.01) is None  # commands stopped


@pytest.mark.parametrize(
    "pose", [np.full(3, np.nan), np.array([0.0, np.inf, 0.0]), np.zeros(4), np.zeros(())]
)
def test_when_measured_pose_is_unusable_expect_no_finding_and_no_error(pose):
    watch = TrackingWatch(hold_s=0.05)
    watch.command(np.ones(3), 0.0)
    watch.measure(np.zeros(3), 0.0)
    assert watch.measure(pose, 0.1) is None
    assert watch.off_rad == 0.0


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_when_a_setting_is_not_positive_expect_value_error(bad):
    for kwargs in ({"tolerance_rad": bad}, {"lag_s": bad}, {"hold_s": bad}):
        with pytest.raises(ValueError, match="must be positive"):
            TrackingWatch(**kwargs)


def test_commands_older_than_the_lag_are_forgotten():
    watch = TrackingWatch(hold_s=0.01)
    watch.command(np.full(3, 1.0), 0.0)  # the robot was told 1 rad long ago...
    for i in range(1, 100):
        watch.command(np.zeros(3), i * PERIOD)
    watch.measure(np.full(3, 1.0), 0.99)
    assert watch.measure(np.full(3, 1.0), 0.99 + PERIOD) is not None  # ...which no longer counts
