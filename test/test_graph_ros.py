"""The node graph over real DDS: three node processes, real speech in, commands out.

Each test starts the real executables as separate processes (as `audio2pose run` and the launch
file do) and talks to them from this process with real rclpy. Only the robot is missing: the
commands are checked where naoqi_driver / ros2_control would receive them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from audio_common_msgs.msg import AudioData, AudioInfo
from graph_probe import Probe, diagnostics_of
from node_processes import configuration_error_line

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.ros.nodes.motion_filter_node import PARAMETERS as FILTER_PARAMETERS
from audio2pose_ros.ros.supervisor import node_graph

pytestmark = [pytest.mark.ros, pytest.mark.slow]

S16 = S16LE_MONO_16K


def test_when_speech_streamed_in_odd_chunks_expect_commands_for_11_joints_within_limits(
    tmp_path: Path, probe: Probe, robot, speech_files
):
    wav = speech_files[1]  # 2.99 s of LibriVox speech
    samples, _ = read_wav(wav)
    payload = encode_pcm(samples, S16)
    rng = np.random.default_rng(7)
    chunk_sizes = [int(s) | 1 for s in rng.integers(1, 4000, size=64)]  # odd sizes: split samples
    with node_graph(log_dir=tmp_path, no_robot=True) as graph:
        probe.info.publish(AudioInfo(**S16.audio_info_fields()))
        probe.wait_until(probe.graph_ready)
        probe.warm_up()
        probe.play(payload, chunk_sizes, bytes_per_s=32000)
        probe.spin_for(1.5)
        assert not any(graph.restarts.values()), "a node died"
        assert all(p.poll() is None for p in graph.processes.values())

    duration_s = len(samples) / 16000
    raw_points = sum(len(m.points) for m in probe.received["raw"])
    # After the warm-up every 160 new samples complete one more 25 ms window: 100 poses per
    # second of audio, none lost.
    expected = len(samples) // 160
    assert raw_points == expected, (raw_points, expected, duration_s)

    angles = probe.received["angles"]
    rate_hz = default_of("joint_angles_rate_hz")
    assert len(angles) >= 0.9 * rate_hz * duration_s  # evenly spaced commands while speech plays
    positions = np.array([m.joint_angles for m in angles])
    assert all(list(m.joint_names) == list(robot.names) for m in angles)
    assert positions.shape[1] == 11
    assert np.all(positions >= robot.lower_rad - 1e-6)
    assert np.all(positions <= robot.upper_rad + 1e-6)
    assert np.all(np.isfinite(positions))
    assert np.ptp(positions, axis=0).max() > 0.05  # the voice moves the robot

    states = probe.received["states"]
    trajectories = probe.received["trajectory"]
    assert len(states) > 0.9 * default_of("joint_states_rate_hz") * duration_s
    assert len(trajectories) > 0.9 * default_of("joint_trajectory_rate_hz") * duration_s
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
    with node_graph(log_dir=tmp_path, no_robot=True) as graph:
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
        assert not any(graph.restarts.values()), "a node died on bad input"
        assert all(p.poll() is None for p in graph.processes.values())

    frames = sum(m.layout.dim[0].size for m in probe.received["features"])
    assert frames == 1 + (16000 - 400) // 160  # exactly one second of audio after the bad bits
    log = (tmp_path / "audio_features_node.log").read_text()
    assert "no usable AudioInfo received yet" in log
    assert "S24BE" in log
    assert "dropped an audio chunk" in log


def default_of(parameter: str) -> float:
    """The motion filter's declared default of ``parameter``."""
    return float(next(s.default for s in FILTER_PARAMETERS if s.name == parameter))


def test_when_checkpoint_tampered_expect_one_line_and_no_respawnable_exit(tmp_path: Path):
    from audio2pose_ros.resources import default_checkpoint_path

    data = bytearray(default_checkpoint_path().read_bytes())
    data[-5] ^= 0x55
    tampered = tmp_path / "tampered.safetensors"
    tampered.write_bytes(bytes(data))
    message = configuration_error_line("inference_node", "-p", f"model_path:={tampered}")
    assert "checksum mismatch" in message


def test_when_model_is_offline_only_expect_refusal_pointing_to_synth(tmp_path: Path, robot):
    from audio2pose_ros.audio.features import FeatureSpec
    from audio2pose_ros.audio.normalize import FeatureNormalizer
    from audio2pose_ros.checkpoints.torch_io import Checkpoint, save_checkpoint
    from audio2pose_ros.models.registry import build_model

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
    message = configuration_error_line("inference_node", "-p", f"model_path:={path}")
    assert "audio2pose synth" in message
