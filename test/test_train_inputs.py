"""audio2pose train on inputs at their worst: nothing observed, a tampered training state."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.timebase import complete_frames


def small_dataset(root: Path, robot, observed: bool = True) -> Path:
    """Three 1 s clips (train, validation, test); every joint observed, or none."""
    rng = np.random.default_rng(0)
    dataset = Dataset.create(root, robot)
    for k in range(3):
        audio = (0.1 * rng.standard_normal(16000)).astype(np.float32)
        t = np.arange(complete_frames(audio.size)) / 100.0
        angles = robot.neutral_rad + 0.1 * np.sin(2 * np.pi * (0.5 + k) * t)[:, None]
        angles = np.clip(angles, robot.lower_rad, robot.upper_rad)
        mask = np.full(angles.shape, observed)
        info = ClipInfo(f"c{k}", f"s{k}", "test", "CC0", ("train", "validation", "test")[k])
        dataset.add(Clip(info, audio, angles, mask), robot)
    return root


def test_when_no_joint_angle_is_observed_expect_train_refuses_not_an_untrained_model(
    capsys, tmp_path, robot
):
    """The loss over nothing observed is 0: it read as a perfect fit of the initial weights."""
    data = small_dataset(tmp_path / "ds", robot, observed=False)
    out = tmp_path / "m.safetensors"
    status, stderr = audio2pose(
        capsys, "train", "--data", data, "-o", out, "--model", "mlp", "--max-epochs", "1"
    )
    assert status == 1
    assert_one_line(stderr, "no joint angle is observed in the training clips")
    assert not out.exists()


def _edit_state(state: Path, edit) -> None:
    """Change the training state's metadata in place, as a hand edit or a broken copy would."""
    raw = state.read_bytes()
    size = struct.unpack("<Q", raw[:8])[0]
    container = json.loads(raw[8 : 8 + size])
    meta = json.loads(container["__metadata__"]["audio2pose_train_state"])
    edit(meta)
    container["__metadata__"]["audio2pose_train_state"] = json.dumps(meta)
    text = json.dumps(container).encode()
    text += b" " * (-len(text) % 8)
    state.write_bytes(struct.pack("<Q", len(text)) + text + raw[8 + size :])


@pytest.mark.parametrize(
    ("field", "value", "problem"),
    [
        ("epoch", "x", r"progress\.epoch must be an integer >= 0"),
        ("epoch", -5, r"progress\.epoch must be an integer >= 0"),
        ("learning_rate", float("nan"), r"progress\.learning_rate must be a number"),
        ("learning_rate", 1e400, r"progress\.learning_rate must be finite"),
        ("stage", 50, "training state at stage 50 of a model with"),
    ],
)
def test_when_the_training_state_is_tampered_expect_one_line_naming_the_field(
    capsys, tmp_path, robot, field, value, problem
):
    data = small_dataset(tmp_path / "ds", robot)
    out = tmp_path / "m.safetensors"
    train = ["train", "--data", data, "-o", out, "--model", "mlp", "--max-epochs", "2"]
    status, stderr = audio2pose(capsys, *train)
    assert status == 0, stderr
    _edit_state(
        tmp_path / "m.train-state.safetensors", lambda meta: meta["progress"].update({field: value})
    )
    status, stderr = audio2pose(capsys, *train, "--resume")
    assert status == 1, stderr
    assert_one_line(stderr, r"train-state\.safetensors: .*" + problem)
