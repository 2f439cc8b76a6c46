"""Speech + motion data sets on disk: what importers write and training / evaluation read.

A data set is a folder::

    index.json            format version, joint names, motion rate, one entry per clip
    clips/<clip_id>.npz   audio (16 kHz mono float32), angles_rad (T, J) float32 at 100 Hz,
                          mask (T, J) bool: True where the angle was observed

Each index entry carries the clip's speaker, source, licence and split ('train', 'validation'
or 'test'), so a data set derived from third-party recordings keeps their attribution. Motion
frame i covers audio samples [160 i, 160 i + 400), the frame grid of
:mod:`audio2pose_ros.timebase` that the audio features use too (seed 003 section 4.2.2: 25 ms
windows every 10 ms), so feature frame i and pose frame i line up.

The files of a data set are untrusted input, read the same way whoever wrote them:

- every file must be a regular file of bounded size (:func:`open_bounded`): a FIFO or a link
  to a device is refused before it is opened;
- the index is checked whole when the data set is opened: its JSON nesting
  (:data:`MAX_INDEX_DEPTH`), its members and their types, each entry's fields, unique clip ids;
- a clip's arrays are checked from their ``.npy`` headers before any is read (dtype, and the
  shapes :func:`_check_clip_shapes` requires, at most :data:`MAX_CLIP_S` of audio), then the
  loaded clip goes through the same checks as a clip that is added (:func:`_check_clip`).

Every refusal is a :class:`DatasetError` naming the file and the problem in one line.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import IO

import numpy as np

from audio2pose_ros.checkpoints.format import json_depth
from audio2pose_ros.errors import InputError, short_repr
from audio2pose_ros.files import open_bounded
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import (
    FRAME_RATE_HZ,
    SAMPLE_RATE_HZ,
    SAMPLES_PER_FRAME,
    WINDOW_SAMPLES,
    complete_frames,
)

FORMAT_VERSION = 1
SPLITS = ("train", "validation", "test")
INDEX_FILE = "index.json"
FRAME_TOLERANCE = 3  # motion may be this many frames longer or shorter than the audio's grid
# An hour of audio is 230 MB of float32 (a clip is loaded whole); longer recordings are cut.
MAX_CLIP_S = 3600.0
MAX_CLIP_SAMPLES = int(MAX_CLIP_S * SAMPLE_RATE_HZ)
MAX_CLIP_FRAMES = complete_frames(MAX_CLIP_SAMPLES) + FRAME_TOLERANCE
MAX_INDEX_BYTES = 16 * 1024 * 1024  # about 80 000 clips; a data set of 1 000 clips has 200 KB
MAX_INDEX_DEPTH = 8  # JSON nesting of the index; the format needs 3 (object, clips, entry)
MAX_EXTRA_TRACKS = 4  # float64 per-frame arrays beside a clip (importers write 2 and a mask)
MAX_CLIP_ID_BYTES = 200  # clips/<id>.extras.npz must stay within a file name's 255 bytes
_NPZ_OVERHEAD_BYTES = 1 << 20  # zip and .npy headers, and deflate's worst case beyond the raw data
#: Size cap of a clip's extras file (:func:`check_extras_headers` bounds what it declares).
MAX_EXTRAS_FILE_BYTES = MAX_EXTRA_TRACKS * MAX_CLIP_FRAMES * 8 + _NPZ_OVERHEAD_BYTES
_NPZ_ERRORS = (OSError, ValueError, EOFError, NotImplementedError, zipfile.BadZipFile, zlib.error)
_CLIP_DTYPES = {"audio": np.dtype(np.float32), "angles_rad": np.dtype(np.float32),
                "mask": np.dtype(bool)}  # fmt: skip
_EXTRA_DTYPES = (np.dtype(np.float64), np.dtype(np.float32), np.dtype(bool))

#: Shape and dtype of one array of a ``.npz`` file, as its ``.npy`` header declares them.
ArrayHeader = tuple[tuple[int, ...], np.dtype]


class DatasetError(InputError):
    """A data set or clip is missing, malformed or made for other joints."""


@dataclass(frozen=True)
class ClipInfo:
    """Index entry of one clip."""

    clip_id: str
    speaker: str
    source: str
    licence: str
    split: str = "train"

    def __post_init__(self) -> None:
        """Reject fields that are not text, unknown splits and ids that are not file names."""
        if not isinstance(self.clip_id, str) or not _is_file_name(self.clip_id):
            raise DatasetError(f"clip id {short_repr(self.clip_id)} is not a valid file name")
        for name in ("speaker", "source", "licence", "split"):
            value = getattr(self, name)
            if not isinstance(value, str) or not _is_text(value):
                raise DatasetError(
                    f"clip {self.clip_id}: {name} must be a string, got {short_repr(value)}"
                )
        if self.split not in SPLITS:
            raise DatasetError(f"clip {self.clip_id}: split {self.split!r} not in {SPLITS}")


def _is_text(value: str) -> bool:
    """Whether ``value`` encodes as UTF-8 (JSON may carry lone surrogates, files cannot)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _is_file_name(clip_id: str) -> bool:
    """Whether ``clip_id`` can name the files ``clips/<clip_id>.npz`` and its extras."""
    return (
        bool(clip_id)
        and _is_text(clip_id)
        and "/" not in clip_id
        and not clip_id.startswith(".")
        and not any(ord(c) < 32 or c == "\x7f" for c in clip_id)
        and len(clip_id.encode("utf-8")) <= MAX_CLIP_ID_BYTES
    )


