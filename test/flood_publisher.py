"""A separate process that publishes one node input as fast as it can (the flood tests).

Run as ``python flood_publisher.py <kind> <seconds>``: it waits until the input's node
subscribes, writes ``ready`` on stdout, publishes for ``seconds`` and then writes
``sent <n> <first wall-clock s> <last wall-clock s>`` (what the tests line the probe's windows
up with). Kinds:

- ``joint_angles``: naoqi_driver's JointAnglesWithSpeed, one joint, alternating targets;
- ``audio_bytes``: 1-byte audio_common AudioData chunks after a 16 kHz mono S16LE AudioInfo;
- ``features``: 1 s messages (100 frames) of plausible features, numbered.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Float32MultiArray

from audio2pose_ros.audio.pcm import S16LE_MONO_16K
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.ros.diagnosed_node import AUDIO_QOS, LATCHED_QOS, STREAM_QOS, features_to_msg
from audio2pose_ros.topics import AUDIO, AUDIO_INFO, FEATURES, JOINT_ANGLES, absolute

FRAMES_PER_MESSAGE = 100
RCLError = rclpy_implementation.RCLError


def joint_angles(node: Node) -> tuple[Publisher, Callable[[int], None]]:
    publisher = node.create_publisher(JointAnglesWithSpeed, absolute(JOINT_ANGLES), 10)
    messages = [
        JointAnglesWithSpeed(joint_names=["HeadYaw"], joint_angles=[angle], speed=0.5)
        for angle in (0.2, -0.2)
    ]
    return publisher, lambda i: publisher.publish(messages[i % 2])


def audio_bytes(node: Node) -> tuple[Publisher, Callable[[int], None]]:
    info = node.create_publisher(AudioInfo, absolute(AUDIO_INFO), LATCHED_QOS)
    info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
    publisher = node.create_publisher(AudioData, absolute(AUDIO), AUDIO_QOS)
    messages = [AudioData(data=[value]) for value in (0x10, 0x02)]  # a quiet 16-bit sample
    return publisher, lambda i: publisher.publish(messages[i % 2])


def features(node: Node) -> tuple[Publisher, Callable[[int], None]]:
    model = load_streaming_model(default_checkpoint_path())
    spec = model.features
    rng = np.random.default_rng(0)
    shape = (FRAMES_PER_MESSAGE, spec.dim)
    frames = model.normalizer.mean + rng.standard_normal(shape) * model.normalizer.std
    msg = features_to_msg(frames.astype(np.float32), spec.label, 0)
    publisher = node.create_publisher(Float32MultiArray, absolute(FEATURES), STREAM_QOS)

    def send(i: int) -> None:
        msg.layout.dim[0].label = f"frames from {i * FRAMES_PER_MESSAGE}"
        publisher.publish(msg)

    return publisher, send


KINDS = {"joint_angles": joint_angles, "audio_bytes": audio_bytes, "features": features}


def main(kind: str, seconds: float) -> None:
    with rclpy.init():
        node = Node("flood_publisher")
        publisher, send = KINDS[kind](node)
        deadline = time.monotonic() + 60.0
        while not publisher.get_subscription_count() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # discovery complete both ways
        print("ready", flush=True)
        sent, first = 0, time.time()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for _ in range(100):
                try:
                    send(sent)
                except RCLError:  # a reliable writer whose reader is full times out: go on
                    continue
                sent += 1
        print(f"sent {sent} {first:.6f} {time.time():.6f}", flush=True)
        node.destroy_node()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
