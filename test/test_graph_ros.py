"""The node graph over real DDS: three node processes, real speech in, commands out.

Each test starts the real executables as separate processes (as `audio2pose run` and the launch
file do) and talks to them from this process with real rclpy. Only the robot is missing: the
commands are checked where naoqi_driver / ros2_control would receive them.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.audio.pcm import PcmFormat, encode_pcm, read_wav
from audio2pose_ros.cli.graph import executable_command, node_graph
from audio2pose_ros.nodes.common import LATCHED_QOS

pytestmark = [pytest.mark.ros, pytest.mark.slow]

S16 = PcmFormat(sample_format="S16LE", channels=1, sample_rate_hz=16000, coding_format="wave")


class Probe(Node):
    """Publishes audio like audio_capture and records everything the graph sends."""

    def __init__(self) -> None:
        super().__init__("test_probe")
        self.audio = self.create_publisher(AudioData, "/audio/audio", 100)
        self.info = self.create_publisher(AudioInfo, "/audio/audio_info", LATCHED_QOS)
        self.received: dict[str, list] = {
            k: [] for k in ("angles", "trajectory", "states", "raw", "features", "diagnostics")
        }
        for key, msg_type, topic in (
            ("angles", JointAnglesWithSpeed, "/joint_angles"),
            ("trajectory", JointTrajectory, "/joint_trajectory_controller/joint_trajectory"),
            ("states", JointState, "/joint_states"),
            ("raw", JointTrajectory, "/raw_trajectory"),
            ("features", Float32MultiArray, "/features"),
            ("diagnostics", DiagnosticArray, "/diagnostics"),
        ):
            self.create_subscription(msg_type, topic, self.received[key].append, 1000)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(self, timeout_sec=0.005)

    def wait_until(self, condition, timeout_s: float = 60.0) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if condition():
                return
            rclpy.spin_once(self, timeout_sec=0.05)
        raise TimeoutError("condition not met in time")

    def graph_ready(self) -> bool:
        return (
            self.audio.get_subscription_count() > 0
            and self.count_subscribers("/features") > 0
            and self.count_subscribers("/raw_trajectory") > 0
            and self.count_publishers("/joint_angles") > 0
        )

    def warm_up(self) -> None:
        """Send silence until poses come back: every link of the graph has matched.

        DDS discovery is asymmetric: our side may see a subscriber before the node's own
        publisher has matched the next node, and reliable volatile samples sent before that
        are lost. 160-sample chunks keep the feature extractor aligned to whole frames.
        """
        silence = bytes(2 * 160)

        def poses_arrive() -> bool:
            self.audio.publish(AudioData(data=silence))
            self.spin_for(0.02)
            return bool(self.received["raw"]) and bool(self.received["angles"])

        self.wait_until(poses_arrive, timeout_s=60)
        for _ in range(5):  # make the warm-up longer than one 25 ms window
            self.audio.publish(AudioData(data=silence))
        self.spin_for(0.5)
        for key in self.received:
            self.received[key].clear()

    def play(self, payload: bytes, chunk_sizes: list[int], bytes_per_s: float) -> int:
        """Send ``payload`` in chunks of the given sizes (cycled), paced at ``bytes_per_s``."""
        start, offset, i = time.monotonic(), 0, 0
        while offset < len(payload):
            size = chunk_sizes[i % len(chunk_sizes)]
            due = start + offset / bytes_per_s
            while time.monotonic() < due:
                rclpy.spin_once(self, timeout_sec=0.001)
            self.audio.publish(AudioData(data=payload[offset : offset + size]))
            offset += size
            i += 1
        return i


@pytest.fixture
def probe():
    with rclpy.init():
        node = Probe()
        yield node
        node.destroy_node()


def diagnostics_of(probe: Probe, node_name: str) -> dict[str, str]:
    for array in reversed(probe.received["diagnostics"]):
        for status in array.status:
            if status.name.endswith(node_name):
                return {kv.key: kv.value for kv in status.values}
    return {}


def test_when_speech_streamed_in_odd_chunks_expect_commands_for_11_joints_within_limits(
    tmp_path: Path, probe: Probe, robot, speech_files
):
    wav = speech_files[1]  # 2.99 s of LibriVox speech
    samples, _ = read_wav(wav)
    payload = encode_pcm(samples, S16)
    rng = np.random.default_rng(7)
    chunk_sizes = [int(s) | 1 for s in rng.integers(1, 4000, size=64)]  # odd sizes: split samples
    with node_graph(log_dir=tmp_path) as processes:
        probe.info.publish(
            AudioInfo(
                channels=1,
                sample_rate=16000,
                sample_format="S16LE",
                bitrate=256000,
                coding_format="wave",
            )
        )
        probe.wait_until(probe.graph_ready)
        probe.warm_up()
        probe.play(payload, chunk_sizes, bytes_per_s=32000)
        probe.spin_for(1.5)
        assert all(p.poll() is None for p in processes), "a node died"

    duration_s = len(samples) / 16000
    raw_points = sum(len(m.points) for m in probe.received["raw"])
    # After the warm-up every 160 new samples complete one more 25 ms window: 100 poses per
    # second of audio, none lost.
    expected = len(samples) // 160
    assert raw_points == expected, (raw_points, expected, duration_s)

    angles = probe.received["angles"]
    assert len(angles) >= 0.9 * 100 * duration_s  # 100 Hz commands while speech plays
    positions = np.array([m.joint_angles for m in angles])
    assert all(list(m.joint_names) == list(robot.names) for m in angles)
    assert positions.shape[1] == 11
    assert np.all(positions >= robot.lower_rad - 1e-6)
    assert np.all(positions <= robot.upper_rad + 1e-6)
    assert np.all(np.isfinite(positions))
    assert np.ptp(positions, axis=0).max() > 0.05  # the voice moves the robot

    states = probe.received["states"]
    trajectories = probe.received["trajectory"]
    assert len(states) > 0.9 * 50 * duration_s
    assert len(trajectories) > 0.9 * 100 * duration_s
    for msg in trajectories[:20]:
        assert list(msg.joint_names) == list(robot.names)
        assert len(msg.points) == 1
        assert len(msg.points[0].positions) == 11
    state_positions = np.array([m.position for m in states])
    assert np.all(state_positions >= robot.lower_rad - 1e-6)
    assert np.all(state_positions <= robot.upper_rad + 1e-6)


def test_when_audio_is_malformed_expect_logged_skipped_and_node_keeps_running(
    tmp_path: Path, probe: Probe, speech
):
    good = encode_pcm(speech[:16000], S16)
    with node_graph(log_dir=tmp_path) as processes:
        probe.wait_until(probe.graph_ready)

        # 1. No AudioInfo yet: audio is dropped and counted in /diagnostics, nothing published.
        def dropped_reported() -> bool:
            probe.audio.publish(AudioData(data=good[:3200]))
            probe.spin_for(0.2)
            return int(diagnostics_of(probe, "audio_features_node").get("dropped_bytes", 0)) > 0

        probe.wait_until(dropped_reported, timeout_s=20)
        assert probe.received["features"] == []

        # 2. An AudioInfo with an unknown sample format: rejected, audio still dropped.
        probe.info.publish(
            AudioInfo(
                channels=1,
                sample_rate=16000,
                sample_format="S24BE",
                bitrate=0,
                coding_format="wave",
            )
        )
        probe.spin_for(0.5)
        probe.audio.publish(AudioData(data=good[:3200]))
        probe.spin_for(0.5)
        assert probe.received["features"] == []

        # 3. F32LE with NaN samples and an empty message: dropped; valid audio then works.
        probe.info.publish(
            AudioInfo(
                channels=1,
                sample_rate=16000,
                sample_format="F32LE",
                bitrate=0,
                coding_format="wave",
            )
        )
        probe.spin_for(0.5)
        nan_chunk = np.full(800, np.nan, dtype="<f4").tobytes()
        probe.audio.publish(AudioData(data=nan_chunk))
        probe.audio.publish(AudioData(data=b""))
        probe.spin_for(0.5)
        floats = speech[:16000].astype("<f4").tobytes()
        probe.play(floats, [1001, 3, 4097], bytes_per_s=64000)  # odd sizes split the floats
        probe.spin_for(1.5)
        assert all(p.poll() is None for p in processes), "a node died on bad input"

    frames = sum(m.layout.dim[0].size for m in probe.received["features"])
    assert frames == 1 + (16000 - 400) // 160  # exactly one second of audio after the bad bits
    log = (tmp_path / "audio_features_node.log").read_text()
    assert "no usable AudioInfo received yet" in log
    assert "S24BE" in log
    assert "dropped an audio chunk" in log


def run_inference_node_until_error(probe: Probe, model: Path, log: Path) -> str:
    """Start inference_node on ``model``; return its ERROR diagnostics message.

    Asserts that the node stays up (a respawning supervisor would loop on an exit) and
    publishes no trajectory.
    """
    with log.open("w") as stream:
        process = subprocess.Popen(
            [*executable_command("inference_node"), "--ros-args", "-p", f"model_path:={model}"],
            stdout=stream,
            stderr=subprocess.STDOUT,
        )

    def error_status():
        return next(
            (
                status
                for array in probe.received["diagnostics"]
                for status in array.status
                if status.level == DiagnosticStatus.ERROR and status.name.endswith("inference_node")
            ),
            None,
        )

    try:
        probe.wait_until(lambda: error_status() is not None, timeout_s=60)
        probe.spin_for(2.0)
        assert process.poll() is None, "the node exited: a respawning supervisor would loop"
        assert probe.received["raw"] == []
    finally:
        process.terminate()
        process.wait(timeout=10)
    assert "Traceback" not in log.read_text()
    return error_status().message


def test_when_checkpoint_tampered_expect_idle_node_reporting_error(tmp_path: Path, probe: Probe):
    from audio2pose_ros.resources import default_checkpoint_path

    data = bytearray(default_checkpoint_path().read_bytes())
    data[-5] ^= 0x55
    tampered = tmp_path / "tampered.safetensors"
    tampered.write_bytes(bytes(data))
    message = run_inference_node_until_error(probe, tampered, tmp_path / "node.log")
    assert "configuration error" in message
    assert "checksum mismatch" in message


def test_when_model_is_offline_only_expect_refusal_pointing_to_synth(
    tmp_path: Path, probe: Probe, robot
):
    from audio2pose_ros.audio.features import FeatureNormalizer, FeatureSpec
    from audio2pose_ros.models import build_model
    from audio2pose_ros.models.checkpoint import Checkpoint, save_checkpoint

    spec = FeatureSpec()
    model = build_model("cvae", {"n_features": spec.dim, "n_joints": robot.n_joints})
    path = save_checkpoint(
        tmp_path / "cvae.safetensors",
        Checkpoint(
            model,
            spec,
            FeatureNormalizer.fit(np.random.default_rng(0).normal(size=(50, spec.dim))),
            robot,
        ),
    )
    message = run_inference_node_until_error(probe, path, tmp_path / "node.log")
    assert "audio2pose synth" in message
