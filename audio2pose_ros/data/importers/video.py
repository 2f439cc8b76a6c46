"""Video importer: speech + head pose (MediaPipe FaceMesh) + upper body (MediaPipe Pose).

One file becomes one clip: its audio track (16 kHz mono), HeadYaw and HeadPitch from the head
rotation of :mod:`~audio2pose_ros.data.importers.head_pose`, and the shoulder, elbow and hip angles
of
:mod:`~audio2pose_ros.data.importers.upper_body` where MediaPipe Pose sees the arms and hips (masked
elsewhere: a talking-head shot labels only the head). Head roll goes to the clip's extras.
mediapipe==0.10.14 ships its models inside the wheel, so this works offline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.data.importers import head_pose, upper_body
from audio2pose_ros.data.importers.common import (
    HEAD_JOINTS,
    ImporterError,
    assemble_clip,
    head_neutral,
)
from audio2pose_ros.data.importers.media import check_video, probe_media, read_audio, video_frames
from audio2pose_ros.robot.description import RobotDescription

MIN_FACE_FRACTION = 0.5  # fewer frames with a face than this: the file is refused
MIN_VISIBILITY = 0.5  # MediaPipe Pose visibility below which a keypoint counts as unseen
# MediaPipe Pose landmark indices (BlazePose topology), the person's own left and right
POSE_INDEX = {
    "left_shoulder": 11, "right_shoulder": 12, "left_elbow": 13, "right_elbow": 14,
    "left_wrist": 15, "right_wrist": 16, "left_hip": 23, "right_hip": 24,
}  # fmt: skip


@dataclass(frozen=True)
class VideoImportSettings:
    """Options of the video importer.

    Attributes:
        mirror: robot as the speaker's mirror image (or a horizontally flipped video): exchange
            left and right (see :func:`~audio2pose_ros.data.importers.common.mirror_angles`).
        centre: the clip's median head orientation becomes the robot's neutral head pose (else
            angles are relative to facing the camera squarely).
        body: run MediaPipe Pose for the arms and hip (False: head only, arms/hip masked, faster).
        max_seconds: import only the recording's first this many seconds (None: all of it);
            enrolment bounds its time this way.

    """

    mirror: bool = False
    centre: bool = True
    body: bool = True
    max_seconds: float | None = None


@dataclass
class VideoTracks:
    """Per-video-frame estimates (N frames)."""

    times_s: np.ndarray  # (N,)
    face_found: np.ndarray  # (N,) bool
    head_rotation: np.ndarray  # (N, 3, 3) camera frame; identity where no face
    fit_residual: np.ndarray  # (N,) relative RMS residual of the face fit; inf where no face
    body_xyz: np.ndarray  # (N, 33, 3) MediaPipe Pose world landmarks (m); NaN where none
    body_visibility: np.ndarray  # (N, 33) in [0, 1]; 0 where no body
    seconds: float = field(default=0.0)  # wall-clock time spent tracking


def _face_points(landmarks: object, width: int, height: int, indices: np.ndarray) -> np.ndarray:
    """Camera-frame coordinates (pixels) of the chosen FaceMesh landmarks."""
    points = landmarks.landmark  # type: ignore[attr-defined]
    scale = np.array([width, height, width])  # FaceMesh: x / width, y / height, z / width
    return scale * np.array([[points[i].x, points[i].y, points[i].z] for i in indices])


def track_video(
    path: Path, body: bool = True, face: bool = True, max_seconds: float | None = None
) -> VideoTracks:
    """Run FaceMesh (unless ``face`` is False) and Pose (if ``body``) on every frame of a video.

    With ``max_seconds``, frames after that time are not decoded. Frames come one at a time,
    scaled down to what MediaPipe needs (:func:`~.media.video_frames`).

    Raises:
        ImporterError: the file is not a readable video, or what
            :func:`~.media.check_video` refuses.

    """
    import mediapipe as mp

    model = head_pose.canonical_face_model()
    times, found, rotations, residuals = [], [], [], []
    xyz: list[list[list[float]] | np.ndarray] = []
    visibility: list[list[float] | np.ndarray] = []
    start = time.perf_counter()
    face_mesh = (
        mp.solutions.face_mesh.FaceMesh(static_image_mode=False, max_num_faces=1) if face else None
    )
    pose = mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1) if body else None
    try:
        for time_s, rgb in video_frames(path, max_seconds):
            times.append(time_s)
            faces = face_mesh.process(rgb).multi_face_landmarks if face_mesh is not None else None
            if faces:
                observed = _face_points(faces[0], rgb.shape[1], rgb.shape[0], model.indices)
                rotation, residual = head_pose.rigid_fit(model.points, observed)
            else:
                rotation, residual = np.eye(3), np.inf
            found.append(bool(faces))
            rotations.append(rotation)
            residuals.append(residual)
            world = pose.process(rgb).pose_world_landmarks if pose is not None else None
            if world is not None:
                xyz.append([[p.x, p.y, p.z] for p in world.landmark])
                visibility.append([p.visibility for p in world.landmark])
            else:
                xyz.append(np.full((33, 3), np.nan))
                visibility.append(np.zeros(33))
    finally:
        if face_mesh is not None:
            face_mesh.close()
        if pose is not None:
            pose.close()
    return VideoTracks(
        np.asarray(times),
        np.asarray(found),
        np.asarray(rotations),
        np.asarray(residuals),
        np.asarray(xyz, dtype=np.float64),
        np.asarray(visibility, dtype=np.float64),
        time.perf_counter() - start,
    )


def body_angles(tracks: VideoTracks, robot: RobotDescription) -> tuple[np.ndarray, np.ndarray]:
    """Arm and hip angles per video frame, (N, J) with NaN, and their (N, J) observed mask."""
    n, names = tracks.times_s.size, robot.names
    angles = np.full((n, robot.n_joints), np.nan)
    seen = {k: tracks.body_visibility[:, i] >= MIN_VISIBILITY for k, i in POSE_INDEX.items()}
    at = {k: tracks.body_xyz[:, i] for k, i in POSE_INDEX.items()}
    camera_up = np.array([0.0, -1.0, 0.0])  # MediaPipe world: y points down
    hips_seen = seen["left_hip"] & seen["right_hip"]
    hip_centre = 0.5 * (at["left_hip"] + at["right_hip"])
    shoulder_centre = 0.5 * (at["left_shoulder"] + at["right_shoulder"])
    up = np.where(hips_seen[:, None], shoulder_centre - hip_centre, camera_up)
    torso = upper_body.body_frame(at["left_shoulder"], at["right_shoulder"], up)
    shoulders_seen = seen["left_shoulder"] & seen["right_shoulder"]
    observed = np.zeros_like(angles, dtype=bool)
    for side, prefix in (("left", "L"), ("right", "R")):
        arm_seen = shoulders_seen & seen[f"{side}_elbow"] & seen[f"{side}_wrist"]
        arm = upper_body.arm_angles(
            at[f"{side}_shoulder"], at[f"{side}_elbow"], at[f"{side}_wrist"], torso, side == "left"
        )
        for joint, values in arm.items():
            if prefix + joint in names:
                j = names.index(prefix + joint)
                angles[:, j] = values
                observed[:, j] = arm_seen & np.isfinite(values)
    if "HipRoll" in names:
        pelvis = upper_body.body_frame(at["left_hip"], at["right_hip"], camera_up)
        j = names.index("HipRoll")
        angles[:, j] = upper_body.hip_roll(hip_centre, shoulder_centre, pelvis)
        observed[:, j] = hips_seen & shoulders_seen
    return angles, observed


def clip_from_tracks(
    tracks: VideoTracks,
    audio: np.ndarray,
    info: ClipInfo,
    robot: RobotDescription,
    settings: VideoImportSettings,
) -> tuple[Clip, dict[str, np.ndarray]]:
    """Turn per-frame estimates into a clip on the audio feature grid (seed 003 section 4.2.3).

    Face fits whose residual exceeds :data:`~.head_pose.RESIDUAL_OUTLIER_FACTOR` times the
    clip's median count as misses.

    Returns:
        The clip and its extras (``head_roll_rad``, ``head_roll_mask``; see :mod:`.extras`).

    """
    face = tracks.face_found.copy()
    if face.any():
        typical = np.median(tracks.fit_residual[face])
        face &= tracks.fit_residual <= head_pose.RESIDUAL_OUTLIER_FACTOR * typical
    neutral = head_neutral(robot) if settings.centre else None
    ypr, face = head_pose.clean_head_track(tracks.head_rotation, face, neutral)
    angles, observed = body_angles(tracks, robot)
    for k, name in enumerate(HEAD_JOINTS):
        angles[:, robot.names.index(name)] = ypr[:, k]
        observed[:, robot.names.index(name)] = face
    return assemble_clip(
        tracks.times_s, angles, observed, ypr[:, 2], audio, info, robot, settings.mirror
    )


def import_video(
    path: Path,
    info: ClipInfo,
    robot: RobotDescription,
    settings: VideoImportSettings | None = None,
    on_tracks: Callable[[VideoTracks], None] | None = None,
) -> tuple[Clip, dict[str, np.ndarray]]:
    """Import one video file as a clip (audio, joint angles at 100 Hz, mask) plus extras.

    Args:
        path: any file ffmpeg and OpenCV read, with an audio track and a visible face.
        info: the clip's id, speaker, source, licence and split.
        robot: joint order, limits and neutral pose.
        settings: importer options (defaults: not mirrored, centred, with the body).
        on_tracks: called with the per-frame tracks (e.g. to report speed and face rate).

    Raises:
        ImporterError: no audio track, unreadable video, frames too large to read
            (:func:`~.media.check_video`, before anything is decoded), or a face in too few
            frames; the message names the file.

    """
    settings = settings or VideoImportSettings()
    check_video(path, probe_media(path))
    audio = read_audio(path, settings.max_seconds)
    tracks = track_video(path, body=settings.body, max_seconds=settings.max_seconds)
    if on_tracks is not None:
        on_tracks(tracks)
    n_face, n_frames = int(tracks.face_found.sum()), tracks.times_s.size
    if n_face < MIN_FACE_FRACTION * n_frames:
        raise ImporterError(f"{path}: a face was found in only {n_face} of {n_frames} frames")
    return clip_from_tracks(tracks, audio, info, robot, settings)
