"""``audio2pose train`` then ``audio2pose evaluate`` on a tiny data set folder; synthesis of all."""

import argparse
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.cli.model_commands import register
from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.learning.evaluation import MEAN_MOTION, NEUTRAL, OTHER_UTTERANCE, evaluate
from audio2pose_ros.offline.synthesis import synthesize

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_motion import write_dataset

torch.set_num_threads(1)


def run_cli(argv):
    parser = argparse.ArgumentParser(prog="audio2pose")
    register(parser.add_subparsers(dest="verb", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def folder(tmp_path_factory, robot):
    root = tmp_path_factory.mktemp("eval") / "data"
    write_dataset(root, robot, {"train": 4, "validation": 1, "test": 2}, seconds=2.0, seed=3)
    return root


def test_when_train_then_evaluate_cli_expect_table_and_one_png_per_clip(folder, tmp_path, capsys):
    models = {}
    for name in ("mlp", "cvae"):
        models[name] = tmp_path / f"{name}.safetensors"
        assert (
            run_cli(
                [
                    "train",
                    "--model",
                    name,
                    "--data",
                    str(folder),
                    "-o",
                    str(models[name]),
                    "--max-epochs",
                    "3",
                ]
            )
            == 0
        )
    assert "wrote" in capsys.readouterr().out
    out = tmp_path / "report"
    assert (
        run_cli(
            [
                "evaluate",
                "--data",
                str(folder),
                str(models["mlp"]),
                str(models["cvae"]),
                "--out",
                str(out),
            ]
        )
        == 0
    )
    table = capsys.readouterr().out
    for row in (NEUTRAL, MEAN_MOTION, OTHER_UTTERANCE, "mlp (mlp)", "cvae (cvae)"):
        assert row in table
    for column in ("RMSE deg", "LCCA_Theta", "Delta J", "H speed", "diversity deg"):
        assert column in table
    assert sorted(p.name for p in out.glob("*.png")) == [
        "distributions.png",
        "test0.png",
        "test1.png",
    ]
    assert "head  cvae (cvae)" in table  # the per-group distribution table follows
    assert (out / "metrics.txt").read_text().startswith("2 clips")


def test_when_evaluating_expect_neutral_baseline_matches_hand_rmse(folder, robot):
    dataset = Dataset.open(folder, robot)
    result = evaluate([], dataset, robot, split="test")
    neutral = result.methods[0]
    clip = dataset.load("test0")
    n = min(clip.n_frames, 1 + (clip.audio.size - 400) // 160)
    expected = np.degrees(np.sqrt(np.mean((clip.angles_rad[:n] - robot.neutral_rad) ** 2)))
    assert neutral.per_clip[0]["RMSE deg"] == pytest.approx(expected, rel=1e-6)
    assert neutral.per_clip[0]["J 1e3 rad2/s5"] == pytest.approx(0.0, abs=1e-12)  # still pose


@pytest.mark.parametrize("name", ["dae_gru", "blstm_prior", "cvae", "live"])
def test_when_synthesizing_any_model_expect_limited_angles_and_seeded_samples(
    name, folder, tmp_path, robot
):
    path = tmp_path / f"{name}.safetensors"
    assert (
        run_cli(
            ["train", "--model", name, "--data", str(folder), "-o", str(path), "--max-epochs", "1"]
        )
        == 0
    )
    checkpoint = load_checkpoint(path, robot=robot)
    audio = Dataset.open(folder, robot).load("test0").audio
    times, angles = synthesize(checkpoint, audio, seed=1)
    assert angles.shape == (times.size, robot.n_joints)
    assert np.all((angles >= robot.lower_rad) & (angles <= robot.upper_rad))
    np.testing.assert_array_equal(synthesize(checkpoint, audio, seed=1)[1], angles)
    if checkpoint.model.stochastic:
        assert np.abs(synthesize(checkpoint, audio, seed=2)[1] - angles).max() > 0


def test_when_evaluating_leave_one_speaker_out_expect_group_table_with_baselines_and_figure(
    folder, tmp_path, capsys
):
    out = tmp_path / "loso"
    argv = ["evaluate", "--data", str(folder), "--loso", "mlp", "live", "--max-epochs", "2"]
    assert run_cli([*argv, "--samples", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "leave one speaker out" in text
    for method in ("static pose", "mismatched real motion", "mlp (LOSO)", "live (LOSO)"):
        assert f"head  {method}" in text
        assert f"arms  {method}" in text
    assert (out / "distributions.png").stat().st_size > 1000
    assert "speech/silence" in (out / "metrics.txt").read_text()
