"""The checkpoint file format, read and verified without torch.

A checkpoint is a safetensors file (an 8-byte little-endian header length, a JSON header, then
the tensor bytes) whose string metadata holds a JSON header (format version, model name and
config, feature specification, normalisation, robot, training info) and a SHA-256 digest over
that header and every tensor. Light processes such as ``audio_features_node`` read the header
here to learn which features the model expects; :mod:`audio2pose_ros.checkpoints.torch_io` loads
the tensors.

Files are untrusted input. Before anything is parsed:

- the header length is read and capped (:data:`MAX_HEADER_BYTES`, and never beyond the file);
- the JSON nesting depth is capped (:data:`MAX_JSON_DEPTH`) before ``json.loads`` runs, so a
  deeply nested header cannot exhaust the recursion limit;
- every tensor entry must have the safetensors structure, dtype F32 (the only dtype this package
  writes; anything else is refused, never cast), a shape of non-negative integers and byte
  offsets inside the file that match its shape;
- the audio2pose header must be an object with the expected members and types.

:func:`verify_digest` then streams the tensor bytes through SHA-256, so a header or tensor
edited after saving is refused wherever a checkpoint is used, :func:`feature_spec_of` included.
The tensor reader (``safetensors``, 0.8 MB resident) is only imported with the tensors
(:func:`load_checked_tensors`): ``audio_features_node`` only needs the features a model expects.
Every refusal is a :class:`CheckpointError` naming the file and the problem in one line.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.errors import Audio2PoseError, ConfigurationError
from audio2pose_ros.robot.description import RobotDescription

__all__ = [
    "DIGEST_KEY",
    "FORMAT_VERSION",
    "HEADER_KEY",
    "MAX_HEADER_BYTES",
    "MAX_JSON_DEPTH",
    "CheckpointError",
    "CheckpointFile",
    "TensorEntry",
    "feature_spec_of",
    "read_checkpoint_file",
    "verify_digest",
]

FORMAT_VERSION = 1
HEADER_KEY = "audio2pose"
DIGEST_KEY = "audio2pose_sha256"
MAX_HEADER_BYTES = 16 * 1024 * 1024  # safetensors JSON header; the packaged model's is 6 KB
MAX_JSON_DEPTH = 32  # nesting of objects/arrays; the format itself needs 5
TENSOR_DTYPE = "F32"  # the only dtype save_checkpoint writes
TENSOR_ITEMSIZE = 4
_HEADER_SECTIONS = {"model": dict, "features": dict, "normalizer": dict, "robot": dict}
_STRINGS = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_READ_CHUNK_BYTES = 1 << 20
T = TypeVar("T")
TensorT = TypeVar("TensorT")  # a numpy array or a torch tensor, as the caller's reader gives


class CheckpointError(ConfigurationError):
    """A checkpoint cannot be used: unreadable, modified, or made for another robot or features.

    It is a :class:`~audio2pose_ros.errors.ConfigurationError`: a node whose ``model_path``
    names such a file stops at start-up and is not restarted.
    """


@dataclass(frozen=True)
class TensorEntry:
    """Where one tensor's bytes lie in the file (offsets relative to the data section)."""

    name: str
    shape: tuple[int, ...]
    begin: int
    end: int


@dataclass(frozen=True)
class CheckpointFile:
    """A checkpoint whose container and header passed the structural checks.

    Attributes:
        path: the file.
        header: the parsed audio2pose header (an object with the expected sections).
        header_text: its exact JSON text, as covered by the digest.
        digest: the stored SHA-256 digest (64 lowercase hex digits).
        tensors: the tensor entries by name.
        data_offset: file offset of the tensor data section.
    """

    path: Path
    header: dict[str, Any]
    header_text: str
    digest: str
    tensors: dict[str, TensorEntry]
    data_offset: int


def json_depth(text: str) -> int:
    """Deepest nesting of objects and arrays in JSON ``text``, without parsing it.

    String literals are removed first, so brackets inside strings do not count. Runs in linear
    time and constant stack, unlike ``json.loads`` whose recursion a deep document exhausts.
    """
    structure = np.frombuffer(_STRINGS.sub("", text).encode("utf-8"), dtype=np.uint8)
    steps = np.zeros(structure.shape, dtype=np.int64)
    steps[(structure == ord("[")) | (structure == ord("{"))] = 1
    steps[(structure == ord("]")) | (structure == ord("}"))] = -1
    return int(np.cumsum(steps).max(initial=0))


