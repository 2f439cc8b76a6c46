"""Which pose the filter starts from, decided by what happened, not by how long start-up took.

The decision (:mod:`audio2pose_ros.motion.start_pose`) alone, then ``motion_filter_node`` in this
process with a controlled clock and controlled publishers on ``joint_states``
(:mod:`clocked_filter`). Without a measured pose the start waits, however long; with
``start_without_measured_pose``, a publisher discovered late, or one that has not sent its first
message yet, is waited for, one that sends nothing usable is not, and neither the saved pose nor
neutral is taken while a usable measured pose may still come.
"""

from __future__ import annotations

import numpy as np
import pytest
from clocked_filter import clocked_nodes, measured, moved_arm
from sensor_msgs.msg import JointState

from audio2pose_ros.motion.start_pose import (
    DISCOVERY_WAIT_S,
    HOLD,
    MEASURED_WAIT_S,
    NEUTRAL,
    SAVED,
    UNKNOWN,
    WAIT,
    StartPose,
    identity,
    repaired_start_pose,
)

TOPIC = "/joint_states"


# --- the decision alone -----------------------------------------------------------------------


def test_when_no_measured_pose_comes_expect_a_wait_however_long_and_why(tmp_path):
    """Not knowing where the robot is never moves it: no timeout makes the filter guess."""
    start = StartPose(created_s=0.0, reported_before=False, without_measured=False)
    for now_s in (1.0, 10.0, 3600.0):
        step = start.decide(now_s, "", TOPIC, saved="state.json")
        assert step.action == WAIT
        assert "no measured pose on /joint_states (no publisher)" in step.reason
        assert "commanding nothing" in step.reason
        assert "start_without_measured_pose" in step.reason
    start.discovered([b"driver"], 3600.0)
    start.heard(b"driver", "non-finite", 3600.1)
    step = start.decide(3700.0, "", TOPIC, saved="")
    assert step.action == WAIT
    assert "sent no usable pose of the robot (1 non-finite)" in step.reason


def test_when_a_publisher_is_discovered_late_expect_its_first_message_awaited_from_then():
    start = StartPose(created_s=0.0, reported_before=True, without_measured=True)
    start.discovered([], 1.0)
    assert start.decide(1.0, "", TOPIC, saved="state.json").action == WAIT  # the driver is awaited
    start.discovered([b"driver"], 8.0)  # discovery took 8 s on a loaded machine
    assert start.decide(8.0 + MEASURED_WAIT_S - 0.01, "", TOPIC, saved="state.json").action == WAIT
    step = start.decide(8.0 + MEASURED_WAIT_S, "", TOPIC, saved="state.json")
    assert step.action == SAVED
    assert "1 publisher(s) on /joint_states sent nothing" in step.reason
    assert "start_without_measured_pose is true" in step.reason


def test_when_the_silent_publisher_keeps_reappearing_expect_the_wait_bounded():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=True)
    now = 0.0
    while start.decide(now, "", TOPIC, saved="").action == WAIT:
        start.discovered([], now)  # it leaves the graph and comes back, never sending
        start.discovered([b"silent"], now)
        now += 0.5
    assert now <= DISCOVERY_WAIT_S + MEASURED_WAIT_S + 0.5


def test_when_every_publisher_sent_only_unusable_messages_expect_a_start_without_them():
    start = StartPose(created_s=0.0, reported_before=True, without_measured=True)
    start.discovered([b"gripper", b"driver"], 0.1)
    start.heard(b"gripper", "partial", 0.2)
    start.heard(b"driver", "non-finite", 0.3)
    start.heard(b"driver", "broken", 0.4)
    step = start.decide(1.0, "", TOPIC, saved="")
    assert step.action == NEUTRAL
    assert "sent no usable pose of the robot (1 broken, 1 non-finite, 1 partial)" in step.reason


