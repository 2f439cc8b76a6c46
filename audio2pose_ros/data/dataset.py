"""Speech + motion data sets on disk: what importers write and training / evaluation read.

A data set is a folder::

    index.json            format version, joint names, motion rate, one entry per clip
    clips/<clip_id>.npz   audio (16 kHz mono float32), angles_rad (T, J) at 100 Hz,
                          mask (T, J) bool: True where the angle was observed

Each index entry carries the clip's speaker, source, licence and split ('train', 'validation'
or 'test'), so a data set derived from third-party recordings keeps their attribution. Motion
frame i covers audio samples [160 i, 160 i + 400), the frame grid of
:mod:`audio2pose_ros.timebase` that the audio features use too (seed 003 section 4.2.2: 25 ms
windows every 10 ms), so feature frame i and pose frame i line up.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLE_RATE_HZ, complete_frames

FORMAT_VERSION = 1
SPLITS = ("train", "validation", "test")
INDEX_FILE = "index.json"
FRAME_TOLERANCE = 3  # motion may be this many frames longer or shorter than the audio's grid


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
        """Reject unknown splits and ids that are not safe file names."""
        if self.split not in SPLITS:
            raise DatasetError(f"clip {self.clip_id}: split {self.split!r} not in {SPLITS}")
        if not self.clip_id or "/" in self.clip_id or self.clip_id.startswith("."):
            raise DatasetError(f"clip id {self.clip_id!r} is not a valid file name")


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


def _check_clip(clip: Clip, robot: RobotDescription) -> None:
    cid = clip.info.clip_id
    if clip.angles_rad.ndim != 2 or clip.angles_rad.shape[1] != robot.n_joints:
        raise DatasetError(
            f"clip {cid}: angles shape {clip.angles_rad.shape}, expected (T, {robot.n_joints})"
        )
    if clip.mask.shape != clip.angles_rad.shape or clip.mask.dtype != bool:
        raise DatasetError(f"clip {cid}: mask must be bool with the angles' shape")
    if clip.audio.ndim != 1:
        raise DatasetError(f"clip {cid}: audio must be mono (1-d), got shape {clip.audio.shape}")
    grid = complete_frames(clip.audio.shape[0])
    if abs(clip.n_frames - grid) > FRAME_TOLERANCE:
        raise DatasetError(
            f"clip {cid}: {clip.n_frames} motion frames for audio of {grid} "
            f"frames ({clip.audio.shape[0]} samples at 16 kHz)"
        )
    if not np.isfinite(clip.angles_rad[clip.mask]).all():
        raise DatasetError(f"clip {cid}: observed angles contain NaN/inf")


class Dataset:
    """A data set folder; create it with :meth:`create`, open it with :meth:`open`."""

    def __init__(self, root: Path, joint_names: tuple[str, ...], clips: list[ClipInfo]) -> None:
        """Use :meth:`create` or :meth:`open`."""
        self.root = root
        self.joint_names = joint_names
        self.clips = clips

    @classmethod
    def create(cls, root: str | Path, robot: RobotDescription) -> Dataset:
        """Start an empty data set in ``root`` (created if needed; must not hold one yet)."""
        path = Path(root)
        if (path / INDEX_FILE).exists():
            raise DatasetError(f"{path} already holds a data set ({INDEX_FILE})")
        (path / "clips").mkdir(parents=True, exist_ok=True)
        dataset = cls(path, robot.names, [])
        dataset._write_index()
        return dataset

    @classmethod
    def open(cls, root: str | Path, robot: RobotDescription | None = None) -> Dataset:
        """Open a data set; with ``robot``, its joints must be the robot's, in order."""
        path = Path(root)
        try:
            index = json.loads((path / INDEX_FILE).read_text(encoding="utf-8"))
            version = index["format_version"]
            names = tuple(index["joint_names"])
            clips = [ClipInfo(**entry) for entry in index["clips"]]
        except FileNotFoundError:
            raise DatasetError(f"{path}: no {INDEX_FILE}; not a data set folder") from None
        except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, DatasetError) as exc:
            raise DatasetError(f"{path / INDEX_FILE}: malformed index ({exc})") from None
        except OSError as exc:
            raise DatasetError(
                f"{path / INDEX_FILE}: cannot read ({exc.strerror or exc})"
            ) from None
        if version != FORMAT_VERSION:
            raise DatasetError(f"{path}: data set format {version}, expected {FORMAT_VERSION}")
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

    def add(self, clip: Clip, robot: RobotDescription) -> None:
        """Validate and store ``clip``, replacing a clip with the same id."""
        if robot.names != self.joint_names:
            raise DatasetError(f"{self.root}: robot joints differ from the data set's")
        _check_clip(clip, robot)
        np.savez_compressed(
            self.root / "clips" / f"{clip.info.clip_id}.npz",
            audio=clip.audio.astype(np.float32),
            angles_rad=clip.angles_rad.astype(np.float32),
            mask=clip.mask,
        )
        self.clips = [c for c in self.clips if c.clip_id != clip.info.clip_id] + [clip.info]
        self._write_index()

    def load(self, clip_id: str) -> Clip:
        """Read one clip from disk."""
        info = next((c for c in self.clips if c.clip_id == clip_id), None)
        if info is None:
            raise DatasetError(f"{self.root}: no clip {clip_id!r}")
        path = self.root / "clips" / f"{clip_id}.npz"
        try:
            with np.load(path, allow_pickle=False) as data:
                return Clip(
                    info,
                    data["audio"],
                    data["angles_rad"].astype(np.float64),
                    data["mask"].astype(bool),
                )
        except (OSError, KeyError, ValueError) as exc:
            raise DatasetError(f"{path}: unreadable clip ({exc})") from None

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
