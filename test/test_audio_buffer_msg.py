"""The AudioBuffer copy in support/ros_msgs is naoqi_driver's message: same fields, constants and
type hash as ros-naoqi/naoqi_bridge_msgs2."""

from __future__ import annotations

import pytest
import rclpy
from naoqi_bridge_msgs.msg import AudioBuffer

from audio2pose_ros.audio.source import NAOQI_CHANNELS
from audio2pose_ros.ros.player import rclpy_session

# RIHS01 hash of msg/AudioBuffer.msg at ros-naoqi/naoqi_bridge_msgs2 commit 73ac611, computed
# by rosidl_generator_type_description (Kilted wheels of this venv) from the upstream file.
UPSTREAM_TYPE_HASH = "RIHS01_74b1fa80d19a087b210cef045e054a0bfc34bc8d5621d3500bf6f343696b51cf"


def test_when_audio_buffer_inspected_expect_upstream_fields_and_types():
    assert AudioBuffer.get_fields_and_field_types() == {
        "header": "std_msgs/Header",
        "frequency": "uint16",
        "channel_map": "sequence<uint8>",
        "data": "sequence<int16>",
    }


def test_when_audio_buffer_constants_read_expect_the_channel_names_the_node_accepts():
    constants = {
        name.removeprefix("CHANNEL_").lower(): getattr(AudioBuffer, name)
        for name in dir(AudioBuffer)
        if name.startswith("CHANNEL_")
    }
    assert constants == NAOQI_CHANNELS


@pytest.mark.ros
def test_when_audio_buffer_published_expect_the_upstream_type_hash():
    with rclpy_session():
        node = rclpy.create_node("audio_buffer_hash")
        try:
            node.create_publisher(AudioBuffer, "audio_buffer_hash_probe", 1)
            (info,) = node.get_publishers_info_by_topic("audio_buffer_hash_probe")
            # Humble's rclpy has no type hashes: there the fields test above is the check.
            type_hash = getattr(info, "topic_type_hash", UPSTREAM_TYPE_HASH)
            assert str(type_hash) == UPSTREAM_TYPE_HASH
        finally:
            node.destroy_node()
