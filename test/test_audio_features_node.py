"""audio_features_node as a real process over DDS: format bombs, recovery, the naoqi microphones,
parameters and a diagnostics heartbeat that describes the present. Each test starts the node
alone and plays its publishers from here."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import AudioBuffer
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.pcm import S16LE_MONO_16K, PcmDecoder, PcmFormat, encode_pcm
from audio2pose_ros.audio.streaming import StreamingFeatureExtractor
from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR
from audio2pose_ros.ros.messages import msg_to_features, stamp_s
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS
from audio2pose_ros.ros.tools.process_stats import rss_mb
from audio2pose_ros.topics import DIAGNOSTICS

pytestmark = pytest.mark.ros

NODE = "audio_features_node"
PEPPER_MAP = [3, 5, 0, 2]  # naoqi_driver on Pepper: rear left, rear right, front left, front right


class Peer(Node):
    """Plays audio_capture or naoqi_driver and records features and the node's diagnostics."""

    def __init__(self, naoqi: bool = False) -> None:
        """Publish AudioBuffer (``naoqi``) or AudioInfo and AudioData on the node's topics."""
        super().__init__("audio_peer")
        if naoqi:
            self.audio = self.create_publisher(AudioBuffer, "audio/audio", AUDIO_QOS)
        else:
            self.info = self.create_publisher(AudioInfo, "audio/audio_info", LATCHED_QOS)
            self.audio = self.create_publisher(AudioData, "audio/audio", AUDIO_QOS)
        self.frames: list[np.ndarray] = []
        self.first_frames: list[int | None] = []
        self.statuses: list[tuple[float, DiagnosticStatus]] = []
        self.stamps: list[float] = []  # each status's header stamp: when the node sent it
        self.create_subscription(Float32MultiArray, "features", self._on_features, 1000)
        self.create_subscription(DiagnosticArray, DIAGNOSTICS, self._on_diagnostics, 100)

    def _on_features(self, msg: Float32MultiArray) -> None:
        batch = msg_to_features(msg)
        self.frames.append(batch.frames)
        self.first_frames.append(batch.first_frame)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(NODE):
                self.statuses.append((time.monotonic(), status))
                self.stamps.append(stamp_s(msg.header.stamp))

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.01)

    def wait_until(self, condition: Callable[[], bool], timeout_s: float = 20.0) -> None:
        end = time.monotonic() + timeout_s
        while not condition():
            assert time.monotonic() < end, "timed out"
            rclpy.spin_once(self, timeout_sec=0.01)

    def latest(self) -> DiagnosticStatus:
        return self.statuses[-1][1]

    def fresh_status(self) -> DiagnosticStatus:
        """The first status published from now on (the heartbeat is 0.5 s)."""
        since = time.monotonic()
        self.wait_until(lambda: bool(self.statuses) and self.statuses[-1][0] > since, 3.0)
        return self.latest()

    def n_frames(self) -> int:
        return sum(f.shape[0] for f in self.frames)


def values_of(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@contextmanager
def features_node(tmp_path: Path, *parameters: str) -> Iterator[subprocess.Popen]:
    """The node in its own process (``-p name:=value`` per parameter), stopped afterwards."""
    args = [sys.executable, "-m", "audio2pose_ros.ros.nodes.audio_features_node", "--ros-args"]
    for parameter in parameters:
        args += ["-p", parameter]
    with (tmp_path / f"{NODE}.log").open("w") as log:
        process = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, env=os.environ)
        try:
            yield process
        finally:
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


@pytest.fixture
def peer(request: pytest.FixtureRequest) -> Iterator[Peer]:
    """A Peer playing audio_capture, or naoqi_driver when parametrized with "naoqi"."""
    with rclpy_session():
        node = Peer(naoqi=getattr(request, "param", "") == "naoqi")
        yield node
        node.destroy_node()


