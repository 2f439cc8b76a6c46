"""A node flooded with messages keeps its heartbeat, and says it is falling behind.

rclpy's EventsExecutor serves events in arrival order: while messages come faster than a node
serves them, its heartbeat timer waits behind the backlog, and a supervisor kills a node that is
working (the memory soak saw this at 10x real time). A guarded callback that ends with the
heartbeat overdue sends it (DiagnosedNode).
"""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.ros.diagnosed_node import (
    HEARTBEAT_OVERDUE_S,
    STALE_AFTER_S,
    STREAM_QOS,
    DiagnosedNode,
    features_to_msg,
)
from audio2pose_ros.ros.graph import RESTART_AFTER_S, executable_command
from audio2pose_ros.ros.player import spin_until
from audio2pose_ros.topics import DIAGNOSTICS, FEATURES, absolute

pytestmark = pytest.mark.ros

FLOOD_S = 8.0  # longer than a supervisor's RESTART_AFTER_S: the old node went silent throughout


@pytest.fixture
def node():
    with rclpy.init():
        node = DiagnosedNode("backlog_check")
        yield node
        node.destroy_node()


def test_when_a_callback_ends_with_the_heartbeat_overdue_expect_it_sent_with_a_warning(node):
    sent: list[DiagnosticArray] = []
    node.diagnostics_pub.publish = sent.append  # type: ignore[method-assign]
    served: list[bool] = []
    callback = node.guarded(served.append)

    node.last_heartbeat_s = time.monotonic()
    callback(True)
    assert sent == []  # on time: the timer sends it

    node.last_heartbeat_s = time.monotonic() - 2 * HEARTBEAT_OVERDUE_S
    callback(True)
    (beat,) = sent
    (status,) = beat.status
    assert status.level == DiagnosticStatus.WARN
    values = {kv.key: kv.value for kv in status.values}
    assert values["problem: falling behind"] == "1"
    assert "late" in status.message
    assert values["late_heartbeats"] == "1"
    assert time.monotonic() - node.last_heartbeat_s < HEARTBEAT_OVERDUE_S
    callback(True)
    assert len(sent) == 1  # just sent: not again
    assert served == [True, True, True]


def test_when_inference_node_is_flooded_expect_heartbeats_throughout(tmp_path):
    """The real node process on rclpy's executor, fed features as fast as one process can send."""
    model = load_streaming_model(default_checkpoint_path())
    spec = model.features
    rng = np.random.default_rng(0)
    frames = model.normalizer.mean + rng.standard_normal((20, spec.dim)) * model.normalizer.std
    msg = features_to_msg(frames.astype(np.float32), f"{spec.kind}{spec.dim}")
    log = (tmp_path / "inference_node.log").open("w")
    process = subprocess.Popen([*executable_command("inference_node")], stderr=log, stdout=log)
    beats: list[tuple[float, DiagnosticStatus]] = []

    def on_diagnostics(array: DiagnosticArray) -> None:
        beats.extend((time.monotonic(), s) for s in array.status if "inference" in s.name)

    with rclpy.init():
        probe = Node("flood_probe")
        probe.create_subscription(DiagnosticArray, DIAGNOSTICS, on_diagnostics, 100)
        publisher = probe.create_publisher(Float32MultiArray, absolute(FEATURES), STREAM_QOS)
        try:
            assert spin_until(probe, time.monotonic() + 60.0, lambda: bool(beats)), "never heard"
            start = time.monotonic()
            sent = 0
            while time.monotonic() - start < FLOOD_S:
                publisher.publish(msg)
                sent += 1
                rclpy.spin_once(probe, timeout_sec=0)
            end = time.monotonic()
            spin_until(probe, end + 1.0)
        finally:
            process.terminate()
            process.wait(20)
            probe.destroy_node()
    times = [start] + [t for t, _ in beats if start <= t <= end]
    longest_gap_s = max(np.diff([*times, end]))
    statuses = [s for t, s in beats if t >= start]
    served = max(int({kv.key: kv.value for kv in s.values}["frames_in"]) for s in statuses)
    print(
        f"sent {sent} messages in {FLOOD_S} s; served {served} frames; heartbeats "
        f"{len(times) - 1}, longest gap {longest_gap_s:.2f} s"
    )
    assert served > 0
    # STALE may show on a busy machine; a restart (RESTART_AFTER_S of silence) must never come.
    assert longest_gap_s < min(RESTART_AFTER_S, 2 * STALE_AFTER_S + 0.6)
    behind = [s for s in statuses if "problem: falling behind" in [kv.key for kv in s.values]]
    assert behind
    assert all(s.level == DiagnosticStatus.WARN for s in behind)
