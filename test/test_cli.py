"""The audio2pose command: run/record through the live graph, offline synth, bench, errors."""

from __future__ import annotations

import csv
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.supervisor import executable_command
from audio2pose_ros.topics import AUDIO, AUDIO_INFO, COMMANDED_JOINT_STATES, JOINT_ANGLES, absolute

AUDIO2POSE = executable_command("audio2pose")
COMMAND_TOPICS = {
    absolute(JOINT_ANGLES),
    CONTROLLER_TOPIC,
    absolute(COMMANDED_JOINT_STATES),
}


@pytest.mark.ros
@pytest.mark.slow
def test_when_run_plays_and_records_expect_mcap_both_readers_open(
    tmp_path: Path, robot, speech_files
):
    wav = speech_files[1]
    bag = tmp_path / "bag"
    result = subprocess.run(
        [
            *AUDIO2POSE,
            "run",
            "--no-robot",  # what a robot would receive, recorded
            *("--play", str(wav), "--record", str(bag), "--log-dir", str(tmp_path)),
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert result.returncode == 0, result.stderr
    assert "/joint_angles:" in result.stdout

    # Independent reader 1: the mcap library with its own ROS 2 decoder.
    counts: Counter[str] = Counter()
    angles = []
    with next(bag.glob("*.mcap")).open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            if channel.topic == absolute(JOINT_ANGLES):
                assert list(msg.joint_names) == list(robot.names)
                angles.append(msg.joint_angles)
    assert set(counts) >= COMMAND_TOPICS
    assert counts[absolute(AUDIO_INFO)] == 1
    assert counts[absolute(AUDIO)] > 0
    duration_s = len(read_wav(wav)[0]) / 16000
    filter_params = yaml.safe_load(share_path("config", "pepper.yaml").read_text())[
        "motion_filter_node"
    ]["ros__parameters"]
    assert (
        counts[absolute(JOINT_ANGLES)] >= 0.9 * filter_params["joint_angles_rate_hz"] * duration_s
    )
    angles = np.array(angles)
    assert np.all(angles >= robot.lower_rad - 1e-6)
    assert np.all(angles <= robot.upper_rad + 1e-6)

    # Independent reader 2: rosbags, from the bag's own metadata and schemas.
    with AnyReader([bag]) as reader:
        seen = Counter(conn.topic for conn, _, _ in reader.messages())
        for conn, _, raw in reader.messages(connections=reader.connections):
            reader.deserialize(raw, conn.msgtype)  # every message decodes
    assert seen == counts


def test_when_record_without_play_expect_clear_error(tmp_path: Path):
    result = subprocess.run(
        [*AUDIO2POSE, "run", "--record", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2  # a usage error
    assert "--record needs --play" in result.stderr


@pytest.mark.parametrize("command", ["run", "console"])
def test_when_sim_and_no_robot_are_both_given_expect_a_usage_error_before_anything_runs(command):
    result = subprocess.run(
        [*AUDIO2POSE, command, "--sim", "--no-robot"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2  # a usage error
    assert "--sim and --no-robot" in result.stderr


@pytest.mark.ros
@pytest.mark.parametrize(
    ("content", "gave_up"),
    [
        (b"motion_filter_node:\n  ros__parameters: [1, 2]\n", "_node"),  # rcl: all three
        (b"motion_filter_node:\n  ros__parameters:\n    head_gain: .nan\n", "motion_filter_node"),
    ],
    ids=["every-node", "the-filter"],
)
def test_when_a_node_refuses_its_parameters_expect_run_to_stop_and_fail(
    tmp_path: Path, content: bytes, gave_up: str
):
    """Without the filter (or any node) nothing reaches the robot: `run` must not carry on.

    The graph stops as soon as the supervisor gives up on a node, naming the nodes it gave up on.
    """
    params = tmp_path / "params.yaml"
    params.write_bytes(content)
    result = subprocess.run(
        [*AUDIO2POSE, "run", "--params-file", str(params), "--log-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert "refused its configuration" in result.stderr
    assert result.returncode == 1, result.stderr[-500:]
    last = result.stderr.strip().splitlines()[-1]
    assert "the graph stopped: gave up on" in last
    assert gave_up in last


def test_when_synth_wav_expect_csv_at_100hz_within_limits(tmp_path: Path, robot, speech_path):
    out = tmp_path / "traj.csv"
    result = subprocess.run(
        [*AUDIO2POSE, "synth", str(speech_path), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    with out.open() as stream:
        rows = list(csv.reader(stream))
    assert rows[0] == ["time_s", *robot.names]
    data = np.array(rows[1:], dtype=float)
    n_samples = len(read_wav(speech_path)[0])
    assert len(data) == 1 + -(-(n_samples - 400) // 160)  # python_speech_features' frame count
    np.testing.assert_allclose(np.diff(data[:, 0]), 0.01, atol=1e-3)
    assert np.all(data[:, 1:] >= robot.lower_rad - 1e-6)
    assert np.all(data[:, 1:] <= robot.upper_rad + 1e-6)
    assert np.ptp(data[:, 1:], axis=0).max() > 0.05


def test_when_synth_missing_file_expect_error_naming_it(tmp_path: Path):
    result = subprocess.run(
        [*AUDIO2POSE, "synth", str(tmp_path / "nope.wav"), "-o", str(tmp_path / "o.csv")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1
    assert "nope.wav" in result.stderr


def test_when_bench_runs_expect_every_stage_timed():
    """The stage table (the model table, minutes of offline synthesis, is tested on its own)."""
    result = subprocess.run(
        [*AUDIO2POSE, "bench", "--frames", "30", "--skip-models"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    for stage in (
        "features",
        "model step",
        "motion filter",
        "whole online frame",
        "python_speech_features",
    ):
        assert stage in result.stdout
    assert "x faster" in result.stdout


def test_when_core_modules_imported_expect_no_ros():
    code = (
        "import sys\n"
        "import audio2pose_ros.audio.features, audio2pose_ros.audio.pcm\n"
        "import audio2pose_ros.robot.description\n"
        "import audio2pose_ros.motion.filter, audio2pose_ros.motion.prosody\n"
        "import audio2pose_ros.checkpoints.torch_io, audio2pose_ros.offline.synthesis\n"
        "import audio2pose_ros.learning.training, audio2pose_ros.offline.benchmark\n"
        "import audio2pose_ros.data.bag\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rosidl_runtime_py')]\n"
        "print(bad)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_when_plot_filter_expect_png_and_figures(tmp_path: Path, speech_files):
    out = tmp_path / "filter.png"
    result = subprocess.run(
        [*AUDIO2POSE, "plot-filter", str(speech_files[1]), "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    figures = dict(line.split(": ") for line in result.stdout.splitlines()[1:])
    # The filter smooths: the commanded motion is slower than the raw model output.
    assert float(figures["online_rms_speed_rad_s"]) < float(figures["raw_rms_speed_rad_s"])


def test_when_distill_prosody_expect_loadable_checkpoint_and_honest_card(
    tmp_path: Path, robot, speech_files
):
    out = tmp_path / "rule.safetensors"
    result = subprocess.run(
        [
            *AUDIO2POSE,
            "distill-prosody",
            *map(str, speech_files[:2]),
            "-o",
            str(out),
            "--max-epochs",
            "2",  # the command and its outputs, not the fit: training is test_training.py's
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint

    checkpoint = load_checkpoint(out, robot=robot)
    assert "not human motion" in checkpoint.info["trained_on"]
    card = (tmp_path / "MODEL_CARD.md").read_text()
    assert "It was not trained on human motion" in card
    assert "neutral-pose RMSE deg" in result.stdout


def test_when_bench_prints_json_expect_one_object_with_its_schema_version(capsys):
    import json

    from audio2pose_ros.cli.bench_commands import BENCH_SCHEMA_VERSION
    from audio2pose_ros.cli.main import main

    assert main(["bench", "--frames", "20", "--skip-models", "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert isinstance(figures, dict)
    assert figures["schema_version"] == BENCH_SCHEMA_VERSION
    assert "motion filter (push + tick)" in figures["stages_us"]


def test_when_bench_is_paced_expect_one_call_per_frame_period_and_it_said(capsys):
    """--paced times the stages one frame every 10 ms (a lower bound on the time it takes)."""
    import json
    import time

    from audio2pose_ros.cli.main import main
    from audio2pose_ros.offline.benchmark import _time_calls

    calls: list[float] = []
    start = time.monotonic()
    durations = _time_calls([lambda: calls.append(time.monotonic())] * 5, period_s=0.02)
    assert len(durations) == 5
    # call k waits for period k (a lower bound: a loaded machine can only make it later)
    assert all(at - start >= 0.02 * k - 1e-3 for k, at in enumerate(calls))
    assert main(["bench", "--frames", "20", "--skip-models", "--json", "--paced"]) == 0
    assert json.loads(capsys.readouterr().out)["stages_paced"] is True


def test_when_every_model_family_is_timed_expect_a_row_each_with_its_costs():
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.models.registry import MODEL_REGISTRY
    from audio2pose_ros.offline.benchmark import model_costs
    from audio2pose_ros.resources import bundled_speech_path
    from audio2pose_ros.robot.description import load_robot

    signal, _ = read_wav(bundled_speech_path())
    costs = model_costs(signal[:16000], load_robot(), n_frames=10, repeats=1)
    assert [cost.name for cost in costs] == list(MODEL_REGISTRY)
    for cost in costs:
        assert cost.offline_audio_s_per_s > 0.0
        if cost.step is not None:  # streaming: its step, numpy kernel and torch call timed
            assert cost.step.calls == 10
            assert cost.kernel_step is not None
            assert cost.torch_step is not None
    assert any(cost.step is None for cost in costs)  # the offline-only families have no step
