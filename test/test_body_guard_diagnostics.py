"""motion_filter_node reports the self-collision guard's last-resort holds on /diagnostics.

The node is built in this process and its filter driven directly (no traffic between
processes): a state no braking can stop in time makes the guard hold, and the node's
diagnostics count it and say so in the guard's warning.
"""

from __future__ import annotations

import pytest
import rclpy
from test_body_guard_pressure import state_that_cannot_stop

from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

pytestmark = pytest.mark.ros

PERIOD = 0.01


@pytest.fixture
def node(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    rclpy.init(args=["--ros-args", "-p", f"state_file:={tmp_path / 'state.json'}"])
    built = MotionFilterNode(subscribe_graph=False)
    yield built
    built.destroy_node()
    rclpy.try_shutdown()


def test_when_the_guard_holds_as_a_last_resort_expect_it_counted_on_diagnostics(node):
    guard = node.filter.body_guard
    pose, velocity = state_that_cannot_stop(guard.body)
    assert node.diagnostic_values()["body_guard_holds"] == 0
    guard.enforce(pose + velocity * PERIOD, velocity, pose, velocity, PERIOD, node.filter.limiter)
    assert node.diagnostic_values()["body_guard_holds"] == 1
    node.report_body_guard(guard.status)
    _, message, _ = node.current_problems()["body_guard"]
    assert "last-resort holds so far: 1" in message
