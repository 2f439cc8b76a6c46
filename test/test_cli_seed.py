"""`audio2pose synth --seed N`: the same seed gives the same motion, another seed other motion."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.cli.main import main


def test_when_synth_runs_with_seeds_expect_same_seed_same_motion_other_seed_other_motion(
    tmp_path, speech_files
):
    wav = str(speech_files[1])
    runs = {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        out = tmp_path / f"{name}.csv"
        assert main(["synth", wav, "-o", str(out), "--seed", str(seed), "--no-smooth"]) == 0
        runs[name] = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1:]
    np.testing.assert_array_equal(runs["a"], runs["b"])
    assert np.abs(runs["a"] - runs["c"]).max() > 0.01  # visibly different, same audio


@pytest.mark.parametrize("family", ["mlp", "lstm"])
def test_when_a_deterministic_model_gets_a_seed_expect_it_accepted_and_unused(robot, family):
    """inference_node passes its seed to every streaming model (a TypeError crash-looped it)."""
    from audio2pose_ros.audio.features import FeatureSpec
    from audio2pose_ros.audio.normalize import FeatureNormalizer
    from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
    from audio2pose_ros.checkpoints.torch_io import Checkpoint, save_checkpoint
    from audio2pose_ros.models.registry import build_model

    spec = FeatureSpec()
    model = build_model(family, {"n_features": spec.dim, "n_joints": robot.n_joints})
    normalizer = FeatureNormalizer.fit(np.random.default_rng(0).normal(size=(50, spec.dim)))
    frames = np.random.default_rng(1).normal(size=(5, spec.dim))
    with tempfile.TemporaryDirectory() as tmp:
        path = save_checkpoint(
            Path(tmp) / "m.safetensors", Checkpoint(model, spec, normalizer, robot)
        )
        loaded = load_streaming_model(path, robot=robot)
    a = loaded.predictor(seed=1).run(frames)
    b = loaded.predictor(seed=2).run(frames)
    np.testing.assert_array_equal(a, b)
