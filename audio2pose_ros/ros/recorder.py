"""The player and recorder of ``audio2pose run``: audio into the running graph, commands to a bag.

The player (:mod:`audio2pose_ros.ros.player`) publishes audio_common_msgs AudioInfo (latched)
and AudioData chunks in real time; the recorder writes every command the robot would receive to
a rosbag2 (MCAP).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    AUDIO_TOPIC_TYPES,
    BagError,
    BagMessage,
    BagWriter,
    Chunking,
    audio_messages,
    read_checked_messages,
)
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.player import MessagePlayer, spin_until, warm_up
from audio2pose_ros.ros.supervisor import GraphTimeoutError

QUIET_S = 0.3  # recording starts once no raw pose came for this long after the warm-up
RECORD_FLUSH_PERIOD_S = 0.5  # a killed recording loses at most about this much (BagWriter.flush)
RECORDED_TOPICS = {
    topics.absolute(topics.JOINT_ANGLES): (
        JointAnglesWithSpeed,
        "naoqi_bridge_msgs/msg/JointAnglesWithSpeed",
    ),
    CONTROLLER_TOPIC: (JointTrajectory, "trajectory_msgs/msg/JointTrajectory"),
    topics.absolute(topics.COMMANDED_JOINT_STATES): (JointState, "sensor_msgs/msg/JointState"),
    topics.absolute(topics.RAW_TRAJECTORY): (
        JointTrajectory,
        "trajectory_msgs/msg/JointTrajectory",
    ),
}


@dataclass
class PlaybackResult:
    """What a run recorded."""

    audio_s: float
    chunks_sent: int
    recorded_s: float
    counts: dict[str, int] = field(default_factory=dict)
    bag: Path | None = None


class PlayerRecorder(Node):
    """Publishes a WAV as audio_common_msgs in real time and records the graph's commands."""

    def __init__(self, bag: BagWriter | None) -> None:
        """Create the audio publishers and one recording subscription per command topic."""
        super().__init__("audio2pose_player")
        self.bag = bag
        self.recording = False
        self.counts = dict.fromkeys(RECORDED_TOPICS, 0)
        self.poses_seen = 0
        self.heard: set[str] = set()  # recorded topics that ever delivered a message
        self.player = MessagePlayer(
            self, [(AUDIO_TOPIC, AUDIO_DATA_TYPE), (AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE)]
        )
        self.create_subscription(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), self._on_pose, 100
        )
        for topic, (msg_type, type_name) in RECORDED_TOPICS.items():
            self.create_subscription(
                msg_type, topic, self._recorder(topic, type_name), 100, raw=True
            )

    def _on_pose(self, msg: JointTrajectory) -> None:
        self.poses_seen += len(msg.points)

    def _recorder(self, topic: str, type_name: str) -> Callable[[bytes], None]:
        def record(data: bytes) -> None:
            self.heard.add(topic)
            if not self.recording:
                return
            self.counts[topic] += 1
            if self.bag is not None:
                self.bag.write(topic, type_name, self.get_clock().now().nanoseconds, data)

        return record

    def record_sent(self, message: BagMessage) -> None:
        """Record a message the player just published, while recording."""
        if self.recording and self.bag is not None:
            self.bag.write(
                message.topic, message.msgtype, self.get_clock().now().nanoseconds, message.data
            )

    def warm_up(self, timeout_s: float) -> None:
        """Send silence until poses and every recorded command come back: each link has matched.

        Then wait until no raw pose came for :data:`QUIET_S`: a busy graph may still be working
        through the silence sent meanwhile, and its poses must not be recorded as the played
        audio's.

        Raises:
            GraphTimeoutError: the graph did not answer within ``timeout_s``.
        """
        deadline = time.monotonic() + timeout_s
        if not warm_up(
            self.player,
            AUDIO_TOPIC,
            lambda: self.poses_seen > 0 and self.heard >= set(RECORDED_TOPICS),
            timeout_s,
        ):
            raise GraphTimeoutError(
                f"the node graph did not answer within {timeout_s} s (see the node logs)"
            )
        seen = -1
        while self.poses_seen != seen and time.monotonic() < deadline:
            seen = self.poses_seen
            spin_until(self, time.monotonic() + QUIET_S)


def audio_source(path: Path, chunking: Chunking | None = None) -> list[BagMessage]:
    """The audio messages to play: a WAV cut like a live capture, or a bag's audio topics."""
    if path.suffix.lower() == ".wav":
        samples, _ = read_wav(path)
        return audio_messages(samples, chunking)
    messages = read_checked_messages(path, AUDIO_TOPIC_TYPES, AUDIO_TOPIC_TYPES)
    if not any(m.topic == AUDIO_TOPIC for m in messages):
        raise BagError(f"{path}: no {AUDIO_TOPIC} messages to play")
    start = messages[0].timestamp_ns
    return [replace(m, timestamp_ns=m.timestamp_ns - start) for m in messages]


def play_and_record(
    messages: Sequence[BagMessage],
    bag_path: Path | None,
    rate: float = 1.0,
    tail_s: float = 2.0,
    startup_timeout_s: float = 60.0,
) -> PlaybackResult:
    """Publish audio messages with their timing (``rate`` x faster); record what the graph sends.

    Must run while :func:`node_graph` is up, inside an initialised rclpy context. Recording
    starts with the first message and ends ``tail_s`` after the last one, so the bag also shows
    the glide back to the neutral pose.

    Raises:
        GraphTimeoutError: the graph did not come up within ``startup_timeout_s``.
    """
    first_info = next((m for m in messages if m.topic == AUDIO_INFO_TOPIC), None)
    with ExitStack() as stack:
        bag = (
            stack.enter_context(BagWriter(bag_path, flush_period_s=RECORD_FLUSH_PERIOD_S))
            if bag_path
            else None
        )
        node = PlayerRecorder(bag)
        stack.callback(node.destroy_node)
        if first_info is not None:
            node.player.publish(first_info)
        node.warm_up(startup_timeout_s)
        node.recording = True
        start = node.player.play(messages, rate, on_publish=node.record_sent)
        spin_until(node, time.monotonic() + tail_s)
        return PlaybackResult(
            audio_s=messages[-1].timestamp_ns * 1e-9 if messages else 0.0,
            chunks_sent=sum(m.topic == AUDIO_TOPIC for m in messages),
            recorded_s=time.monotonic() - start,
            counts=dict(node.counts),
            bag=bag_path,
        )
