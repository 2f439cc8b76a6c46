"""motion_filter_node in this process, fed through its own callbacks: inputs at their worst.

The robot's measured pose at a joint limit, a speed for ``JointAnglesWithSpeed`` that the robot
refuses, and joint states whose names and positions disagree. No DDS traffic between processes:
the node is built here and each message goes through the callback the executor would call.
"""

from __future__ import annotations

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

pytestmark = pytest.mark.ros

PERIOD = 0.01


@pytest.fixture
def make_node(tmp_path, monkeypatch):
    """A function that builds the node with extra ``-p name:=value`` parameters."""
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    nodes: list[MotionFilterNode] = []
    context = None

    def make(*parameters: str) -> MotionFilterNode:
        nonlocal context
        args = ["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"]
        for parameter in parameters:
            args += ["-p", parameter]
        rclpy.init(args=args)  # returns nothing before Kilted
        context = True
        nodes.append(MotionFilterNode(subscribe_graph=False))
        return nodes[-1]

    yield make
    for node in nodes:
        node.destroy_node()
    if context is not None:
        rclpy.try_shutdown()


def measured(robot, pose) -> JointState:
    return JointState(name=list(robot.names), position=[float(v) for v in pose])


def test_when_the_robot_reports_a_straight_elbow_expect_the_first_command_from_there(
    make_node, robot
):
    """LElbowRoll at its upper limit (a common rest) lies inside a 0.1 rad margin."""
    node = make_node("position_margin_rad:=0.1")
    pose = robot.neutral_rad.copy()
    elbow = robot.names.index("LElbowRoll")
    pose[elbow] = robot.upper_rad[elbow]
    node.on_measured(measured(robot, pose))
    assert node.started
    np.testing.assert_array_equal(node.filter.position_rad, pose)  # at rest where the robot is
    first, _ = node.filter.tick(PERIOD)
    step = abs(first[elbow] - pose[elbow])
    assert step <= node.filter.limiter.max_velocity_rad_s[elbow] * PERIOD + 1e-12
    assert node.diagnostic_values()["command_finite_and_in_limits"] is True


@pytest.mark.parametrize("speed", ["0.0", "0.001"])
def test_when_joint_angles_speed_is_one_the_robot_refuses_expect_it_refused(
    make_node, robot, speed
):
    """naoqi's setAngles (and pepper_sim_node) take a fraction of the maximum speed in (0, 1]."""
    node = make_node()
    node.on_startup_timeout()
    result = node.set_parameters([Parameter("joint_angles_speed", value=float(speed))])[0]
    assert not result.successful
    assert "joint_angles_speed" in result.reason
    assert "not in [0, 0.01)" in result.reason
    sent = []
    node.publishers_by_output["joint_angles"].publish = sent.append
    node.publish_joint_angles()
    assert 0.0 < sent[0].speed <= 1.0


def test_when_joint_angles_speed_0_is_given_at_start_up_expect_a_configuration_error(make_node):
    with pytest.raises(ConfigurationError, match=r"joint_angles_speed: value 0.0 is in the excl"):
        make_node("joint_angles_speed:=0.0")


def test_when_measured_names_and_positions_disagree_expect_a_warning_not_a_bug(make_node, robot):
    node = make_node()
    subscription = next(s for s in node.subscriptions if s.topic_name == "/joint_states")
    bad = JointState(name=list(robot.names), position=[0.0] * (robot.n_joints - 1))
    info = {"publisher_gid": {"data": bytes(24)}, "source_timestamp": 0}
    subscription.callback(serialize_message(bad), info)  # what the executor hands over
    assert node.callback_errors == 0  # bad input, not a bug in the node
    assert node.input_messages_refused == 1
    problems = node.current_problems()
    assert not any(key.startswith("exception in") for key in problems), problems
    (level, message, _), *_ = [v for k, v in problems.items() if k.startswith("bad input to")]
    assert level == DiagnosticStatus.WARN
    assert "11 names, 10 positions" in message
    partial = JointState(name=list(robot.names[:3]), position=[0.0] * 3)  # another robot's
    subscription.callback(serialize_message(partial), info)
    assert node.diagnostic_values()["measured_partial_messages"] == 1
    assert not node.started  # neither was taken for the robot's pose