@dataclass
class Clip:
    """One clip in memory."""

    info: ClipInfo
    audio: np.ndarray  # (n_samples,) float32, 16 kHz mono, in [-1, 1]
    angles_rad: np.ndarray  # (T, J) at 100 Hz, in the robot's joint order
    mask: np.ndarray  # (T, J) bool

    @property
    def n_frames(self) -> int:
        """Number of motion frames."""
        return int(self.angles_rad.shape[0])


def _check_clip_shapes(
    clip_id: str,
    audio_shape: tuple[int, ...],
    angles_shape: tuple[int, ...],
    mask_shape: tuple[int, ...],
    mask_dtype: np.dtype,
    n_joints: int,
) -> None:
    """Check the shapes of a clip's arrays: what :func:`_check_clip` and reading a clip share.

    Audio is mono with at most :data:`MAX_CLIP_SAMPLES` samples and at least one complete frame;
    angles are (T, ``n_joints``) with T within :data:`FRAME_TOLERANCE` of the audio's frame
    grid; the mask is bool with the angles' shape.

    Raises:
        DatasetError: the first check that fails, naming the clip.
    """
    if len(angles_shape) != 2 or angles_shape[1] != n_joints:
        raise DatasetError(f"clip {clip_id}: angles shape {angles_shape}, expected (T, {n_joints})")
    if mask_shape != angles_shape or mask_dtype != np.dtype(bool):
        raise DatasetError(f"clip {clip_id}: mask must be bool with the angles' shape")
    if len(audio_shape) != 1:
        raise DatasetError(f"clip {clip_id}: audio must be mono (1-d), got shape {audio_shape}")
    n_samples = audio_shape[0]
    if n_samples > MAX_CLIP_SAMPLES:
        raise DatasetError(
            f"clip {clip_id}: audio holds {n_samples} samples, more than {MAX_CLIP_SAMPLES} "
            f"({MAX_CLIP_S:g} s at {SAMPLE_RATE_HZ} Hz)"
        )
    grid = complete_frames(n_samples)
    if grid == 0 or angles_shape[0] == 0:
        raise DatasetError(
            f"clip {clip_id}: no complete frame ({n_samples} samples, {angles_shape[0]} motion "
            "frames)"
        )
    if abs(angles_shape[0] - grid) > FRAME_TOLERANCE:
        raise DatasetError(
            f"clip {clip_id}: {angles_shape[0]} motion frames for audio of {grid} "
            f"frames ({n_samples} samples at 16 kHz)"
        )


