"""A test participant that plays audio_capture's part and records everything the graph sends."""

from __future__ import annotations

import time

import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.ros.diagnosed_node import LATCHED_QOS
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC


class Probe(Node):
    """Publishes audio like audio_capture and records everything the graph sends."""

    def __init__(self) -> None:
        super().__init__("test_probe")
        self.audio = self.create_publisher(AudioData, "/audio/audio", 100)
        self.info = self.create_publisher(AudioInfo, "/audio/audio_info", LATCHED_QOS)
        self.received: dict[str, list] = {
            k: [] for k in ("angles", "trajectory", "states", "raw", "features", "diagnostics")
        }
        for key, msg_type, topic in (
            ("angles", JointAnglesWithSpeed, "/joint_angles"),
            ("trajectory", JointTrajectory, CONTROLLER_TOPIC),
            ("states", JointState, "/commanded_joint_states"),
            ("raw", JointTrajectory, "/raw_trajectory"),
            ("features", Float32MultiArray, "/features"),
            ("diagnostics", DiagnosticArray, "/diagnostics"),
        ):
            self.create_subscription(msg_type, topic, self.received[key].append, 1000)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.005)

    def wait_until(self, condition, timeout_s: float = 60.0) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if condition():
                return
            rclpy.spin_once(self, timeout_sec=0.05)
        raise TimeoutError("condition not met in time")

    def graph_ready(self) -> bool:
        return (
            self.audio.get_subscription_count() > 0
            and self.count_subscribers("/features") > 0
            and self.count_subscribers("/raw_trajectory") > 0
            and self.count_publishers("/joint_angles") > 0
        )

    def warm_up(self) -> None:
        """Send silence until poses come back: every link of the graph has matched.

        DDS discovery is asymmetric: our side may see a subscriber before the node's own
        publisher has matched the next node, and reliable volatile samples sent before that
        are lost. 160-sample chunks keep the feature extractor aligned to whole frames.
        """
        silence = bytes(2 * 160)

        def poses_arrive() -> bool:
            self.audio.publish(AudioData(data=silence))
            self.spin_for(0.02)
            return bool(self.received["raw"]) and bool(self.received["angles"])

        self.wait_until(poses_arrive, timeout_s=60)
        for _ in range(5):  # make the warm-up longer than one 25 ms window
            self.audio.publish(AudioData(data=silence))
        self.spin_for(0.5)
        for key in self.received:
            self.received[key].clear()

    def play(self, payload: bytes, chunk_sizes: list[int], bytes_per_s: float) -> int:
        """Send ``payload`` in chunks of the given sizes (cycled), paced at ``bytes_per_s``."""
        start, offset, i = time.monotonic(), 0, 0
        while offset < len(payload):
            size = chunk_sizes[i % len(chunk_sizes)]
            due = start + offset / bytes_per_s
            while time.monotonic() < due:
                rclpy.spin_once(self, timeout_sec=0.001)
            self.audio.publish(AudioData(data=payload[offset : offset + size]))
            offset += size
            i += 1
        return i


def diagnostics_of(probe: Probe, node_name: str) -> dict[str, str]:
    """The latest /diagnostics key-values of ``node_name``."""
    for array in reversed(probe.received["diagnostics"]):
        for status in array.status:
            if status.name.endswith(node_name):
                return {kv.key: kv.value for kv in status.values}
    return {}