def _parse_json(text: str, what: str, file: Path) -> object:
    depth = json_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise CheckpointError(
            f"{file}: {what} nests {depth} levels deep, at most {MAX_JSON_DEPTH} are allowed"
        )
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{file}: {what} is not valid JSON ({exc})") from None


def _tensor_entry(name: str, entry: object, data_bytes: int, file: Path) -> TensorEntry:
    """Check one safetensors header entry against the format and the file's size."""
    if not isinstance(entry, Mapping) or set(entry) != {"dtype", "shape", "data_offsets"}:
        raise CheckpointError(
            f"{file}: tensor {name!r} entry must be an object with dtype, shape and data_offsets"
        )
    dtype, shape, offsets = entry["dtype"], entry["shape"], entry["data_offsets"]
    if dtype != TENSOR_DTYPE:
        raise CheckpointError(
            f"{file}: tensor {name!r} has dtype {dtype!r}; checkpoints hold {TENSOR_DTYPE} "
            "(float32) tensors only"
        )
    if not isinstance(shape, list) or not all(
        isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape
    ):
        raise CheckpointError(
            f"{file}: tensor {name!r} shape {shape!r} is not a list of sizes >= 0"
        )
    if (
        not isinstance(offsets, list)
        or len(offsets) != 2
        or not all(isinstance(n, int) and not isinstance(n, bool) for n in offsets)
        or not 0 <= offsets[0] <= offsets[1] <= data_bytes
    ):
        raise CheckpointError(
            f"{file}: tensor {name!r} data_offsets {offsets!r} do not lie inside the "
            f"{data_bytes} data bytes"
        )
    if offsets[1] - offsets[0] != math.prod(shape) * TENSOR_ITEMSIZE:
        raise CheckpointError(
            f"{file}: tensor {name!r} holds {offsets[1] - offsets[0]} bytes, its shape "
            f"{shape} needs {math.prod(shape) * TENSOR_ITEMSIZE}"
        )
    return TensorEntry(name, tuple(shape), offsets[0], offsets[1])


def _audio2pose_header(metadata: object, file: Path) -> tuple[dict[str, Any], str, str]:
    """The audio2pose header, its text and the digest from the safetensors metadata."""
    if not isinstance(metadata, Mapping) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in metadata.items()
    ):
        raise CheckpointError(f"{file}: not an audio2pose checkpoint (no string __metadata__)")
    if HEADER_KEY not in metadata or DIGEST_KEY not in metadata:
        raise CheckpointError(
            f"{file}: not an audio2pose checkpoint (metadata lacks {HEADER_KEY!r} or "
            f"{DIGEST_KEY!r})"
        )
    header_text, digest = metadata[HEADER_KEY], metadata[DIGEST_KEY]
    if not re.fullmatch(r"[0-9a-f]{64}", digest):
        raise CheckpointError(f"{file}: {DIGEST_KEY} is not a SHA-256 hex digest")
    header = _parse_json(header_text, f"{HEADER_KEY} header", file)
    if not isinstance(header, dict):
        raise CheckpointError(f"{file}: {HEADER_KEY} header must be a JSON object")
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{file}: checkpoint format {version!r}, this package reads format {FORMAT_VERSION}"
        )
    for section, kind in _HEADER_SECTIONS.items():
        if not isinstance(header.get(section), kind):
            raise CheckpointError(f"{file}: header section {section!r} must be a JSON object")
    model = header["model"]
    if not isinstance(model.get("name"), str) or not isinstance(model.get("config"), dict):
        raise CheckpointError(f"{file}: header 'model' needs a string name and a config object")
    if not isinstance(header.get("info", {}), dict):
        raise CheckpointError(f"{file}: header section 'info' must be a JSON object")
    return header, header_text, digest