def test_when_one_publisher_has_not_sent_yet_expect_a_wait_though_another_sent_junk():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=True)
    start.discovered([b"gripper", b"driver"], 0.5)
    start.heard(b"gripper", "partial", 0.6)
    assert start.decide(1.0, "", TOPIC, saved="state.json").action == WAIT
    assert start.decide(0.5 + MEASURED_WAIT_S, "", TOPIC, saved="state.json").action == SAVED


def test_when_a_usable_pose_just_arrived_expect_no_stand_in_even_after_the_waits():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=True)
    start.discovered([b"a", b"b"], 0.0)
    start.heard(b"a", "pose", 20.0)
    start.heard(b"b", "pose", 20.0)
    assert start.decide(20.5, "", TOPIC, saved="state.json").action == WAIT  # it is listening
    assert start.decide(21.5, "", TOPIC, saved="state.json").action == SAVED  # the pose stopped


def test_when_nothing_publishes_and_starting_without_is_chosen_expect_the_saved_pose_at_once():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=True)
    start.discovered([], 0.3)
    assert start.decide(0.3, "", TOPIC, saved="state.json").action == SAVED


def test_when_the_measured_pose_cannot_be_believed_expect_a_hold_whatever_else():
    for without_measured in (False, True):
        start = StartPose(created_s=0.0, reported_before=False, without_measured=without_measured)
        step = start.decide(100.0, "2 publishers send poses that disagree", TOPIC, saved="s.json")
        assert step.action == HOLD
        said = "cannot tell where the robot is: 2 publishers send poses that disagree"
        assert step.reason == said


def test_when_a_publisher_is_heard_before_the_graph_shows_it_expect_it_counted_and_listened_to():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=False)
    start.discovered([b"robot"], 0.5)  # the graph shows one publisher: the robot's driver
    start.heard(b"second", "pose", 0.6)  # another's message arrives before its discovery
    assert start.publishers == 2
    assert "2 publishers on /joint_states: listening" in start.listening(0.0, 0.6, TOPIC)
    start.heard(b"second", "pose", 1.7)
    said = start.listening(1.1, 1.7, TOPIC)  # heard long enough, but the robot is silent so far
    assert "1 of them silent so far" in said
    assert start.listening(3.6, 0.5 + MEASURED_WAIT_S, TOPIC) == ""  # the robot never sent


def test_when_messages_carry_no_gid_expect_them_one_of_the_discovered_publishers():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=False)
    start.discovered([b"driver"], 0.5)
    start.heard(UNKNOWN, "pose", 0.6)
    assert start.publishers == 1
    assert start.silent(0.6) == 0
    assert start.listening(0.0, 0.6, TOPIC) == ""  # the lone driver starts the filter at once
    start.discovered([b"driver", b"second"], 0.7)
    assert start.publishers == 2
    assert start.silent(0.7) == 1  # one of the two has not sent yet


def test_when_the_graph_and_a_message_give_one_gid_in_two_lengths_expect_one_publisher():
    start = StartPose(created_s=0.0, reported_before=False, without_measured=False)
    gid = bytes(range(1, 17))
    start.discovered([identity(list(gid))], 0.5)  # the graph: 16 bytes, as a list of ints
    start.heard(identity(gid + bytes(8)), "pose", 0.6)  # the message: padded to 24 bytes
    assert start.publishers == 1
    assert start.listening(0.0, 0.6, TOPIC) == ""


def test_when_a_measured_pose_holds_nan_and_out_of_range_expect_each_repaired_and_named():
    lower, upper = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    pose, repairs = repaired_start_pose(
        np.array([0.5, 1.2, np.nan]), ("a", "b", "c"), lower, upper, np.zeros(3), "saved pose"
    )
    np.testing.assert_array_equal(pose, [0.5, 1.0, 0.0])
    assert [(r.joints, r.how) for r in repairs] == [
        (("b",), "out of range, clamped into it"),
        (("c",), "not finite, taken from the saved pose"),
    ]