def test_when_audio_info_claims_bomb_rates_expect_refusal_kept_then_recovery(
    tmp_path, peer, speech
):
    """Rates 1 and 383999 Hz used to try 62 GiB or grow to 2.3 GB; now they are refused, the
    reason stays on /diagnostics while audio is dropped, and a valid AudioInfo recovers."""
    with features_node(tmp_path) as process:
        peer.wait_until(lambda: bool(peer.statuses) and peer.audio.get_subscription_count() > 0)
        baseline_mb = rss_mb(process.pid)
        dropped = 0
        for rate in (1, 383999):
            peer.info.publish(AudioInfo(channels=1, sample_rate=rate, sample_format="S16LE"))
            peer.spin_for(0.2)

            def bomb_dropped(before: int = dropped) -> bool:
                """Send 128 KiB (a 7.8 GiB allocation at 1 Hz before); True once one is dropped."""
                peer.audio.publish(AudioData(data=bytes(1 << 17)))
                status = peer.fresh_status()  # best effort: a large sample may be lost
                return int(values_of(status)["chunks_dropped"]) > before

            peer.wait_until(bomb_dropped)
            status = peer.latest()
            assert status.level == DiagnosticStatus.ERROR
            assert f"AudioInfo rejected: unsupported sample_rate {rate}" in status.message
            assert "no usable AudioInfo received yet" not in status.message
            dropped = int(values_of(status)["chunks_dropped"])
        assert process.poll() is None
        assert rss_mb(process.pid) < baseline_mb + 50

        peer.info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
        peer.spin_for(0.3)
        payload = encode_pcm(speech[:16000], S16LE_MONO_16K)
        for offset in range(0, len(payload), 3200):
            peer.audio.publish(AudioData(data=payload[offset : offset + 3200]))
            peer.spin_for(0.02)
        peer.wait_until(lambda: peer.n_frames() >= 98)
        status = peer.fresh_status()
        assert status.level == DiagnosticStatus.OK
        assert "decoding S16LE, 1 channel(s), 16000 Hz" in status.message
        assert int(values_of(status)["chunks_dropped"]) == dropped


def test_when_a_message_is_over_a_limit_expect_warn_while_it_happens_then_ok(tmp_path, peer):
    """A stale WARN disappears once the problem is gone."""
    with features_node(tmp_path, "max_chunk_bytes:=4096", "max_chunk_s:=0.1") as process:
        peer.info.publish(AudioInfo(**S16LE_MONO_16K.audio_info_fields()))
        peer.wait_until(lambda: bool(peer.statuses) and "decoding" in peer.latest().message)
        peer.audio.publish(AudioData(data=bytes(5000)))
        peer.wait_until(lambda: peer.latest().level == DiagnosticStatus.WARN)
        assert "AudioData message of 5000 bytes (max_chunk_bytes 4096)" in peer.latest().message
        peer.audio.publish(AudioData(data=bytes(4000)))  # 0.125 s of audio
        peer.wait_until(lambda: "max_chunk_s 0.1" in peer.latest().message)
        warned_s = peer.stamps[-1]
        peer.wait_until(lambda: peer.latest().level == DiagnosticStatus.OK, timeout_s=30.0)
        # held its few seconds, not forever: by the node's own stamps (a loaded machine may
        # deliver them late, the node stamps them when it sends them)
        assert peer.stamps[-1] - warned_s < 7.0
        assert "dropped" not in peer.latest().message
        assert process.poll() is None


