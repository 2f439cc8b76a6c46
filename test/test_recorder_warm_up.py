"""What ``audio2pose run --play`` records is what the played audio caused, however busy the graph.

The player warms the graph up with silence until it answers, and records from then on. A graph
that is busy (a loaded machine) answers late, and the silence sent meanwhile is still on its way
through it when recording starts. A stand-in graph in another thread of this process answers
every audio message half a second late, with a raw pose that says whether the audio was silent;
the recording must hold the played audio's poses only (before, 10 of the warm-up's silent poses
were recorded as the audio's; a loaded `make test` recorded 25 extra poses of 300).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from audio_common_msgs.msg import AudioData
from background_node import BackgroundNode
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from audio2pose_ros import topics
from audio2pose_ros.data.bag import Chunking, audio_messages, read_messages
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.recorder import play_and_record

pytestmark = [pytest.mark.ros, pytest.mark.slow]
ANSWER_DELAY_S = 0.5


class SlowGraph(BackgroundNode):
    """Answers each audio message ANSWER_DELAY_S late: a raw pose of 0 (silence) or 1 (sound)."""

    def __init__(self) -> None:
        super().__init__("slow_graph")
        self.raw = self.node.create_publisher(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), 100
        )
        self.commands = [
            self.node.create_publisher(
                JointAnglesWithSpeed, topics.absolute(topics.JOINT_ANGLES), 10
            ),
            self.node.create_publisher(JointTrajectory, CONTROLLER_TOPIC, 10),
            self.node.create_publisher(
                JointState, topics.absolute(topics.COMMANDED_JOINT_STATES), 10
            ),
        ]
        self.due: list[tuple[float, float]] = []  # (when, 0 or 1)
        self.node.create_subscription(AudioData, topics.absolute(topics.AUDIO), self.on_audio, 1000)
        self.node.create_timer(0.005, self.answer)
        self.start()

    def on_audio(self, msg: AudioData) -> None:
        sound = float(any(bytes(msg.data)))
        self.due.append((time.monotonic() + ANSWER_DELAY_S, sound))

    def answer(self) -> None:
        while self.due and self.due[0][0] <= time.monotonic():
            _, sound = self.due.pop(0)
            self.raw.publish(JointTrajectory(points=[JointTrajectoryPoint(positions=[sound])]))
        self.commands[0].publish(JointAnglesWithSpeed())
        self.commands[1].publish(JointTrajectory())
        self.commands[2].publish(JointState())


def test_when_the_graph_answers_late_expect_none_of_the_warm_up_recorded(tmp_path: Path) -> None:
    sound = np.full(16000, 1000, dtype=np.int16)  # 1 s of sound in 100 ms chunks
    messages = audio_messages(sound, Chunking(min_bytes=3200, max_bytes=3200))
    graph = SlowGraph()
    try:
        with rclpy_session():
            result = play_and_record(messages, tmp_path / "bag", tail_s=ANSWER_DELAY_S + 0.5)
    finally:
        graph.close()
    raw = [
        p.positions[0]
        for m in read_messages(tmp_path / "bag", [topics.absolute(topics.RAW_TRAJECTORY)])
        for p in deserialize_message(m.data, JointTrajectory).points
    ]
    chunks = sum(m.topic == topics.absolute(topics.AUDIO) for m in messages)
    assert raw.count(0.0) == 0, f"{raw.count(0.0)} poses of the warm-up's silence recorded"
    assert raw.count(1.0) == chunks  # every pose of the played audio, once
    assert result.chunks_sent == chunks
