"""Which raw poses reach the motion filter (motion.raw_intake), without ROS."""

import numpy as np
import pytest

from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.raw_intake import RawIntake

NOW = 1.7e9  # node clock (s since the epoch)


@pytest.fixture
def intake(robot):
    filt = MotionFilter(robot, MotionFilterSettings(max_points_per_message=5))
    return RawIntake(filt, handover_s=0.5, max_future_s=1.0, max_age_s=1.0)


def keys(problems):
    return [(p.key, p.error) for p in problems]


def test_when_not_started_expect_nothing_taken_and_nothing_reported(intake):
    assert intake.admit(NOW, 3, NOW, started=False) == (None, [])
    assert (intake.messages, intake.dropped) == (1, 0)


def test_when_a_message_is_long_expect_the_first_points_and_a_warn(intake):
    take, problems = intake.admit(NOW, 8, NOW, started=True)
    assert take == 5
    assert keys(problems) == [("raw_truncated", False)]
    assert intake.filter.status.truncated == 3


def test_when_stamps_are_refused_expect_dropped_counted_by_reason(intake):
    assert intake.admit(NOW + 60.0, 1, NOW, started=True)[0] is None
    assert intake.admit(NOW - 0.5, 1, NOW, started=True)[0] == 1
    take, problems = intake.admit(NOW - 0.6, 1, NOW, started=True)  # older than the last
    assert take is None
    assert keys(problems) == [("raw_stamp", False)]
    values = intake.values()
    assert (values["future_stamps_rejected"], values["stale_messages_dropped"]) == (1, 1)
    assert (values["input_messages"], values["dropped_messages"]) == (3, 2)
    assert values["input_latency_ms"] == "500.00"


def test_when_the_clock_steps_back_expect_a_warn_and_the_next_stamp_taken(intake):
    intake.admit(NOW, 1, NOW, started=True)
    take, problems = intake.admit(NOW - 100.0, 1, NOW - 100.0, started=True)
    assert take == 1
    assert keys(problems) == [("clock_step", False)]


def test_when_a_second_source_sends_expect_an_error_until_the_first_is_quiet(intake):
    assert intake.from_source(b"first", 0.0) is None
    refused = intake.from_source(b"second", 0.1)
    assert (refused.key, refused.error) == ("raw_second_source", True)
    assert intake.from_source(b"second", 0.7) is None  # the first quiet for longer than 0.5 s
    assert intake.values()["raw_messages_of_a_second_source"] == 1
    assert intake.dropped == 1


def test_when_the_gate_rejects_poses_expect_a_warn_with_the_totals(intake, robot):
    good = np.tile(robot.neutral_rad, (2, 1))
    assert intake.push(good, 0.0) is None
    bad = good.copy()
    bad[0, 0] = np.nan
    problem = intake.push(bad, 0.01)
    assert problem.key == "raw_rejected"
    assert "1 non-finite" in problem.text
    assert intake.malformed("point 0 has 3 positions").key == "raw_malformed"
    assert intake.dropped == 1


def test_when_a_trajectory_lists_a_joint_twice_expect_it_refused_and_counted(intake, robot):
    """The last HeadYaw of the message said 0.25 rad more: it was taken in 150 of 150."""
    names = [*robot.names, "HeadYaw"]
    refused = intake.joint_names(names)
    assert (refused.key, refused.error) == ("raw_names", False)
    assert "lists HeadYaw more than once" in refused.text
    assert intake.joint_names(list(robot.names)) is None
    assert intake.joint_names(names) is not None  # not taken because the last names were
    values = intake.values()
    assert values["raw_refused_duplicate_names"] == 2
    assert values["raw_refused_unknown_names"] == 0
    assert values["dropped_messages"] == 2


def test_when_a_trajectory_names_a_joint_the_robot_lacks_expect_it_refused_and_counted(
    intake, robot
):
    refused = intake.joint_names([*robot.names, "LWristYaw", "x" * 1000])
    assert "names 2 joint(s) this robot does not have (LWristYaw, xxx" in refused.text
    assert len(refused.text) < 200  # a name of any length is quoted short
    assert intake.values()["raw_refused_unknown_names"] == 1
    assert intake.dropped == 1