def check_tensor_layout(
    file: CheckpointFile, model: str, shapes: Mapping[str, tuple[int, ...]]
) -> None:
    """Refuse a file whose tensor entries are not exactly ``shapes`` (names and shapes).

    Raises:
        CheckpointError: a tensor is missing, unexpected, or of another shape than the model's.
    """
    missing = sorted(set(shapes) - set(file.tensors))
    unexpected = sorted(set(file.tensors) - set(shapes))
    if missing or unexpected:
        raise CheckpointError(
            f"{file.path}: tensors do not fit model {model!r}: missing {missing[:5]}, "
            f"unexpected {unexpected[:5]}"
        )
    for name, shape in shapes.items():
        if file.tensors[name].shape != shape:
            raise CheckpointError(
                f"{file.path}: tensor {name!r} has shape {list(file.tensors[name].shape)}, "
                f"model {model!r} needs {list(shape)} (torch.float32)"
            )


def load_checked_tensors(
    file: CheckpointFile,
    load: Callable[[str], dict[str, TensorT]],
    finite_float32: Callable[[TensorT], bool],
) -> dict[str, TensorT]:
    """Read the tensors of a checked file with ``load`` (safetensors' numpy or torch reader).

    Raises:
        CheckpointError: the tensors cannot be read, or one is not finite float32.
    """
    from safetensors import SafetensorError  # the reader's own library, loaded with it

    try:
        tensors = load(str(file.path))
    except (SafetensorError, OSError) as exc:
        raise CheckpointError(f"{file.path}: unreadable tensors ({exc})") from None
    for name, tensor in tensors.items():
        if not finite_float32(tensor):
            raise CheckpointError(f"{file.path}: tensor {name!r} is not finite float32")
    return tensors


def read_checkpoint_file(path: str | Path) -> CheckpointFile:
    """Read and structurally check a checkpoint's headers without reading its tensors.

    Memory use is bounded by :data:`MAX_HEADER_BYTES` whatever the file claims.

    Raises:
        CheckpointError: the file is missing or unreadable, is not safetensors, has no valid
            audio2pose header, another format version, or a tensor that is not float32 or does
            not fit the file.
    """
    file = Path(path)
    try:
        if not stat.S_ISREG(file.stat().st_mode) and not file.is_dir():
            raise CheckpointError(f"{file}: not a regular file, expected a checkpoint")
        with file.open("rb") as stream:
            file_bytes = file.stat().st_size
            size = int.from_bytes(stream.read(8), "little")
            if file_bytes < 8 or not 2 <= size <= min(MAX_HEADER_BYTES, file_bytes - 8):
                raise CheckpointError(
                    f"{file}: not an audio2pose checkpoint (header length {size} for a file of "
                    f"{file_bytes} bytes; at most {MAX_HEADER_BYTES} allowed)"
                )
            raw = stream.read(size)
    except FileNotFoundError:
        raise CheckpointError(f"{file}: checkpoint file not found") from None
    except IsADirectoryError:
        raise CheckpointError(f"{file}: is a directory, not a checkpoint file") from None
    except OSError as exc:
        raise CheckpointError(f"{file}: cannot read ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise CheckpointError(
            f"{file}: not an audio2pose checkpoint (header is not UTF-8)"
        ) from None
    container = _parse_json(text, "safetensors header", file)
    if not isinstance(container, dict):
        raise CheckpointError(f"{file}: not an audio2pose checkpoint (header is not an object)")
    data_bytes = file_bytes - 8 - size
    header, header_text, digest = _audio2pose_header(container.pop("__metadata__", None), file)
    tensors = {
        name: _tensor_entry(name, entry, data_bytes, file) for name, entry in container.items()
    }
    return CheckpointFile(file, header, header_text, digest, tensors, 8 + size)


def digest_update(sha: hashlib._Hash, name: str, shape: tuple[int, ...], data: bytes) -> None:
    """Add one tensor to a checkpoint digest: its name, its shape as ``str(tuple)``, its bytes.

    :func:`verify_digest` (from the file) and ``save_checkpoint`` (from torch tensors) both
    build the digest with this, tensors in sorted name order after the header text.
    """
    sha.update(name.encode("utf-8"))
    sha.update(str(tuple(shape)).encode("ascii"))
    sha.update(data)


