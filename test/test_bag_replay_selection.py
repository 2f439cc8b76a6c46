"""``bag replay`` feeds a graph its input (audio), never the robot's commands unless named."""

from __future__ import annotations

import subprocess

import numpy as np

from audio2pose_ros.data.bag import (
    INPUT_MESSAGE_TYPES,
    KNOWN_MESSAGE_TYPES,
    BagMessage,
    BagWriter,
    audio_messages,
    select_for_replay,
    typestore,
)
from audio2pose_ros.ros.supervisor import executable_command

JOINT_ANGLES = "naoqi_bridge_msgs/msg/JointAnglesWithSpeed"
START_NS = 1_700_000_000_000_000_000


def recording(tmp_path, speech):
    """A bag like ``audio2pose run --record`` makes: the audio and the commands sent."""
    store = typestore()
    cls = store.types[JOINT_ANGLES]
    command = cls(
        header=store.types["std_msgs/msg/Header"](
            stamp=store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
        ),
        joint_names=["LShoulderPitch"],
        joint_angles=np.array([-0.3], dtype=np.float32),
        speed=0.5,
        relative=0,
    )
    data = bytes(store.serialize_cdr(command, JOINT_ANGLES))
    messages = audio_messages(speech[:8000])
    messages += [BagMessage(i * 20_000_000, "/joint_angles", JOINT_ANGLES, data) for i in range(25)]
    messages.sort(key=lambda m: m.timestamp_ns)
    out = tmp_path / "recording"
    with BagWriter(out, "mcap") as bag:
        for m in messages:
            bag.write(m.topic, m.msgtype, START_NS + m.timestamp_ns, m.data)
    return out, messages


def test_when_no_topics_named_expect_only_input_types_selected():
    assert set(KNOWN_MESSAGE_TYPES) >= INPUT_MESSAGE_TYPES
    messages = [
        BagMessage(0, "/audio/audio", "audio_common_msgs/msg/AudioData", b""),
        BagMessage(1, "/joint_angles", JOINT_ANGLES, b""),
        BagMessage(2, "/stop", "std_msgs/msg/Bool", b""),
        BagMessage(3, "/raw_trajectory", "trajectory_msgs/msg/JointTrajectory", b""),
    ]
    selection = select_for_replay(messages, named=False)
    assert [m.topic for m in selection.messages] == ["/audio/audio"]
    assert selection.left_out == ("/joint_angles", "/raw_trajectory", "/stop")
    named = select_for_replay(messages[1:2], named=True)
    assert named.messages == messages[1:2]
    assert named.commanding == ("/joint_angles",)


def replay(bag, *extra):
    return subprocess.run(
        [*executable_command("audio2pose"), "bag", "replay", str(bag), "--wait-s", "0", *extra],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_when_a_recording_is_replayed_expect_audio_only_and_commands_named(tmp_path, speech):
    bag, messages = recording(tmp_path, speech)
    audio = sum(m.msgtype in INPUT_MESSAGE_TYPES for m in messages)
    result = replay(bag, "--rate", "20")
    assert result.returncode == 0, result.stderr
    assert f"replayed {audio} messages on 2 topics" in result.stdout
    assert "not replayed: /joint_angles" in result.stderr


def test_when_command_topics_are_named_expect_them_replayed_with_a_warning(tmp_path, speech):
    bag, _ = recording(tmp_path, speech)
    result = replay(bag, "--rate", "20", "--topics", "/joint_angles")
    assert result.returncode == 0, result.stderr
    assert "replayed 25 messages on 1 topics" in result.stdout
    assert "warning: replaying /joint_angles" in result.stderr