def _check_clip(clip: Clip, n_joints: int) -> None:
    """Check a clip before it is stored and after it is read (the one gate of both ways).

    Its shapes (:func:`_check_clip_shapes`), finite audio and finite observed angles.

    Raises:
        DatasetError: the first check that fails, naming the clip.
    """
    cid = clip.info.clip_id
    _check_clip_shapes(
        cid, clip.audio.shape, clip.angles_rad.shape, clip.mask.shape, clip.mask.dtype, n_joints
    )
    if not np.isfinite(clip.audio).all():
        raise DatasetError(f"clip {cid}: audio contains NaN/inf")
    if not np.isfinite(clip.angles_rad[clip.mask]).all():
        raise DatasetError(f"clip {cid}: observed angles contain NaN/inf")


def read_arrays(
    path: Path,
    what: str,
    max_bytes: int,
    check: Callable[[Mapping[str, ArrayHeader]], None],
    rows: Mapping[str, int] | None = None,
) -> dict[str, np.ndarray]:
    """The arrays of a ``.npz`` file, after ``check`` has accepted their declared shapes.

    The file must be regular and at most ``max_bytes`` long (:func:`open_bounded`). Each
    member's ``.npy`` header is read without its data; ``check`` sees every array's shape and
    dtype before any array is allocated, so a header that claims more than the file holds, or
    than ``check`` allows, costs nothing. An array named in ``rows`` is read only as far as its
    first that many entries along its first axis (:func:`_read_rows`).

    Raises:
        DatasetError: the file is not a regular file, too large or not a ``.npz`` of plain
            arrays, or ``check`` refuses it.
    """
    with open_bounded(path, what, DatasetError, max_bytes) as file:
        try:
            with zipfile.ZipFile(file) as archive:
                members = {
                    info.filename.removesuffix(".npy"): info
                    for info in archive.infolist()
                    if info.filename.endswith(".npy")
                }
                headers = {name: _npy_header(archive, info) for name, info in members.items()}
                try:
                    check(headers)
                except DatasetError as exc:
                    raise DatasetError(f"{path}: {exc}") from None
                arrays = {}
                for name, info in members.items():
                    with archive.open(info) as member:
                        if rows is not None and name in rows:
                            arrays[name] = _read_rows(member, info.filename, rows[name])
                        else:
                            arrays[name] = np.lib.format.read_array(member, allow_pickle=False)
        except _NPZ_ERRORS as exc:
            raise DatasetError(f"{path}: unreadable {what} ({exc})") from None
    return arrays


def _npy_stream_header(stream: IO[bytes], name: str) -> tuple[tuple[int, ...], bool, np.dtype]:
    """Shape, Fortran order and dtype of the ``.npy`` stream ``name``; its data comes next.

    Raises:
        ValueError: another ``.npy`` version than 1.0 or 2.0.
    """
    version = np.lib.format.read_magic(stream)
    if version == (1, 0):
        shape, fortran_order, dtype = np.lib.format.read_array_header_1_0(stream)
    elif version == (2, 0):
        shape, fortran_order, dtype = np.lib.format.read_array_header_2_0(stream)
    else:
        raise ValueError(f"{name}: .npy format {version} is not supported")
    return tuple(shape), bool(fortran_order), dtype


def _read_rows(member: IO[bytes], name: str, rows: int) -> np.ndarray:
    """The first ``rows`` entries (along the first axis) of the C-ordered ``.npy`` stream ``name``.

    Raises:
        ValueError: another ``.npy`` version, a Fortran-ordered or object array, or a stream
            that ends early.
    """
    shape, fortran_order, dtype = _npy_stream_header(member, name)
    if fortran_order or dtype.hasobject or not shape:
        raise ValueError(f"{name}: only C-ordered arrays of plain values are read in part")
    out = np.empty((min(rows, shape[0]), *shape[1:]), dtype=dtype)
    view, filled = out.data.cast("B"), 0
    while filled < view.nbytes:
        chunk = member.read(min(view.nbytes - filled, 1 << 20))
        if not chunk:
            raise ValueError(f"{name}: the data ends after {filled} of {view.nbytes} bytes")
        view[filled : filled + len(chunk)] = chunk
        filled += len(chunk)
    view.release()
    return out


