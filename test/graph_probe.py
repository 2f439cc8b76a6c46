"""A test participant that plays audio_capture's part and records everything the graph sends."""

from __future__ import annotations

import time

from audio_common_msgs.msg import AudioData
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    BagMessage,
)
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.player import MessagePlayer, spin_until, warm_up
from audio2pose_ros.timebase import SAMPLES_PER_FRAME
from audio2pose_ros.topics import (
    COMMANDED_JOINT_STATES,
    DIAGNOSTICS,
    FEATURES,
    JOINT_ANGLES,
    RAW_TRAJECTORY,
    absolute,
)


class Probe(Node):
    """Publishes audio like audio_capture and records everything the graph sends."""

    def __init__(self) -> None:
        super().__init__("test_probe")
        self.player = MessagePlayer(
            self, [(AUDIO_TOPIC, AUDIO_DATA_TYPE), (AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE)]
        )
        self.audio = self.player.publishers[AUDIO_TOPIC]
        self.info = self.player.publishers[AUDIO_INFO_TOPIC]
        self.received: dict[str, list] = {
            k: [] for k in ("angles", "trajectory", "states", "raw", "features", "diagnostics")
        }
        self.subscriptions_by_key = {}
        for key, msg_type, topic in (
            ("angles", JointAnglesWithSpeed, absolute(JOINT_ANGLES)),
            ("trajectory", JointTrajectory, CONTROLLER_TOPIC),
            ("states", JointState, absolute(COMMANDED_JOINT_STATES)),
            ("raw", JointTrajectory, absolute(RAW_TRAJECTORY)),
            ("features", Float32MultiArray, absolute(FEATURES)),
            ("diagnostics", DiagnosticArray, DIAGNOSTICS),
        ):
            self.subscriptions_by_key[key] = self.create_subscription(
                msg_type, topic, self.received[key].append, 1000
            )

    def spin_for(self, seconds: float) -> None:
        spin_until(self, time.monotonic() + seconds)

    def wait_until(self, condition, timeout_s: float = 60.0) -> None:
        if not (condition() or spin_until(self, time.monotonic() + timeout_s, condition)):
            raise TimeoutError("condition not met in time")

    def graph_ready(self) -> bool:
        return (
            self.audio.get_subscription_count() > 0
            and self.count_subscribers(absolute(FEATURES)) > 0
            and self.count_subscribers(absolute(RAW_TRAJECTORY)) > 0
            and self.count_publishers(absolute(JOINT_ANGLES)) > 0
            # present in the graph is not yet matched: the probe's own readers must be
            and self.subscriptions_by_key["raw"].get_publisher_count() > 0
            and self.subscriptions_by_key["features"].get_publisher_count() > 0
        )

    def warm_up(self) -> None:
        """Send silence until poses and commands come back (the player's warm-up), then a
        little more than one 25 ms window of silence, and forget what arrived so far."""
        answered = warm_up(
            self.player,
            AUDIO_TOPIC,
            lambda: bool(self.received["raw"]) and bool(self.received["angles"]),
            timeout_s=60.0,
        )
        if not answered:
            raise TimeoutError("the graph did not answer within 60 s")
        for _ in range(5):
            self.audio.publish(AudioData(data=bytes(2 * SAMPLES_PER_FRAME)))
        self.spin_for(0.5)
        for key in self.received:
            self.received[key].clear()

    def play(self, payload: bytes, chunk_sizes: list[int], bytes_per_s: float) -> int:
        """Send ``payload`` in chunks of the given sizes (cycled), paced at ``bytes_per_s``."""
        messages, offset, i = [], 0, 0
        while offset < len(payload):
            size = chunk_sizes[i % len(chunk_sizes)]
            chunk = serialize_message(AudioData(data=payload[offset : offset + size]))
            stamp_ns = round(offset / bytes_per_s * 1e9)
            messages.append(BagMessage(stamp_ns, AUDIO_TOPIC, AUDIO_DATA_TYPE, chunk))
            offset += size
            i += 1
        self.player.play(messages)
        return len(messages)


def diagnostics_of(probe: Probe, node_name: str) -> dict[str, str]:
    """The latest /diagnostics key-values of ``node_name``."""
    for array in reversed(probe.received["diagnostics"]):
        for status in array.status:
            if status.name.endswith(node_name):
                return {kv.key: kv.value for kv in status.values}
    return {}