@pytest.mark.parametrize("peer", ["naoqi"], indirect=True)
def test_when_naoqi_audio_buffer_plays_expect_features_of_the_selected_channel(
    tmp_path, peer, speech
):
    """naoqi_driver's 48 kHz, 4-channel AudioBuffer; channels:=front_left takes channel 2."""
    one_s = speech[16000:32000]
    at_48k = np.repeat(one_s, 3)
    channels = np.zeros((at_48k.size, 4))
    channels[:, 2] = at_48k  # front left on Pepper
    channels[:, 0] = 0.5 * np.sign(np.sin(np.arange(at_48k.size)))  # loud noise elsewhere
    data = np.clip(np.rint(channels * 32768), -32768, 32767).astype(np.int16)
    decoder = PcmDecoder(PcmFormat("S16LE", 1, 48000))
    expected = StreamingFeatureExtractor(FeatureSpec()).push(
        decoder.feed(data[:, 2].astype("<i2").tobytes())
    )
    with features_node(tmp_path, "input_type:=naoqi", "channels:=front_left") as process:
        peer.wait_until(lambda: peer.count_subscribers("audio/audio") > 0)
        peer.spin_for(0.5)
        for start in range(0, data.shape[0], 4096):  # naoqi_driver's 4096-frame buffers
            msg = AudioBuffer(frequency=48000, channel_map=PEPPER_MAP)
            msg.data = data[start : start + 4096].ravel().tolist()
            peer.audio.publish(msg)
            peer.spin_for(0.02)
        peer.wait_until(lambda: peer.n_frames() >= expected.shape[0])
        status = peer.fresh_status()
        assert process.poll() is None
    frames = np.concatenate(peer.frames)
    np.testing.assert_allclose(frames[: expected.shape[0]], expected, rtol=0, atol=1e-4)
    assert status.level == DiagnosticStatus.OK
    assert values_of(status)["channels_used"] == "(2,)"
    # each message numbers its first frame: the receiver sees that none was lost
    sizes = [len(f) for f in peer.frames]
    assert peer.first_frames == list(np.cumsum([0, *sizes[:-1]])), peer.first_frames


@pytest.mark.parametrize(
    ("parameter", "match"),
    [
        ("channels:=front_left", "names channels, which only AudioBuffer carries"),
        ("max_chunk_s:=.nan", "parameter max_chunk_s: value nan is not finite"),
        ("input_type:=alsa", "parameter input_type: value 'alsa' is not allowed"),
        ("model_path:=/nonexistent/model.safetensors", "/nonexistent/model.safetensors"),
    ],
)
def test_when_a_parameter_is_refused_expect_one_line_and_the_configuration_exit(
    tmp_path, parameter, match
):
    with features_node(tmp_path, parameter) as process:
        assert process.wait(30) == EXIT_CONFIGURATION_ERROR
    log = (tmp_path / f"{NODE}.log").read_text()
    assert match in log
    assert "Traceback" not in log


def test_when_parameters_described_and_set_live_expect_descriptors_and_validated_changes():
    """Every parameter has a descriptor; integers pass for floats; live changes are validated
    read-only ones are refused, bad values refused with the reason."""
    from rclpy.parameter import Parameter

    from audio2pose_ros.ros.nodes.audio_features_node import PARAMETERS, AudioFeaturesNode

    with rclpy_session(["--ros-args", "-p", "max_chunk_s:=1"]):
        node = AudioFeaturesNode()
        try:
            assert node.get_parameter("max_chunk_s").value == 1.0
            for spec in PARAMETERS:
                descriptor = node.describe_parameter(spec.name)
                assert descriptor.description.startswith(spec.description)
                assert descriptor.read_only == (spec.name in ("model_path", "input_type"))
            assert node.describe_parameter("max_chunk_s").floating_point_range[0].to_value == 60.0

            def set_one(name: str, value: object) -> tuple[bool, str]:
                result = node.set_parameters([Parameter(name, value=value)])[0]
                return result.successful, result.reason

            assert set_one("channels", "1") == (True, "")
            assert node.input.settings.channels == "1"
            ok, reason = set_one("channels", "left")
            assert not ok
            assert "parameter channels: value 'left' not understood" in reason
            ok, reason = set_one("max_chunk_s", float("nan"))
            assert not ok
            assert "max_chunk_s" in reason
            assert set_one("input_type", "naoqi")[0] is False
            assert node.input.settings.max_chunk_s == 1.0  # refused changes left nothing behind
        finally:
            node.destroy_node()
