"""Which pose the filter starts from, decided by what happened, not by how long start-up took.

The decision (:mod:`audio2pose_ros.motion.start_pose`) alone, then ``motion_filter_node`` in this
process with a controlled clock and a controlled count of publishers on ``joint_states``: each
message and each start-up check goes through the callback the executor would call, in a fixed
order. A publisher discovered late, or one that has not sent its first message yet, is waited
for; one that sends nothing usable is not; neither the saved pose nor neutral is taken while a
usable measured pose may still come.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from sensor_msgs.msg import JointState

from audio2pose_ros.motion.start_pose import (
    DISCOVERY_WAIT_S,
    HOLD,
    MEASURED_WAIT_S,
    NEUTRAL,
    SAVED,
    WAIT,
    StartPose,
    repaired_start_pose,
)
from audio2pose_ros.motion.state_file import FilterMemory, save_memory

TOPIC = "/joint_states"


# --- the decision alone -----------------------------------------------------------------------


def test_when_a_publisher_is_discovered_late_expect_its_first_message_awaited_from_then():
    start = StartPose(created_s=0.0, reported_before=True)
    start.discovered(0, 1.0)
    assert start.decide(1.0, "", TOPIC, saved="state.json").action == WAIT  # the driver is awaited
    start.discovered(1, 8.0)  # discovery took 8 s on a loaded machine
    assert start.decide(8.0 + MEASURED_WAIT_S - 0.01, "", TOPIC, saved="state.json").action == WAIT
    step = start.decide(8.0 + MEASURED_WAIT_S, "", TOPIC, saved="state.json")
    assert step.action == SAVED
    assert "1 publisher(s) on /joint_states sent nothing" in step.reason


def test_when_the_silent_publisher_keeps_reappearing_expect_the_wait_bounded():
    start = StartPose(created_s=0.0, reported_before=False)
    now = 0.0
    while start.decide(now, "", TOPIC, saved="").action == WAIT:
        start.discovered(0, now)  # it leaves the graph and comes back, never sending
        start.discovered(1, now)
        now += 0.5
    assert now <= DISCOVERY_WAIT_S + MEASURED_WAIT_S + 0.5


def test_when_every_publisher_sent_only_unusable_messages_expect_a_start_without_them():
    start = StartPose(created_s=0.0, reported_before=True)
    start.discovered(2, 0.1)
    start.heard("gripper", "partial", 0.2)
    start.heard("driver", "non-finite", 0.3)
    start.heard("driver", "broken", 0.4)
    step = start.decide(1.0, "", TOPIC, saved="")
    assert step.action == NEUTRAL
    assert "sent no usable pose of the robot (1 broken, 1 non-finite, 1 partial)" in step.reason


def test_when_one_publisher_has_not_sent_yet_expect_a_wait_though_another_sent_junk():
    start = StartPose(created_s=0.0, reported_before=False)
    start.discovered(2, 0.5)
    start.heard("gripper", "partial", 0.6)
    assert start.decide(1.0, "", TOPIC, saved="state.json").action == WAIT
    assert start.decide(0.5 + MEASURED_WAIT_S, "", TOPIC, saved="state.json").action == SAVED


def test_when_a_usable_pose_just_arrived_expect_no_stand_in_even_after_the_waits():
    start = StartPose(created_s=0.0, reported_before=False)
    start.discovered(2, 0.0)
    start.heard("a", "pose", 20.0)
    start.heard("b", "pose", 20.0)
    assert start.decide(20.5, "", TOPIC, saved="state.json").action == WAIT  # it is listening
    assert start.decide(21.5, "", TOPIC, saved="state.json").action == SAVED  # the pose stopped


def test_when_nothing_publishes_and_nothing_was_reported_expect_the_saved_pose_at_once():
    start = StartPose(created_s=0.0, reported_before=False)
    start.discovered(0, 0.3)
    assert start.decide(0.3, "", TOPIC, saved="state.json").action == SAVED


def test_when_the_measured_pose_cannot_be_believed_expect_a_hold_whatever_else():
    start = StartPose(created_s=0.0, reported_before=False)
    step = start.decide(100.0, "2 publishers send poses that disagree", TOPIC, saved="state.json")
    assert step.action == HOLD
    assert step.reason == "cannot tell where the robot is: 2 publishers send poses that disagree"


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
def clocked_node(tmp_path, monkeypatch, robot):
    """Build motion_filter_node on a controlled monotonic clock; a saved pose, measured before.

    Returns (node, clock, graph): set ``clock.now`` and ``graph.publishers`` before each call.
    """
    from audio2pose_ros.ros.nodes import motion_filter_node as module

    clock = SimpleNamespace(now=0.0)
    graph = SimpleNamespace(publishers=0)
    monkeypatch.setattr(
        module, "time", SimpleNamespace(monotonic=lambda: clock.now, time=time.time)
    )
    monkeypatch.setattr(
        module.MotionFilterNode, "count_publishers", lambda self, topic: graph.publishers
    )
    state = tmp_path / "state.json"
    saved = robot.neutral_rad.copy()
    save_memory(
        state,
        FilterMemory(
            tuple(robot.names), tuple(float(v) for v in saved), False, time.time(), measured=True
        ),
    )
    context = rclpy.init(args=["--ros-args", "-p", f"state_file:={state}"])
    node = module.MotionFilterNode(subscribe_graph=False)
    yield node, clock, graph, saved
    node.destroy_node()
    if context is not None:
        rclpy.try_shutdown()


def measured(robot, pose, gid: int = 1):
    message = JointState(name=list(robot.names), position=[float(v) for v in pose])
    return message, {"publisher_gid": {"data": bytes([gid] * 24)}, "source_timestamp": 0}


def moved_arm(robot) -> np.ndarray:
    """Where the robot is: its left arm moved 0.6 rad while the filter was down."""
    pose = robot.neutral_rad.copy()
    pose[robot.names.index("LShoulderPitch")] -= 0.6
    return pose


@pytest.mark.ros
def test_when_the_driver_is_discovered_after_3_s_expect_the_start_from_its_pose(
    clocked_node, robot
):
    """The flake of a loaded machine: discovery took longer than the old fixed 3 s wait."""
    node, clock, graph, _ = clocked_node
    clock.now, graph.publishers = 1.0, 0
    node.on_startup_timeout()  # startup_timeout_s passed: nothing discovered yet
    clock.now, graph.publishers = 3.5, 1
    node.on_startup_timeout()  # discovered now: its first message is on the way
    assert not node.started
    assert "sent nothing yet" in node.current_problems()["start_pose"][1]
    clock.now = 3.6
    node.on_measured(*measured(robot, moved_arm(robot)))
    assert node.started_from == "measured pose"
    np.testing.assert_allclose(node.filter.position_rad, moved_arm(robot))
    first, _ = node.filter.tick(3.61)
    assert np.abs(first - moved_arm(robot)).max() < 0.02  # never a command far from the robot


@pytest.mark.ros
def test_when_a_discovered_publisher_sends_nothing_expect_the_saved_pose_after_its_wait(
    clocked_node, robot
):
    node, clock, graph, saved = clocked_node
    clock.now, graph.publishers = 2.5, 1
    node.on_startup_timeout()
    clock.now = 2.5 + MEASURED_WAIT_S - 0.1
    node.on_startup_timeout()
    assert not node.started  # three seconds after its discovery have not passed yet
    clock.now = 2.5 + MEASURED_WAIT_S
    node.on_startup_timeout()
    assert node.started_from == SAVED
    np.testing.assert_allclose(node.filter.position_rad, saved)
    message = node.current_problems()["start_pose"][1]
    said = "1 publisher(s) on joint_states sent nothing: started from the last commanded pose"
    assert f"{said} saved in {node.state_path}" in message


@pytest.mark.ros
def test_when_the_only_publisher_sends_unusable_poses_expect_a_start_without_it_said(
    clocked_node, robot
):
    node, clock, graph, _ = clocked_node
    clock.now, graph.publishers = 0.5, 1
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
    graph.publishers = 2  # the driver and a gripper
    clock.now = 3.0
    node.on_measured(*measured(robot, moved_arm(robot)))  # listening 1 s first
    clock.now = 3.2
    node.on_startup_timeout()
    assert not node.started  # the measured pose is arriving: not the saved one
    clock.now = 4.1
    node.on_measured(*measured(robot, moved_arm(robot)))
    assert node.started_from == "measured pose"
