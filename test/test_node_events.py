"""QoS event handlers of the nodes: none, since each one costs CPU; the graph says what they said.

rclpy gives every publisher and subscription two default event handlers (incompatible QoS,
incompatible type), and the SingleThreadedExecutor polls each of them in Python at every wait.
The nodes create none; a reliable or latched reader is checked against its publishers from the
graph (rclpy's ``qos_check_compatible``), and one it cannot match is a WARN on /diagnostics.
"""

from __future__ import annotations

import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Bool

from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import LATCHED_QOS, STREAM_QOS

pytestmark = pytest.mark.ros


@pytest.fixture
def node():
    with rclpy_session():
        node = DiagnosedNode("event_handler_check")
        yield node
        node.destroy_node()


def test_when_publishing_expect_no_default_event_handlers(node):
    publisher = node.create_publisher(Bool, "out", 10)
    assert publisher.event_handlers == []
    assert node.diagnostics_pub.event_handlers == []


def test_when_reading_expect_no_event_handler_and_reliable_readers_checked_from_the_graph(node):
    noop = lambda msg: None  # noqa: E731
    best_effort = node.create_subscription(Bool, "sensor", noop, qos_profile_sensor_data)
    assert best_effort.event_handlers == []
    for qos in (LATCHED_QOS, STREAM_QOS, 10):
        assert node.create_subscription(Bool, "stop", noop, qos).event_handlers == []
    assert [topic for topic, _ in node.checked_readers] == ["/stop"] * 3  # not the best effort


def test_when_a_best_effort_publisher_meets_a_latched_reader_expect_a_warning_naming_it(node):
    """The warning rclpy's event handler gave, from the graph: a best-effort stop never arrives."""
    node.create_subscription(Bool, "stop", lambda msg: None, LATCHED_QOS)
    other = rclpy.create_node("best_effort_panel")
    try:
        other.create_publisher(Bool, "stop", qos_profile_sensor_data)
        deadline = time.monotonic() + 30  # bounds a hung discovery only
        while node.count_publishers("stop") < 1:
            assert time.monotonic() < deadline, "the publisher was never discovered"
            time.sleep(0.02)
        node.check_publishers_qos()
        problem = node.current_problems()["incompatible QoS on /stop"]
        assert "/best_effort_panel" in problem[1]
        assert problem[0] == DiagnosticStatus.WARN
    finally:
        other.destroy_node()