# --- the node, with a controlled clock ---------------------------------------------------------


@pytest.fixture
def clocked(tmp_path, monkeypatch, robot):
    """motion_filter_node on a controlled clock and graph (:func:`clocked_nodes`)."""
    yield from clocked_nodes(tmp_path, monkeypatch, robot)


@pytest.fixture
def clocked_node(clocked):
    """A saved pose, measured before; the start waits for a measured pose."""
    return clocked()


@pytest.mark.ros
def test_when_the_driver_is_discovered_after_3_s_expect_the_start_from_its_pose(
    clocked_node, robot
):
    """The flake of a loaded machine: discovery took longer than the old fixed 3 s wait."""
    node, clock, graph, _ = clocked_node
    clock.now, graph.publishers = 1.0, []
    node.on_startup_timeout()  # startup_timeout_s passed: nothing discovered yet
    clock.now, graph.publishers = 3.5, [1]
    node.on_startup_timeout()  # discovered now: its first message is on the way
    assert not node.started
    said = node.current_problems()["start_pose"][1]
    assert "1 publisher(s) on joint_states sent nothing yet" in said
    clock.now = 3.6
    node.on_measured(*measured(robot, moved_arm(robot)))
    assert node.started_from == "measured pose"
    np.testing.assert_allclose(node.filter.position_rad, moved_arm(robot))
    first, _ = node.filter.tick(3.61)
    assert np.abs(first - moved_arm(robot)).max() < 0.02  # never a command far from the robot


@pytest.mark.ros
def test_when_a_discovered_publisher_sends_nothing_expect_the_saved_pose_after_its_wait(
    clocked, robot
):
    node, clock, graph, saved = clocked(without=True)
    clock.now, graph.publishers = 2.5, [1]
    node.on_startup_timeout()
    clock.now = 2.5 + MEASURED_WAIT_S - 0.1
    node.on_startup_timeout()
    assert not node.started  # three seconds after its discovery have not passed yet
    clock.now = 2.5 + MEASURED_WAIT_S
    node.on_startup_timeout()
    assert node.started_from == SAVED
    np.testing.assert_allclose(node.filter.position_rad, saved)
    message = node.current_problems()["start_pose"][1]
    said = (
        "1 publisher(s) on joint_states sent nothing; start_without_measured_pose is true: "
        "started from the last commanded pose"
    )
    assert f"{said} saved in {node.state_path}" in message


@pytest.mark.ros
def test_when_the_only_publisher_sends_unusable_poses_expect_a_start_without_it_said(
    clocked, robot
):
    node, clock, graph, _ = clocked(without=True)
    clock.now, graph.publishers = 0.5, [1]
    node.on_measured(*measured(robot, np.full(robot.n_joints, np.nan)))
    node.on_measured(*measured(robot, np.full(robot.n_joints, np.nan)))
    clock.now = 1.0
    node.on_startup_timeout()
    assert node.started_from == SAVED  # no three-second wait for a pose that is not coming
    message = node.current_problems()["start_pose"][1]
    assert "sent no usable pose of the robot (2 non-finite)" in message


@pytest.mark.ros
def test_when_the_start_listens_for_a_second_source_expect_no_stand_in_meanwhile(
    clocked_node, robot
):
    node, clock, graph, _ = clocked_node
    graph.publishers = [1, 2]  # the driver and a gripper
    clock.now = 3.0
    node.on_measured(*measured(robot, moved_arm(robot)))  # listening 1 s first
    clock.now = 3.2
    node.on_startup_timeout()
    assert not node.started  # the measured pose is arriving: not the saved one
    gripper = JointState(name=["LHand"], position=[0.5])
    node.on_measured(gripper, {"publisher_gid": {"data": bytes([2] * 16)}, "source_timestamp": 0})
    clock.now = 4.1
    node.on_measured(*measured(robot, moved_arm(robot)))
    assert node.started_from == "measured pose"
