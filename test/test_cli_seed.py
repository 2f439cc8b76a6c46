"""`audio2pose synth --seed N`: the same seed gives the same motion, another seed other motion."""

from __future__ import annotations

import numpy as np

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
