"""Runs of consecutive true frames in a per-frame mask (clips cut, poses mended, silences found)."""

from __future__ import annotations

import numpy as np


def true_runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of every run of consecutive true values of a 1-D mask, in order.

    ``stop`` is exclusive, as in slicing: ``flags[start:stop]`` is all true and the frames on
    either side (if any) are false.
    """
    padded = np.concatenate([[0], np.asarray(flags, dtype=bool).astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(padded))
    return [(int(start), int(stop)) for start, stop in zip(edges[::2], edges[1::2], strict=True)]
