"""What a measured joint state means for the motion filter (motion.measured_states), no ROS.

The node's use of these (reports, the start) is tested in test_start_pose.py and
test_motion_filter_inputs.py; here the core's answers alone: which problems, which start pose.
"""

import numpy as np
import pytest

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.measured_states import MeasuredStates

NOW = 1.7e9  # node clock (s since the epoch)
TOPIC = "joint_states"


@pytest.fixture
def states(robot):
    return MeasuredStates(robot, now_s=0.0, measured_before=False, without_measured=False)


def take(
    states,
    robot,
    pose,
    started=False,
    arrival_s=0.1,
    source=b"a",
    publishers=(b"a",),  # the graph's publishers of the topic
    saved=None,
    names=None,
    stamp_s=NOW,
):
    return states.take(
        list(robot.names) if names is None else names,
        [float(v) for v in pose],
        stamp_s,
        None,
        NOW,
        source,
        arrival_s,
        started,
        TOPIC,
        lambda: publishers,
        lambda: saved,
    )


def keys(use):
    return [(p.key, p.error) for p in use.problems]


def test_when_a_usable_pose_comes_first_expect_it_the_start_and_the_start_problem_cleared(
    states, robot
):
    use = take(states, robot, robot.neutral_rad + 0.05)
    np.testing.assert_allclose(use.start_rad, robot.neutral_rad + 0.05)
    assert use.cleared == ["start_pose"]
    assert use.problems == []
    np.testing.assert_allclose(states.pose_rad, robot.neutral_rad + 0.05)


def test_when_a_joint_is_not_finite_expect_it_from_the_saved_pose_and_a_warn(states, robot):
    pose = robot.neutral_rad.copy()
    pose[0] = np.nan
    saved = robot.neutral_rad + 0.02
    use = take(states, robot, pose, saved=saved)
    assert use.start_rad[0] == saved[0]
    assert keys(use) == [("measured_invalid", False)]
    assert "saved pose" in use.problems[0].text


def test_when_refused_before_the_start_expect_a_warn_and_the_start_held_as_error(states, robot):
    use = take(states, robot, robot.neutral_rad, stamp_s=NOW - 60.0)
    assert use.start_rad is None
    assert keys(use) == [("measured_refused", False), ("start_pose", True)]
    assert states.doubt(0.2) == states.check.last_reason != ""


def test_when_refused_after_the_start_expect_only_the_warn(states, robot):
    use = take(states, robot, robot.neutral_rad, started=True, stamp_s=NOW - 60.0)
    assert keys(use) == [("measured_refused", False)]


def test_when_another_robots_joints_arrive_expect_them_counted_not_used(states, robot):
    use = take(states, robot, [0.0], names=["KneePitch"])
    assert (use.start_rad, use.problems, states.partial) == (None, [], 1)
    assert states.values(0.2, robot.neutral_rad)["measured_partial_messages"] == 1


def test_when_two_sources_disagree_expect_an_error_and_neither_used(states, robot):
    take(states, robot, robot.neutral_rad, started=True, source=b"a")
    use = take(states, robot, robot.neutral_rad + 0.5, started=True, source=b"b", arrival_s=0.2)
    assert keys(use) == [("measured_sources", True)]
    assert states.conflicts == 1
    assert "disagree" in states.doubt(0.3)


def test_when_several_publishers_expect_the_start_to_listen_first(states, robot):
    use = take(states, robot, robot.neutral_rad, publishers=(b"a", b"b"))
    assert use.start_rad is None
    assert keys(use) == [("start_pose", False)]


def test_when_a_message_is_broken_expect_input_error_and_the_start_told(states, robot):
    with pytest.raises(InputError):
        take(states, robot, [0.0], names=["HeadYaw", "HeadPitch"])
    assert states.check.counts.poses == 0


def test_when_the_robot_does_not_follow_expect_a_warn_then_cleared_when_it_does(states, robot):
    commanded = robot.neutral_rad + 0.3
    for k in range(300):
        states.tracking.command(commanded, k * 0.01)
    use = take(states, robot, robot.neutral_rad, started=True, arrival_s=1.5)
    assert keys(use) == []  # off, not yet for long
    use = take(states, robot, robot.neutral_rad, started=True, arrival_s=2.99)
    assert keys(use) == [("not_following", False)]
    use = take(states, robot, commanded, started=True, arrival_s=3.0)
    assert use.cleared == ["not_following"]
    values = states.values(3.0, commanded)
    assert values["measured_deviation_rad"] == "0.000"
