"""QoS event handlers of the nodes: only where a warning can come, since each one costs CPU.

rclpy gives every publisher and subscription two default event handlers (incompatible QoS,
incompatible type), and the SingleThreadedExecutor polls each of them in Python at every wait.
"""

from __future__ import annotations

import pytest
import rclpy
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Bool

from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.qos import LATCHED_QOS, STREAM_QOS

pytestmark = pytest.mark.ros


@pytest.fixture
def node():
    with rclpy.init():
        node = DiagnosedNode("event_handler_check")
        yield node
        node.destroy_node()


def test_when_publishing_expect_no_default_event_handlers(node):
    publisher = node.create_publisher(Bool, "out", 10)
    assert publisher.event_handlers == []
    assert node.diagnostics_pub.event_handlers == []


def test_when_reading_best_effort_expect_no_handler_and_reliable_keeps_its_warning(node):
    noop = lambda msg: None  # noqa: E731
    best_effort = node.create_subscription(Bool, "sensor", noop, qos_profile_sensor_data)
    assert best_effort.event_handlers == []
    # a best-effort publisher on a reliable or latched input (stop) is refused: say so
    for qos in (LATCHED_QOS, STREAM_QOS, 10):
        assert node.create_subscription(Bool, "stop", noop, qos).event_handlers
