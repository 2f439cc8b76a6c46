"""Head rotation from face landmarks, and head rotations to Pepper's HeadYaw / HeadPitch.

Frames and signs (all right-handed):

- **camera frame**: x to the image's right, y down, z away from the camera (OpenCV; OpenFace's
  pose_R* and MediaPipe's landmark coordinates use it).
- **body frame** (Pepper's torso frame): x forward, y to the robot's left, z up. A person facing
  the camera looks along camera -z, their left is camera +x and their up camera -y.
- A head rotation ``R`` in the body frame is split as ``R = Rz(yaw) Ry(pitch) Rx(roll)``:
  ``yaw`` > 0 turns the face to the person's left, ``pitch`` > 0 tilts it down, ``roll`` > 0 tilts
  the top of the head to the person's right. Pepper's HeadYaw > 0 turns its head to its left and
  HeadPitch > 0 bends it down, so by default (``mirror=False``) HeadYaw = yaw and HeadPitch =
  pitch: the robot moves as the speaker does. The importers' ``mirror`` option
  (:func:`~audio2pose_ros.data.importers.common.mirror_angles`) negates yaw and roll and swaps the
  arms: a mirror image of the speaker, or a correction for horizontally flipped video.
- Pepper has no head-roll joint: roll is returned beside the joints, stored with the clip (see
  :mod:`audio2pose_ros.data.importers.extras`) and drives nothing.

Video head pose follows seed 003 section 4.2.3's structure (per-frame estimate, then 100 Hz
resampling, 4 Hz Butterworth, clamping); the rotation itself comes from a scaled rigid fit
(Umeyama 1991) of the rigid landmarks of MediaPipe's canonical face model
(``config/canonical_face_rigid.yaml``) to MediaPipe FaceMesh's 3-D landmarks in each frame.
Per-frame estimates are unwrapped (no +-180 degree jumps) and outliers are rejected with a Hampel
filter before resampling. Seed 000 section 4.2 centres each clip's head translation because
camera placement differs between recordings; in the same spirit, by default each clip's median
head orientation becomes the robot's neutral pose (``centre=True``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from audio2pose_ros.files import packaged_mapping

FACE_MODEL_FILE = "canonical_face_rigid.yaml"
HAMPEL_HALF_WINDOW = 3  # frames each side of the median window (7 frames: 0.28 s at 25 fps)
HAMPEL_SIGMAS = 3.0  # reject samples farther than this many robust sigmas from the median
HAMPEL_FLOOR_RAD = np.deg2rad(2.0)  # never reject within 2 degrees of the local median
MAD_TO_SIGMA = 1.4826  # median absolute deviation of a Gaussian, in standard deviations
RESIDUAL_OUTLIER_FACTOR = 2.5  # fits worse than this times the clip's median residual are rejected

# Columns are the body frame's axes (forward, left, up) written in camera coordinates.
CAMERA_TO_BODY = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class FaceModel:
    """Rigid landmarks of a 3-D face model in the camera frame (face looking at the camera)."""

    indices: np.ndarray  # (K,) FaceMesh landmark indices
    points: np.ndarray  # (K, 3) model coordinates, camera frame, centred at their mean


@cache
def canonical_face_model() -> FaceModel:
    """MediaPipe's canonical face model, rigid part (``config/canonical_face_rigid.yaml``)."""
    data = packaged_mapping("config", FACE_MODEL_FILE)
    items = sorted(data["landmarks_cm"].items())
    indices = np.array([int(k) for k, _ in items])
    model_up = np.array([v for _, v in items], dtype=np.float64)  # x right, y up, z to camera
    points = model_up * np.array([1.0, -1.0, -1.0])  # to the camera frame (rotation by pi about x)
    return FaceModel(indices, points - points.mean(axis=0))


def rigid_fit(model: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, float]:
    """Rotation of ``model`` that best matches ``observed`` up to scale and shift (Umeyama 1991).

    Args:
        model: (K, 3) model points.
        observed: (K, 3) the same points as seen.

    Returns:
        ``(rotation, residual)``: (3, 3) proper rotation R with observed ~ s R model + t, and the
        RMS residual divided by the RMS size of the observed points (0 for an exact fit).

    """
    m = model - model.mean(axis=0)
    o = observed - observed.mean(axis=0)
    u, sing, vt = np.linalg.svd(o.T @ m)
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ flip @ vt
    scale = float(np.trace(np.diag(sing) @ flip) / max(float((m * m).sum()), 1e-12))
    residual = o - scale * m @ rotation.T
    size = max(float(np.sqrt((o * o).sum(axis=1).mean())), 1e-12)  # guard a degenerate face
    return rotation, float(np.sqrt((residual * residual).sum(axis=1).mean())) / size