def _npy_header(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> ArrayHeader:
    """Shape and dtype declared by one ``.npy`` member (its data is not read)."""
    with archive.open(info) as stream:
        shape, _, dtype = _npy_stream_header(stream, info.filename)
    return shape, dtype


def _check_clip_headers(clip_id: str, n_joints: int) -> Callable[[Mapping[str, ArrayHeader]], None]:
    """The check of :func:`read_arrays` for a clip's file: its arrays, dtypes and shapes."""

    def check(headers: Mapping[str, ArrayHeader]) -> None:
        for name, dtype in _CLIP_DTYPES.items():
            if name not in headers:
                raise DatasetError(f"clip {clip_id}: no {name} array")
            if headers[name][1] != dtype:
                raise DatasetError(
                    f"clip {clip_id}: {name} is {headers[name][1]}, expected {dtype}"
                )
        unknown = sorted(set(headers) - set(_CLIP_DTYPES))
        if unknown:
            raise DatasetError(f"clip {clip_id}: unknown arrays {short_repr(unknown)}")
        _check_clip_shapes(
            clip_id,
            headers["audio"][0],
            headers["angles_rad"][0],
            headers["mask"][0],
            headers["mask"][1],
            n_joints,
        )

    return check


def check_extras_headers(headers: Mapping[str, ArrayHeader]) -> None:
    """Per-frame extras (:mod:`~audio2pose_ros.data.importers.extras`): 1-d float or bool arrays.

    At most :data:`MAX_EXTRA_TRACKS` float64 tracks' worth of a clip's longest frame count.

    Raises:
        DatasetError: an array of another rank or dtype, longer than a clip may be, or more
            data than that in all.
    """
    total = 0
    for name, (shape, dtype) in headers.items():
        if len(shape) != 1 or shape[0] > MAX_CLIP_FRAMES or dtype not in _EXTRA_DTYPES:
            raise DatasetError(
                f"{name} is {dtype} of shape {shape}, expected a float or bool array of at most "
                f"{MAX_CLIP_FRAMES} frames"
            )
        total += shape[0] * dtype.itemsize
    if total > MAX_EXTRA_TRACKS * MAX_CLIP_FRAMES * 8:
        raise DatasetError(f"{len(headers)} arrays of {total} bytes, more than extras may hold")


def _clip_file_bytes(n_joints: int) -> int:
    """Size cap of a clip's file: the raw size of the largest arrays a clip may have."""
    audio, angles, mask = 4 * MAX_CLIP_SAMPLES, 4 * MAX_CLIP_FRAMES * n_joints, MAX_CLIP_FRAMES
    return audio + angles + mask * n_joints + _NPZ_OVERHEAD_BYTES


class Dataset:
    """A data set folder; create it with :meth:`create`, open it with :meth:`open`."""

    def __init__(self, root: Path, joint_names: tuple[str, ...], clips: list[ClipInfo]) -> None:
        """Use :meth:`create` or :meth:`open`."""
        self.root = root
        self.joint_names = joint_names
        self.clips = clips

    @classmethod
    def create(cls, root: str | Path, robot: RobotDescription) -> Dataset:
        """Start an empty data set in ``root`` (created if needed; must not hold one yet).

        Raises:
            DatasetError: ``root`` holds a data set already, or cannot be created or written.
        """
        path = Path(root)
        if (path / INDEX_FILE).exists():
            raise DatasetError(f"{path} already holds a data set ({INDEX_FILE})")
        try:
            (path / "clips").mkdir(parents=True, exist_ok=True)
            dataset = cls(path, robot.names, [])
            dataset._write_index()
        except OSError as exc:
            raise DatasetError(
                f"{path}: cannot create a data set there ({exc.strerror or exc})"
            ) from None
        return dataset

    @classmethod
    def open(cls, root: str | Path, robot: RobotDescription | None = None) -> Dataset:
        """Open a data set after checking its whole index (see the module docstring).

        With ``robot``, its joints must be the robot's, in order.

        Raises:
            DatasetError: no index, an index that is not a regular file, too large or
                malformed, another format version, or other joints than ``robot``'s.
        """
        path = Path(root)
        file = path / INDEX_FILE
        if not (file.exists() or file.is_symlink()):
            raise DatasetError(f"{path}: no {INDEX_FILE}; not a data set folder")
        try:
            with open_bounded(file, "data set index", DatasetError, MAX_INDEX_BYTES) as stream:
                raw = stream.read()
        except OSError as exc:
            raise DatasetError(f"{file}: cannot read ({exc.strerror or exc})") from None
        try:
            index = _index_object(raw)
        except DatasetError as exc:
            raise DatasetError(f"{file}: malformed index ({exc})") from None
        version = index["format_version"]
        if type(version) is not int or version != FORMAT_VERSION:
            raise DatasetError(
                f"{path}: data set format {short_repr(version)}, expected {FORMAT_VERSION}"
            )
        try:
            names, clips = _index_entries(index)
        except DatasetError as exc:
            raise DatasetError(f"{file}: malformed index ({exc})") from None
        if robot is not None and names != robot.names:
            raise DatasetError(
                f"{path}: joints {list(names)} differ from the robot's {list(robot.names)}"
            )
        return cls(path, names, clips)

    def _write_index(self) -> None:
        index = {
            "format_version": FORMAT_VERSION,
            "joint_names": list(self.joint_names),
            "motion_rate_hz": FRAME_RATE_HZ,
            "audio_rate_hz": SAMPLE_RATE_HZ,
            "clips": [asdict(c) for c in self.clips],
        }
        tmp = self.root / (INDEX_FILE + ".tmp")
        tmp.write_text(json.dumps(index, indent=1), encoding="utf-8")
        tmp.replace(self.root / INDEX_FILE)

    def add(self, clip: Clip, robot: RobotDescription, replace: bool = False) -> None:
        """Validate (:func:`_check_clip`) and store ``clip``.

        Args:
            clip: the clip; its id names its file.
            robot: must have the data set's joints.
            replace: a clip with the same id may be replaced (without it, it is refused).

        Raises:
            DatasetError: other joints, a clip that fails :func:`_check_clip`, or an id already
                in the data set and ``replace`` not given.
        """
        if robot.names != self.joint_names:
            raise DatasetError(f"{self.root}: robot joints differ from the data set's")
        _check_clip(clip, robot.n_joints)
        cid = clip.info.clip_id
        if not replace and any(c.clip_id == cid for c in self.clips):
            raise DatasetError(f"{self.root}: clip id {cid!r} is in the data set already")
        np.savez_compressed(
            self.root / "clips" / f"{cid}.npz",
            audio=clip.audio.astype(np.float32),
            angles_rad=clip.angles_rad.astype(np.float32),
            mask=clip.mask,
        )
        self.clips = [c for c in self.clips if c.clip_id != cid] + [clip.info]
        self._write_index()

    def load(self, clip_id: str, max_frames: int | None = None) -> Clip:
        """Read one clip from disk, checked as :meth:`add` checks it (see the module docstring).

        With ``max_frames``, only the clip's first that many motion frames and their audio
        (frame ``i``'s window ends at sample ``160 i + 400``) are read from the file.

        Raises:
            DatasetError: no such clip, or its file is not a regular file, too large,
                unreadable, or holds arrays that :func:`_check_clip` refuses.
        """
        info = next((c for c in self.clips if c.clip_id == clip_id), None)
        if info is None:
            raise DatasetError(f"{self.root}: no clip {clip_id!r}")
        path = self.root / "clips" / f"{clip_id}.npz"
        n_joints = len(self.joint_names)
        rows = None
        if max_frames is not None:
            samples = SAMPLES_PER_FRAME * (max(max_frames, 1) - 1) + WINDOW_SAMPLES
            rows = {"audio": samples, "angles_rad": max_frames, "mask": max_frames}
        arrays = read_arrays(
            path, "clip", _clip_file_bytes(n_joints), _check_clip_headers(clip_id, n_joints), rows
        )
        clip = Clip(info, arrays["audio"], arrays["angles_rad"].astype(np.float64), arrays["mask"])
        try:
            _check_clip(clip, n_joints)
        except DatasetError as exc:
            raise DatasetError(f"{path}: {exc}") from None
        return clip

    def iter_split(self, split: str) -> Iterator[Clip]:
        """Clips of one split, in index order."""
        if split not in SPLITS:
            raise DatasetError(f"split {split!r} not in {SPLITS}")
        for info in self.clips:
            if info.split == split:
                yield self.load(info.clip_id)

    @property
    def speakers(self) -> list[str]:
        """Distinct speakers, sorted."""
        return sorted({c.speaker for c in self.clips})


_INDEX_RATES = {"motion_rate_hz": FRAME_RATE_HZ, "audio_rate_hz": SAMPLE_RATE_HZ}
_CLIP_FIELDS = tuple(f.name for f in fields(ClipInfo))
_REQUIRED_CLIP_FIELDS = ("clip_id", "speaker", "source", "licence")


def _index_object(raw: bytes) -> dict[str, object]:
    """The index's JSON object (with its required members), its nesting checked first.

    Raises:
        DatasetError: the reason, without the file (the caller names it).
    """
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"not UTF-8: {exc}") from None
    depth = json_depth(text)
    if depth > MAX_INDEX_DEPTH:
        raise DatasetError(f"nests {depth} levels deep, at most {MAX_INDEX_DEPTH} are allowed")
    try:
        index = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DatasetError(str(exc)) from None
    if not isinstance(index, dict):
        raise DatasetError(f"expected an object, got {type(index).__name__}")
    missing = [key for key in ("format_version", "joint_names", "clips") if key not in index]
    if missing:
        raise DatasetError(f"no {', '.join(missing)}")
    return index


