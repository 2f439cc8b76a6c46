"""OpenFace 2.0 CSV importer: head rotation per video frame (the format of seed 000's data).

OpenFace's FeatureExtraction writes one row per frame with ``frame, face_id, timestamp,
confidence, success, ..., pose_Tx, pose_Ty, pose_Tz, pose_Rx, pose_Ry, pose_Rz, ...`` (header
names may carry a leading space). Seed 000 section 4.3.2: the rotation is in radians about the
x, y and z axes of OpenCV's camera frame (x right, y down, z away from the camera), composed as
``R = Rx(pose_Rx) Ry(pose_Ry) Rz(pose_Rz)``; that is the camera-frame rotation of
:mod:`~audio2pose_ros.data.importers.head_pose`, so pitch > 0 looks down and a turn to the speaker's
left makes pose_Ry negative (HeadYaw = -pose_Ry for a frontal face). Rows with ``success`` 0 (or
a confidence below the threshold) are masked. Translation (pose_T*) drives nothing on Pepper and
is not imported. The audio comes from a separate file (the video OpenFace analysed, or a WAV).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.data.importers import head_pose
from audio2pose_ros.data.importers.common import (
    HEAD_JOINTS,
    ImporterError,
    assemble_clip,
    head_neutral,
)
from audio2pose_ros.errors import short_repr
from audio2pose_ros.files import open_bounded
from audio2pose_ros.robot.description import RobotDescription

# OpenFace's full output is about 5 KB per frame: 1 GiB is two hours at 30 frames/s.
MAX_CSV_BYTES = 1 << 30
REQUIRED_COLUMNS = ("timestamp", "confidence", "success", "pose_Rx", "pose_Ry", "pose_Rz")


@dataclass(frozen=True)
class OpenFaceImportSettings:
    """Options of the OpenFace importer.

    Attributes:
        min_confidence: rows below this confidence are masked like ``success == 0``.
        face_id: which face to use when the CSV tracks several (None: the first row's face).
        mirror: exchange left and right (see the video importer).
        centre: the clip's median head orientation becomes the robot's neutral head pose.

    """

    min_confidence: float = 0.0
    face_id: int | None = None
    mirror: bool = False
    centre: bool = True


@dataclass
class OpenFaceTrack:
    """The rows of one face: times (s), rotations (camera frame) and usable rows."""

    times_s: np.ndarray  # (N,)
    rotation_cam: np.ndarray  # (N, 3, 3)
    usable: np.ndarray  # (N,) bool


def _rotation_xyz(rx: np.ndarray, ry: np.ndarray, rz: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``Rx(rx) Ry(ry) Rz(rz)`` (seed 000 eq. 4.6; intrinsic x-y-z Euler angles)."""
    return Rotation.from_euler("XYZ", np.stack([rx, ry, rz], axis=-1)).as_matrix()


def read_openface_csv(path: Path, settings: OpenFaceImportSettings) -> OpenFaceTrack:
    """Read the head rotation track of one face from an OpenFace 2.0 CSV.

    The file must be a regular file of at most :data:`MAX_CSV_BYTES`; it is streamed, and only
    the columns the track needs are kept.

    Raises:
        ImporterError: not a regular file, too large, unreadable, malformed CSV, missing
            columns, non-numeric values, no rows or non-increasing timestamps; the message names
            the file.

    """
    with open_bounded(path, "CSV", ImporterError, MAX_CSV_BYTES) as raw:
        stream = io.TextIOWrapper(raw, encoding="utf-8", newline="")
        try:
            reader = csv.reader(stream, skipinitialspace=True)
            first = next(reader, None)
            if first is None:
                raise ImporterError(f"{path}: empty file")
            header = [name.strip() for name in first]
            missing = [c for c in REQUIRED_COLUMNS if c not in header]
            if missing:
                raise ImporterError(
                    f"{path}: not an OpenFace 2.0 CSV: missing columns {missing} "
                    f"(has {short_repr(header[:8], 200)}...)"
                )
            columns = [*REQUIRED_COLUMNS, *(["face_id"] if "face_id" in header else [])]
            index = [header.index(c) for c in columns]
            rows = [[float(row[i]) for i in index] for row in reader if row]
        except UnicodeDecodeError as exc:
            raise ImporterError(f"{path}: not UTF-8 text ({exc})") from None
        except (ValueError, IndexError) as exc:
            raise ImporterError(f"{path}: line {reader.line_num}: malformed row ({exc})") from None
        except csv.Error as exc:
            raise ImporterError(f"{path}: line {reader.line_num}: malformed CSV ({exc})") from None
        except OSError as exc:
            raise ImporterError(f"{path}: cannot read ({exc.strerror or exc})") from None
    data: np.ndarray = np.array(rows, dtype=np.float64, ndmin=2)
    if data.shape[0] == 0 or data.shape[1] != len(columns):
        raise ImporterError(f"{path}: no data rows")
    if "face_id" in columns:
        face = data[0, -1] if settings.face_id is None else settings.face_id
        data = data[data[:, -1] == face]
        if data.shape[0] == 0:
            raise ImporterError(f"{path}: no rows of face_id {face}")
    times = data[:, 0]
    if np.any(np.diff(times) <= 0):
        raise ImporterError(f"{path}: timestamps do not increase")
    finite = np.isfinite(data[:, 3:6]).all(axis=1)
    rotation = _rotation_xyz(*np.where(finite[:, None], data[:, 3:6], 0.0).T)
    usable = (data[:, 2] != 0) & (data[:, 1] >= settings.min_confidence) & finite
    return OpenFaceTrack(times, rotation, usable)


def import_openface(
    path: Path,
    audio: np.ndarray,
    info: ClipInfo,
    robot: RobotDescription,
    settings: OpenFaceImportSettings | None = None,
) -> tuple[Clip, dict[str, np.ndarray]]:
    """Import an OpenFace 2.0 CSV with its audio as a clip (head joints only) plus extras.

    Args:
        path: the CSV.
        audio: (n_samples,) 16 kHz mono float32 of the analysed recording (timestamp 0 = sample 0).
        info: the clip's metadata.
        robot: joint order, limits and neutral pose.
        settings: importer options.

    Raises:
        ImporterError: malformed CSV or no usable row (the message names the file).

    """
    settings = settings or OpenFaceImportSettings()
    track = read_openface_csv(path, settings)
    if not track.usable.any():
        raise ImporterError(f"{path}: no row with success = 1 (no face tracked)")
    neutral = head_neutral(robot) if settings.centre else None
    ypr, kept = head_pose.clean_head_track(track.rotation_cam, track.usable, neutral)
    angles = np.full((track.times_s.size, robot.n_joints), np.nan)
    observed = np.zeros(angles.shape, dtype=bool)
    for k, name in enumerate(HEAD_JOINTS):
        angles[:, robot.names.index(name)] = ypr[:, k]
        observed[:, robot.names.index(name)] = kept
    return assemble_clip(
        track.times_s, angles, observed, ypr[:, 2], audio, info, robot, settings.mirror
    )
