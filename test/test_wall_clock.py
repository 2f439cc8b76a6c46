"""The nodes run on the wall clock, whatever ``use_sim_time`` says.

``use_sim_time:=true`` is often set for a whole launch to replay a bag with ``--clock``. Without
a /clock (or with a paused bag) every timer of a node on sim time stops: no commands, no
heartbeat, and the supervisor restarted the nodes over and over.
"""

from __future__ import annotations

import subprocess
import time

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.parameter import Parameter

from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_PERIOD_S, USE_SIM_TIME, DiagnosedNode
from audio2pose_ros.ros.player import rclpy_session, spin_until
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import DIAGNOSTICS

pytestmark = pytest.mark.ros


def test_when_use_sim_time_is_set_expect_the_wall_clock_and_timers_running():
    with rclpy_session(["--ros-args", "-p", f"{USE_SIM_TIME}:=true"]):
        node = DiagnosedNode("wall_clock_check")
        try:
            sent: list[DiagnosticArray] = []
            node.diagnostics_pub.publish = sent.append  # type: ignore[method-assign]
            assert node.get_parameter(USE_SIM_TIME).value is False
            assert abs(node.get_clock().now().nanoseconds * 1e-9 - time.time()) < 5.0
            spin_until(node, time.monotonic() + 3 * HEARTBEAT_PERIOD_S)
            assert len(sent) >= 2  # the heartbeat timer runs with no /clock

            (result,) = node.set_parameters([Parameter(USE_SIM_TIME, Parameter.Type.BOOL, True)])
            assert not result.successful
            assert "wall clock" in result.reason
            assert node.get_parameter(USE_SIM_TIME).value is False
            assert abs(node.get_clock().now().nanoseconds * 1e-9 - time.time()) < 5.0
            (result,) = node.set_parameters([Parameter(USE_SIM_TIME, Parameter.Type.BOOL, False)])
            assert result.successful
        finally:
            node.destroy_node()


def test_when_the_filter_process_is_started_on_sim_time_expect_its_heartbeat(tmp_path):
    """The real motion_filter_node with use_sim_time true and no /clock: heard, and it warns."""
    log_path = tmp_path / "motion_filter_node.log"
    with log_path.open("w") as log:
        process = subprocess.Popen(
            [
                *executable_command("motion_filter_node"),
                "--ros-args",
                "-p",
                f"{USE_SIM_TIME}:=true",
                "-p",
                f"state_file:={tmp_path / 'state.json'}",
            ],
            stderr=log,
            stdout=log,
        )
        heard: list[DiagnosticArray] = []
        try:
            with rclpy_session():
                probe = Node("wall_clock_probe")
                probe.create_subscription(
                    DiagnosticArray,
                    DIAGNOSTICS,
                    lambda m: heard.extend(s for s in m.status if "motion_filter" in s.name),
                    10,
                )
                spin_until(probe, time.monotonic() + 60.0, lambda: len(heard) >= 3)
                probe.destroy_node()
        finally:
            process.terminate()
            process.wait(20)
    assert len(heard) >= 3, log_path.read_text()
    assert f"{USE_SIM_TIME} ignored" in log_path.read_text()
