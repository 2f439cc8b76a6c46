"""Single-process mode wires the nodes by direct calls, not over DDS.

The three nodes are built in this process as ``audio2pose run --single-process`` builds them
(:func:`audio2pose_ros.ros.nodes.single_process.connect`) and fed audio chunks directly: the
filter queues one pose per feature frame although nothing subscribes to ``features`` or
``raw_trajectory``, so those messages are never built.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from audio_common_msgs.msg import AudioData, AudioInfo

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode
from audio2pose_ros.ros.nodes.inference_node import InferenceNode
from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode
from audio2pose_ros.ros.nodes.single_process import connect
from audio2pose_ros.ros.player import rclpy_session

pytestmark = pytest.mark.ros


def _nodes() -> list:
    return [
        AudioFeaturesNode(),
        InferenceNode(subscribe=False),
        MotionFilterNode(subscribe_graph=False),
    ]


def test_when_connected_expect_every_frame_reaches_the_filter_without_messages(
    tmp_path, speech, monkeypatch
):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    with rclpy_session(["--ros-args", "-p", "start_without_measured_pose:=true"]):
        features, inference, motion = nodes = _nodes()
        connect(nodes)
        motion.on_startup_timeout()  # start from neutral now: no robot here
        sent = []
        for publisher in (features.features_pub, inference.trajectory_pub):
            monkeypatch.setattr(publisher, "publish", sent.append)
        features.on_audio_info(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
        audio = speech[:16000]
        for i in range(0, len(audio), 160):
            features.on_audio_data(AudioData(data=encode_pcm(audio[i : i + 160], S16LE_MONO_16K)))
        assert inference.frames_in == features.frames_out >= 95
        assert motion.filter.status.received == inference.frames_in
        assert motion.input_messages == inference.frames_in  # one hand-over per chunk
        assert not sent  # nobody subscribes to features or raw_trajectory: nothing built
        assert inference.callback_errors == motion.callback_errors == 0
        for node in nodes:
            node.destroy_node()


def test_when_the_filter_commands_a_joint_the_model_lacks_expect_a_configuration_error(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("ROS_HOME", str(tmp_path))
    with rclpy_session():
        nodes = _nodes()
        fewer = SimpleNamespace(names=nodes[1].robot.names[:-1])  # a model for fewer joints
        monkeypatch.setattr(nodes[1], "robot", fewer)
        with pytest.raises(ConfigurationError, match="no joints"):
            connect(nodes)
        for node in nodes:
            node.destroy_node()
