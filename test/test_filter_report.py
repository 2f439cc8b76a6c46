"""The motion filter's figures for /diagnostics (motion.filter_report), without ROS."""

import numpy as np

from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_report import FilterReport


def test_when_poses_arrive_between_reports_expect_rate_of_those_since_the_previous_report(robot):
    filt = MotionFilter(robot)
    report = FilterReport(filt, now_s=10.0)
    filt.push(np.tile(robot.neutral_rad, (50, 1)), 10.0)
    first = report.values(now_s=11.0)
    assert first["poses_received"] == 50
    assert first["input_rate_hz"] == "50.0"
    filt.push(np.tile(robot.neutral_rad, (10, 1)), 11.0)
    assert report.values(now_s=13.0)["input_rate_hz"] == "5.0"  # 10 poses in 2 s
    assert report.values(now_s=14.0)["input_rate_hz"] == "0.0"


def test_when_poses_are_rejected_expect_them_counted_by_reason(robot):
    filt = MotionFilter(robot)
    bad = np.tile(robot.neutral_rad, (3, 1))
    bad[0, 0] = np.nan
    bad[1, 0] = robot.upper_rad[0] + 1.0
    filt.push(bad, 0.0)
    values = FilterReport(filt, 0.0).values(1.0)
    assert (values["poses_rejected"], values["poses_out_of_range"]) == (1, 1)
    assert values["command_finite_and_in_limits"] is True


def test_when_the_command_leaves_a_joint_range_expect_it_reported_as_not_in_limits(robot):
    filt = MotionFilter(robot)
    report = FilterReport(filt, 0.0)
    assert report.values(1.0)["command_finite_and_in_limits"] is True
    filt.position_rad[0] = robot.upper_rad[0] + 0.1  # as a broken filter would command
    assert report.values(2.0)["command_finite_and_in_limits"] is False


def test_when_commands_pass_on_the_travel_bound_expect_the_clearance_reported_as_a_bound(robot):
    """Far from the body the guard's clearance is its travel bound, and the report says so."""
    filt = MotionFilter(robot)
    report = FilterReport(filt, 0.0)
    t = 0.0
    for _ in range(20):
        t += filt.period_s
        filt.push(robot.neutral_rad[None, :], t)
        filt.tick(t)
    values = report.values(t)
    assert values["body_clearance_exact"] is False
    assert values["body_guard_bound_checks"] > 10
    exact = float(filt.body_guard.body.clearance(filt.position_rad))
    assert float(values["body_clearance_cm"]) <= round(exact * 100.0, 1)
    assert " / " in values["body_closest_links"]
