"""audio_features_node publishes voice activity on change, with a refresh.

One message per audio chunk cost one DDS write in audio_features_node and one callback in
motion_filter_node per 10 ms; the voice changes a few times a second at most. The node and a
subscriber run in this process over DDS; the node is fed audio directly, chunk by chunk.
"""

from __future__ import annotations

import time

import pytest
from audio_common_msgs.msg import AudioData, AudioInfo
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import Bool

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.audio.vad import EnergyVad
from audio2pose_ros.ros.nodes.audio_features_node import VOICE_REFRESH_S, AudioFeaturesNode
from audio2pose_ros.ros.player import rclpy_session

pytestmark = pytest.mark.ros

CHUNK = 160  # 10 ms


def _changes(values: list[bool]) -> list[bool]:
    """``values`` without consecutive repeats."""
    return [v for i, v in enumerate(values) if i == 0 or v != values[i - 1]]


def test_when_speech_plays_expect_voice_messages_on_changes_and_refreshes_only(speech):
    """Before: one message per chunk (300 for 3 s); after: changes plus a refresh per 0.5 s."""
    audio = speech[: 3 * 16000]
    chunks = [audio[i : i + CHUNK] for i in range(0, len(audio), CHUNK)]
    vad = EnergyVad()
    expected = [vad.push(chunk) for chunk in chunks]
    received: list[bool] = []
    with rclpy_session():
        node = AudioFeaturesNode()
        peer = Node("voice_peer")
        peer.create_subscription(Bool, "voice_activity", lambda m: received.append(m.data), 1000)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.add_node(peer)
        deadline = time.monotonic() + 10.0
        while not node.voice_pub.get_subscription_count():  # DDS discovery
            assert time.monotonic() < deadline, "the subscriber was never matched"
            executor.spin_once(timeout_sec=0.05)
        info = AudioInfo(**S16LE_MONO_16K.audio_info_fields())
        node.on_audio_info(info)
        start = time.monotonic()
        for chunk in chunks:
            node.on_audio_data(AudioData(data=encode_pcm(chunk, S16LE_MONO_16K)))
        elapsed = time.monotonic() - start
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        node.destroy_node()
        peer.destroy_node()
    assert _changes(received) == _changes(expected)
    assert received[-1] == expected[-1]
    changes = len(_changes(expected))
    assert len(received) <= changes + int(elapsed / VOICE_REFRESH_S) + 1
    assert len(received) < len(chunks) // 10
