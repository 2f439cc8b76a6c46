"""The checkpoint file format, readable without torch.

A checkpoint is a safetensors file whose string metadata holds a JSON header (format version,
model name and config, feature specification, normalisation, robot, training info) and a SHA-256
digest. Light processes such as ``audio_features_node`` read the header here to learn which
features the model expects; :mod:`audio2pose_ros.models.checkpoint` loads the tensors.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from audio2pose_ros.audio.features import FeatureSpec

FORMAT_VERSION = 1
HEADER_KEY = "audio2pose"
DIGEST_KEY = "audio2pose_sha256"
_MAX_HEADER_BYTES = 100_000_000


class CheckpointError(ValueError):
    """A checkpoint cannot be used: unreadable, modified, or made for another robot or features."""


def read_metadata(path: str | Path) -> tuple[dict[str, Any], str, str]:
    """Read a checkpoint's header without loading its tensors.

    Returns:
        ``(header, header_text, digest)``: the parsed header, its exact JSON text and the stored
        SHA-256 digest.

    Raises:
        CheckpointError: the file is missing, is not safetensors, has no audio2pose header or
            has another format version.

    """
    file = Path(path)
    if not file.is_file():
        raise CheckpointError(f"{file}: checkpoint file not found")
    try:
        with file.open("rb") as stream:
            size = int.from_bytes(stream.read(8), "little")
            if not 0 < size < _MAX_HEADER_BYTES:
                raise ValueError(f"implausible header size {size}")
            metadata = json.loads(stream.read(size)).get("__metadata__") or {}
        header_text, digest = metadata[HEADER_KEY], metadata[DIGEST_KEY]
        header = json.loads(header_text)
    except (OSError, ValueError, KeyError, AttributeError) as exc:
        raise CheckpointError(f"{file}: not an audio2pose checkpoint ({exc!r})") from None
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{file}: checkpoint format {version}, this package reads format {FORMAT_VERSION}"
        )
    return header, header_text, digest


def feature_spec_of(path: str | Path) -> FeatureSpec:
    """The feature specification a checkpoint was trained with."""
    header, _, _ = read_metadata(path)
    try:
        return FeatureSpec.from_dict(header["features"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: bad feature specification ({exc})") from None