def verify_digest(checkpoint: CheckpointFile) -> None:
    """Recompute the SHA-256 digest over header text and tensor bytes; refuse a mismatch.

    Tensor bytes are streamed in 1 MiB pieces, so memory stays bounded for any file size.

    Raises:
        CheckpointError: the digest differs (the file was modified after saving) or the file
            cannot be read.
    """
    sha = hashlib.sha256(checkpoint.header_text.encode("utf-8"))
    try:
        with checkpoint.path.open("rb") as stream:
            for name in sorted(checkpoint.tensors):
                entry = checkpoint.tensors[name]
                stream.seek(checkpoint.data_offset + entry.begin)
                digest_update(sha, name, entry.shape, b"")
                remaining = entry.end - entry.begin
                while remaining:
                    piece = stream.read(min(remaining, _READ_CHUNK_BYTES))
                    if not piece:
                        raise CheckpointError(f"{checkpoint.path}: file ends inside {name!r}")
                    sha.update(piece)
                    remaining -= len(piece)
    except OSError as exc:
        raise CheckpointError(f"{checkpoint.path}: cannot read ({exc.strerror or exc})") from None
    if sha.hexdigest() != checkpoint.digest:
        raise CheckpointError(
            f"{checkpoint.path}: checksum mismatch, the file was modified after it was saved; "
            "retrain or restore the original file"
        )


def feature_spec_of(path: str | Path) -> FeatureSpec:
    """The feature specification of a verified checkpoint (structure and digest checked).

    Raises:
        CheckpointError: the file is not a valid, unmodified checkpoint, or its feature
            specification is unusable.
    """
    checkpoint = read_checkpoint_file(path)
    verify_digest(checkpoint)
    return parse_section(checkpoint, "features", FeatureSpec.from_dict)


def parse_section(
    checkpoint: CheckpointFile, section: str, parse: Callable[[dict[str, Any]], T]
) -> T:
    """``parse(header[section])``, with the parser's refusal reported as a CheckpointError.

    The section parsers (``FeatureSpec.from_dict``, ``build_model`` and the like) raise an
    :class:`~audio2pose_ros.errors.Audio2PoseError` for a bad value; torch's modules raise
    ValueError for arguments they refuse (a dropout above 1, a zero-sized recurrent layer), and
    a value of an unexpected JSON type can raise TypeError inside a constructor. For a
    checkpoint these all mean "bad file".
    """
    try:
        return parse(checkpoint.header[section])
    except (Audio2PoseError, ValueError, TypeError) as exc:
        raise CheckpointError(f"{checkpoint.path}: bad {section} section ({exc})") from None


def header_sections(
    checkpoint: CheckpointFile,
) -> tuple[RobotDescription, FeatureSpec, FeatureNormalizer]:
    """The robot, feature and normalizer sections, parsed and checked against each other.

    Raises:
        CheckpointError: a section is malformed, or the normalizer does not fit the features.
    """
    stored_robot = parse_section(
        checkpoint,
        "robot",
        lambda data: RobotDescription.from_dict(data, source=f"{checkpoint.path} robot"),
    )
    stored_features = parse_section(checkpoint, "features", FeatureSpec.from_dict)
    normalizer = parse_section(checkpoint, "normalizer", FeatureNormalizer.from_dict)
    if normalizer.mean.shape != (stored_features.dim,):
        raise CheckpointError(
            f"{checkpoint.path}: normalizer has {normalizer.mean.size} means and deviations, "
            f"the features have {stored_features.dim} dimensions"
        )
    return stored_robot, stored_features, normalizer


def check_made_for(
    checkpoint: CheckpointFile,
    stored_robot: RobotDescription,
    stored_features: FeatureSpec,
    robot: RobotDescription | None,
    features: FeatureSpec | None,
) -> None:
    """Refuse a checkpoint made for other joints than ``robot`` or other features than ``features``.

    ``None`` skips that comparison. Used by both loaders (torch and the numpy runtime).

    Raises:
        CheckpointError: the message lists what differs.
    """
    if robot is not None:
        differences = robot.differences(stored_robot)
        if differences:
            raise CheckpointError(
                f"{checkpoint.path}: made for other joints than the configured robot: "
                + "; ".join(differences)
            )
    if features is not None and stored_features != features:
        configured = features.to_dict()
        changed = [
            f"{key}={value!r} (configured {configured[key]!r})"
            for key, value in stored_features.to_dict().items()
            if configured.get(key) != value
        ]
        raise CheckpointError(
            f"{checkpoint.path}: made for other audio features: " + ", ".join(changed)
        )
