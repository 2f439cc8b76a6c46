"""Bags: speech bags from WAV (MCAP and SQLite 3), audio read back, bad bags refused."""

from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.data.bag import (
    AUDIO_INFO_TOPIC,
    AUDIO_TOPIC,
    BagError,
    BagWriter,
    Chunking,
    audio_messages,
    read_bag_audio,
    read_messages,
    typestore,
    write_audio_bag,
)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_when_wav_written_as_bag_expect_same_audio_back(tmp_path: Path, speech, storage):
    count = write_audio_bag(speech, tmp_path / "bag", storage=storage)
    assert count > 10
    np.testing.assert_array_equal(read_bag_audio(tmp_path / "bag"), speech)


def test_when_chunking_expect_odd_sizes_real_time_stamps_and_periodic_info(speech):
    messages = audio_messages(speech, Chunking(min_bytes=101, max_bytes=999, seed=3))
    data = [m for m in messages if m.topic == AUDIO_TOPIC]
    store = typestore()
    sizes = [len(store.deserialize_cdr(m.data, m.msgtype).data) for m in data]
    assert any(s % 2 for s in sizes)  # samples split across messages
    assert max(sizes) <= 999
    assert sum(sizes) == 2 * len(speech)
    stamps = np.array([m.timestamp_ns for m in data]) * 1e-9
    assert stamps[-1] == pytest.approx(len(speech) / 16000, abs=0.01)  # real time
    infos = [m for m in messages if m.topic == AUDIO_INFO_TOPIC]
    assert len(infos) == 1 + int(len(speech) / 16000 // 5)  # every 5 s, as audio_capture


def test_when_audio_precedes_audio_info_expect_error(tmp_path: Path, speech):
    messages = audio_messages(speech[:8000])
    with BagWriter(tmp_path / "bag") as bag:
        for m in messages:
            if m.topic == AUDIO_TOPIC:
                bag.write(m.topic, m.msgtype, m.timestamp_ns + 1, m.data)
    with pytest.raises(BagError, match="before any AudioInfo"):
        read_bag_audio(tmp_path / "bag")


def test_when_path_is_not_a_bag_expect_error_naming_it(tmp_path: Path):
    with pytest.raises(BagError, match=r"nothing\.mcap: cannot open as a rosbag2"):
        list(read_messages(tmp_path / "nothing.mcap"))


def _replay_command(bag: Path) -> list[str]:
    """`audio2pose bag replay` of the bag's audio at 4x, waiting up to 30 s for a subscriber."""
    from audio2pose_ros.ros.supervisor import executable_command

    return [
        *executable_command("audio2pose"),
        *("bag", "replay", str(bag), "--rate", "4", "--topics", AUDIO_TOPIC, "--wait-s", "30"),
    ]


@pytest.mark.ros
@pytest.mark.slow
def test_when_bag_replayed_faster_expect_every_message_published_in_order(tmp_path, speech, probe):
    import subprocess
    import time

    bag = tmp_path / "bag"
    write_audio_bag(speech[:32000], bag)  # 2 s of speech
    expected = [m for m in read_messages(bag) if m.topic == AUDIO_TOPIC]
    received = []
    from audio_common_msgs.msg import AudioData

    probe.create_subscription(AudioData, AUDIO_TOPIC, received.append, 1000)
    replay = subprocess.Popen(
        _replay_command(bag),  # replay starts as soon as this probe's subscription is matched
        stdout=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 60
    while replay.poll() is None and time.monotonic() < deadline:
        probe.spin_for(0.05)
    probe.spin_for(0.5)
    assert replay.returncode == 0
    assert "replayed" in replay.stdout.read()
    store = typestore()
    assert [bytes(m.data) for m in received] == [
        bytes(store.deserialize_cdr(m.data, m.msgtype).data) for m in expected
    ]


# A reliable subscriber that stops itself after its first message: it stays matched but never
# acknowledges the rest.
_STALLING_SUBSCRIBER = """
import os, signal, sys
import rclpy
from audio_common_msgs.msg import AudioData
from rclpy.qos import QoSProfile, ReliabilityPolicy
rclpy.init()
node = rclpy.create_node("stalling_subscriber")
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
stop = lambda message: os.kill(os.getpid(), signal.SIGSTOP)
node.create_subscription(AudioData, sys.argv[1], stop, qos)
rclpy.spin(node)
"""


@pytest.mark.ros
@pytest.mark.slow
def test_when_a_subscriber_does_not_acknowledge_the_replay_expect_exit_1_and_a_warning(
    tmp_path, speech
):
    import subprocess
    import sys

    from audio2pose_ros.ros.player import ACK_TIMEOUT_S

    bag = tmp_path / "bag"
    write_audio_bag(speech[:32000], bag)
    subscriber = subprocess.Popen([sys.executable, "-c", _STALLING_SUBSCRIBER, AUDIO_TOPIC])
    try:
        replay = subprocess.run(
            _replay_command(bag),
            capture_output=True,
            text=True,
            timeout=90,
        )
    finally:
        subscriber.kill()
        subscriber.wait()
    assert "replayed" in replay.stdout
    assert replay.returncode == 1, replay.stderr
    assert f"did not acknowledge every message within {ACK_TIMEOUT_S:g} s" in replay.stderr


@pytest.mark.parametrize(
    ("sizes", "problem"),
    [
        ((0, 0), r"1 <= min_bytes \(0\) <= max_bytes \(0\)"),
        ((10, 5), r"min_bytes \(10\) <= max_bytes \(5\)"),
        ((1, 2**40), r"<= 1048576"),
    ],
)
def test_when_chunk_sizes_cannot_finish_or_be_drawn_expect_configuration_error(sizes, problem):
    from audio2pose_ros.errors import ConfigurationError

    with pytest.raises(ConfigurationError, match=problem):
        Chunking(min_bytes=sizes[0], max_bytes=sizes[1])
