"""Per-clip arrays that drive no joint (head roll), kept beside a data set's clips.

The data set format (:mod:`audio2pose_ros.data.dataset`) stores the robot's joints only. Importers
that measure more keep it in ``clips/<clip_id>.extras.npz`` next to ``clips/<clip_id>.npz``, on
the same 100 Hz grid: the video and OpenFace importers store ``head_roll_rad`` (T,) (positive:
the top of the head tilts to the speaker's right; mirrored with ``--mirror``) and
``head_roll_mask`` (T,) bool. Pepper has no head-roll joint, so training and the robot ignore
roll; it is kept for analysis and for robots that have such a joint. Every importer also stores
``body_moved_rad`` (T,): how far each frame's arms were moved clear of the robot's body
(:mod:`.body_clearance`), so a changed target can be told from a measured one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from audio2pose_ros.data.dataset import (
    MAX_EXTRAS_FILE_BYTES,
    Dataset,
    DatasetError,
    check_extras_headers,
    read_arrays,
)

EXTRAS_SUFFIX = ".extras.npz"


def extras_path(dataset: Dataset, clip_id: str) -> Path:
    """Where the extras of ``clip_id`` live."""
    return dataset.root / "clips" / f"{clip_id}{EXTRAS_SUFFIX}"


def save_extras(dataset: Dataset, clip_id: str, arrays: dict[str, np.ndarray]) -> Path:
    """Write (replace) the extras of a clip already in ``dataset``."""
    if clip_id not in {c.clip_id for c in dataset.clips}:
        raise DatasetError(f"{dataset.root}: no clip {clip_id!r} to attach extras to")
    path = extras_path(dataset, clip_id)
    np.savez_compressed(path, allow_pickle=False, **arrays)
    return path


def load_extras(dataset: Dataset, clip_id: str) -> dict[str, np.ndarray]:
    """The extras of a clip; empty when it has none.

    Read as a clip is (:func:`~audio2pose_ros.data.dataset.read_arrays`): a regular file of
    bounded size whose arrays are 1-d float or bool tracks of at most a clip's length.

    Raises:
        DatasetError: the file exists but is not a regular file, is too large or unreadable, or
            holds other arrays.
    """
    path = extras_path(dataset, clip_id)
    if not (path.exists() or path.is_symlink()):
        return {}
    return read_arrays(path, "clip extras", MAX_EXTRAS_FILE_BYTES, check_extras_headers)