def _index_entries(index: Mapping[str, object]) -> tuple[tuple[str, ...], list[ClipInfo]]:
    """Joint names and clip entries of an index object, after checking its members.

    Raises:
        DatasetError: the reason, without the file (the caller names it).
    """
    for key, rate in _INDEX_RATES.items():
        value = index.get(key, rate)
        if type(value) not in (int, float) or value != rate:
            raise DatasetError(f"{key} {short_repr(value)}, expected {rate:g}")
    names = index["joint_names"]
    if (
        not isinstance(names, list)
        or not names
        or not all(isinstance(name, str) and name for name in names)
        or len(set(names)) != len(names)
    ):
        raise DatasetError(f"joint_names {short_repr(names)} is not a list of distinct names")
    entries = index["clips"]
    if not isinstance(entries, list):
        raise DatasetError(f"clips must be a list, got {type(entries).__name__}")
    clips: list[ClipInfo] = []
    first: dict[str, int] = {}
    for k, entry in enumerate(entries):
        clips.append(_clip_info(entry, k))
        cid = clips[-1].clip_id
        if cid in first:
            raise DatasetError(f"clips[{k}]: clip id {cid!r} is also that of clips[{first[cid]}]")
        first[cid] = k
    return tuple(names), clips


def _clip_info(entry: object, k: int) -> ClipInfo:
    """Index entry ``clips[k]`` as a :class:`ClipInfo` (its members and their types checked)."""
    if not isinstance(entry, dict):
        raise DatasetError(f"clips[{k}] must be an object, got {type(entry).__name__}")
    problems = []
    missing = [name for name in _REQUIRED_CLIP_FIELDS if name not in entry]
    if missing:
        problems.append(f"no {', '.join(missing)}")
    unknown = sorted(str(name) for name in entry if name not in _CLIP_FIELDS)
    if unknown:
        problems.append(f"unknown members {short_repr(unknown)}")
    if problems:
        raise DatasetError(f"clips[{k}]: {'; '.join(problems)}")
    try:
        return ClipInfo(**entry)
    except DatasetError as exc:
        raise DatasetError(f"clips[{k}]: {exc}") from None