def body_rotation_to_angles(rotation_body: np.ndarray) -> np.ndarray:
    """Yaw, pitch and roll (rad) of body-frame rotations ``Rz(yaw) Ry(pitch) Rx(roll)``.

    Args:
        rotation_body: (..., 3, 3) rotations in the body frame (x forward, y left, z up).

    Returns:
        (..., 3) ``[yaw, pitch, roll]``; pitch lies in [-pi/2, pi/2].

    """
    r = np.asarray(rotation_body)
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    return np.stack([yaw, pitch, roll], axis=-1)


def camera_rotation_to_angles(rotation_cam: np.ndarray) -> np.ndarray:
    """Head yaw, pitch and roll (rad, body frame; see the module docstring) of camera rotations.

    Args:
        rotation_cam: (..., 3, 3) head rotations in the camera frame (identity: facing the
            camera squarely).

    Returns:
        (..., 3) ``[yaw, pitch, roll]`` in radians.

    """
    return body_rotation_to_angles(CAMERA_TO_BODY.T @ np.asarray(rotation_cam) @ CAMERA_TO_BODY)


def reject_outliers(angles_rad: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Hampel filter: drop samples far from the median of their neighbourhood.

    Args:
        angles_rad: (N, K) unwrapped angle tracks.
        observed: (N,) bool, True where the frame has an estimate.

    Returns:
        (N,) bool: ``observed`` without the frames where any track is an outlier.

    """
    keep = observed.copy()
    index = np.flatnonzero(observed)
    values = angles_rad[index]
    for pos in range(index.size):
        lo, hi = max(0, pos - HAMPEL_HALF_WINDOW), min(index.size, pos + HAMPEL_HALF_WINDOW + 1)
        window = values[lo:hi]
        median = np.median(window, axis=0)
        sigma = MAD_TO_SIGMA * np.median(np.abs(window - median), axis=0)
        limit = np.maximum(HAMPEL_SIGMAS * sigma, HAMPEL_FLOOR_RAD)
        if np.any(np.abs(values[pos] - median) > limit):
            keep[index[pos]] = False
    return keep


def unwrap_observed(angles_rad: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Unwrap (N, K) angle tracks along time over the observed frames (no +-pi jumps)."""
    out = np.array(angles_rad, dtype=np.float64, copy=True)
    index = np.flatnonzero(observed)
    if index.size:
        out[index] = np.unwrap(out[index], axis=0)
    return out


def centre_on(ypr_rad: np.ndarray, observed: np.ndarray, neutral_rad: np.ndarray) -> np.ndarray:
    """Shift each track so that its median over the observed frames equals ``neutral_rad``."""
    if not observed.any():
        return ypr_rad.copy()
    return ypr_rad - np.median(ypr_rad[observed], axis=0) + neutral_rad


def clean_head_track(
    rotation_cam: np.ndarray,
    observed: np.ndarray,
    neutral_yaw_pitch_rad: tuple[float, float] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame head rotations to clean yaw / pitch / roll tracks.

    Converts to angles (:func:`camera_rotation_to_angles`), unwraps them over the observed
    frames, rejects outliers (:func:`reject_outliers`) and, with ``neutral_yaw_pitch_rad``, moves
    the median yaw and pitch there and the median roll to 0 (:func:`centre_on`).

    Args:
        rotation_cam: (N, 3, 3) camera-frame head rotations.
        observed: (N,) bool, frames with an estimate.
        neutral_yaw_pitch_rad: the robot's neutral (HeadYaw, HeadPitch), or None to keep angles
            relative to facing the camera.

    Returns:
        ``(ypr_rad, observed)``: (N, 3) yaw, pitch, roll and the (N,) frames kept.

    """
    ypr = unwrap_observed(camera_rotation_to_angles(rotation_cam), observed)
    kept = reject_outliers(ypr, observed)
    if neutral_yaw_pitch_rad is not None:
        ypr = centre_on(ypr, kept, np.array([*neutral_yaw_pitch_rad, 0.0]))
    return ypr, kept
