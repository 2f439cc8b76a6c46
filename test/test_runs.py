"""true_runs: the stretches of a per-frame mask that importers cut or mend and metrics time."""

import numpy as np
import pytest

from audio2pose_ros.data.runs import true_runs


@pytest.mark.parametrize(
    ("flags", "runs"),
    [
        ([], []),
        ([False, False], []),
        ([True, True, True], [(0, 3)]),
        ([True, False, True, True, False], [(0, 1), (2, 4)]),
        ([False, True, True], [(1, 3)]),
        ([0, 2, 0, -1], [(1, 2), (3, 4)]),  # any non-zero value counts as true
    ],
)
def test_when_a_mask_has_runs_expect_each_as_a_slice(flags, runs):
    assert true_runs(np.asarray(flags)) == runs


def test_every_run_is_true_inside_and_false_at_its_edges():
    flags = np.random.default_rng(3).random(500) < 0.6
    runs = true_runs(flags)
    assert sum(stop - start for start, stop in runs) == flags.sum()
    for start, stop in runs:
        assert flags[start:stop].all()
        assert start == 0 or not flags[start - 1]
        assert stop == flags.size or not flags[stop]
