"""The console's STOP asks the filter's emergency_stop service as well as the latched topic.

The real console and motion filter nodes in one process, over DDS: a press is confirmed by the
filter's answer (``stops_confirmed``) and the filter is stopped; with no filter serving the
service, the press is counted as unconfirmed, and the latched topic is still published.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Bool

from audio2pose_ros import topics
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import LATCHED_QOS

pytestmark = [pytest.mark.ros]
WAIT_S = 30.0  # a bound on a hang only


def _spinner(executor: SingleThreadedExecutor) -> Callable[[Callable[[], bool], str], None]:
    def spin_until(done: Callable[[], bool], what: str) -> None:
        end = time.monotonic() + WAIT_S
        while not done():
            assert time.monotonic() < end, f"never: {what}"
            executor.spin_once(timeout_sec=0.05)

    return spin_until


def test_when_stop_is_pressed_expect_the_filters_service_asked_and_its_answer_counted(tmp_path):
    from audio2pose_ros.ros.nodes.console_node import ConsoleNode
    from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode

    args = ["--ros-args", "-p", "port:=0", "-p", f"state_file:={tmp_path / 'filter.json'}"]
    with rclpy_session(args):
        motion_filter, console = MotionFilterNode(), ConsoleNode()
        executor = SingleThreadedExecutor()
        for node in (motion_filter, console):
            executor.add_node(node)
        spin_until = _spinner(executor)
        try:
            spin_until(console.emergency_stop.service_is_ready, "the filter's service")
            console.set_stop(True)
            spin_until(lambda: console.stops_confirmed == 1, "the stop confirmed")
            assert console.stops_unconfirmed == 0
            assert motion_filter.filter.status.stopped
            assert motion_filter.stop_hold.in_force
        finally:
            for node in (console, motion_filter):
                executor.remove_node(node)
                node.destroy_node()


def test_when_no_filter_serves_the_stop_expect_the_press_unconfirmed_and_the_topic_latched():
    from audio2pose_ros.ros.nodes.console_node import ConsoleNode

    with rclpy_session(["--ros-args", "-p", "port:=0"]):
        console = ConsoleNode()
        heard: list[bool] = []
        listener = console.create_subscription(
            Bool, topics.STOP, lambda m: heard.append(m.data), LATCHED_QOS
        )
        executor = SingleThreadedExecutor()
        executor.add_node(console)
        try:
            console.set_stop(True)
            _spinner(executor)(lambda: heard == [True], "the latched stop")
            assert console.stops_unconfirmed == 1
            assert console.stops_confirmed == 0
            assert console.diagnostic_values()["stops_unconfirmed"] == 1
        finally:
            console.destroy_subscription(listener)
            executor.remove_node(console)
            console.destroy_node()
