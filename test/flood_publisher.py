"""A separate process that publishes one node input as fast as it can (the flood tests).

Run as ``python flood_publisher.py <kind> <seconds>`` (:func:`start`, from a test): it waits until
the input's node subscribes, writes ``ready`` on stdout, publishes for ``seconds`` and then writes
``sent <n> <first wall-clock s> <last wall-clock s>`` (what the tests line the probe's windows up
with). It runs at the tests' own CPU priority and competes with the node for the CPU, as a user's
other work would: the tests judge what the node did with the CPU time it had, so the share it gets
is no verdict, and a flooder as fast as the node builds the backlog that starves a node whose timers
wait behind its messages (at the lowest priority, the set_parameters storm did not). Kinds:

- ``joint_angles``: naoqi_driver's JointAnglesWithSpeed, one joint, alternating targets;
- ``audio_bytes``: 1-byte audio_common AudioData chunks after a 16 kHz mono S16LE AudioInfo;
- ``features``: 1 s messages (100 frames) of plausible features, numbered;
- ``joint_states``: a robot's JointState of every joint at its neutral pose (sensor-data QoS);
- ``stop_false``: ``stop: false`` on the latched stop topic;
- ``enable_true``: ``enable: true`` on the latched enable topic;
- ``set_parameters:<node>``: requests to set ``<node>``'s read-only ``command_input``, sent
  without waiting for the answers (taken when there).
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from typing import IO

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float32MultiArray

from audio2pose_ros.audio.pcm import S16LE_MONO_16K
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.messages import features_to_msg
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS, STREAM_QOS
from audio2pose_ros.topics import (
    AUDIO,
    AUDIO_INFO,
    ENABLE,
    FEATURES,
    JOINT_ANGLES,
    JOINT_STATES,
    STOP,
    absolute,
)

FRAMES_PER_MESSAGE = 100
Flood = tuple[Callable[[], bool], Callable[[int], None]]  # (ready to flood?, send message i)


def _subscribed(publisher: Publisher) -> Callable[[], bool]:
    return lambda: bool(publisher.get_subscription_count())


def joint_angles(node: Node) -> Flood:
    publisher = node.create_publisher(JointAnglesWithSpeed, absolute(JOINT_ANGLES), 10)
    messages = [
        JointAnglesWithSpeed(joint_names=["HeadYaw"], joint_angles=[angle], speed=0.5)
        for angle in (0.2, -0.2)
    ]
    return _subscribed(publisher), lambda i: publisher.publish(messages[i % 2])


def audio_bytes(node: Node) -> Flood:
    info = node.create_publisher(AudioInfo, absolute(AUDIO_INFO), LATCHED_QOS)
    info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
    publisher = node.create_publisher(AudioData, absolute(AUDIO), AUDIO_QOS)
    messages = [AudioData(data=[value]) for value in (0x10, 0x02)]  # a quiet 16-bit sample
    return _subscribed(publisher), lambda i: publisher.publish(messages[i % 2])


def features(node: Node) -> Flood:
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

    return _subscribed(publisher), send


def joint_states(node: Node) -> Flood:
    robot = load_robot()
    publisher = node.create_publisher(JointState, absolute(JOINT_STATES), qos_profile_sensor_data)
    msg = JointState(name=list(robot.names), position=[float(v) for v in robot.neutral_rad])

    def send(i: int) -> None:
        msg.header.stamp = node.get_clock().now().to_msg()
        publisher.publish(msg)

    return _subscribed(publisher), send


def _latched_bool(node: Node, topic: str, value: bool) -> Flood:
    publisher = node.create_publisher(Bool, absolute(topic), LATCHED_QOS)
    msg = Bool(data=value)
    return _subscribed(publisher), lambda i: publisher.publish(msg)


def stop_false(node: Node) -> Flood:
    return _latched_bool(node, STOP, False)


def enable_true(node: Node) -> Flood:
    return _latched_bool(node, ENABLE, True)


def set_parameters(node: Node, target: str) -> Flood:
    """Requests to set a read-only parameter of ``target``, never waiting for an answer."""
    client = node.create_client(SetParameters, f"/{target}/set_parameters")
    value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="joint_trajectory")
    request = SetParameters.Request(parameters=[Parameter(name="command_input", value=value)])
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def send(i: int) -> None:
        client.call_async(request)
        executor.spin_once(timeout_sec=0)  # takes an answer when one is there

    return client.service_is_ready, send


KINDS: dict[str, Callable[..., Flood]] = {
    "joint_angles": joint_angles,
    "audio_bytes": audio_bytes,
    "features": features,
    "joint_states": joint_states,
    "stop_false": stop_false,
    "enable_true": enable_true,
    "set_parameters": set_parameters,
}


def start(kind: str, seconds: float, stderr: IO[str] | None = None) -> subprocess.Popen[str]:
    """This script in a process of its own, flooding ``kind`` for ``seconds``; stdout as text."""
    return subprocess.Popen(
        [sys.executable, __file__, kind, str(seconds)],
        stdout=subprocess.PIPE,
        stderr=stderr,
        text=True,
    )


def main(kind: str, seconds: float) -> None:
    with rclpy_session():
        node = Node("flood_publisher")
        name, *target = kind.split(":")
        ready, send = KINDS[name](node, *target)
        deadline = time.monotonic() + 60.0
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # discovery complete both ways
        print("ready", flush=True)
        sent, first = 0, time.time()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for _ in range(100):
                try:
                    send(sent)
                except RuntimeError:  # a reliable writer whose reader is full times out: go on
                    continue
                sent += 1
        print(f"sent {sent} {first:.6f} {time.time():.6f}", flush=True)
        node.destroy_node()


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
