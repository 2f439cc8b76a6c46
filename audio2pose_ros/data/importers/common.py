"""Steps every importer shares: the audio feature grid, seed 003's pose post-processing, mirroring.

Seed 003 section 4.2.3 turns per-video-frame joint angles into training targets in three steps:
up-sampling to the audio feature rate f_f = 100 Hz by linear interpolation ("Synchronisation with
audio features"), a 5th-order 4 Hz low-pass Butterworth filter ("Smoothing") and clamping to the
robot's limits ("Constraining to robot operating limits"). A fourth step is ours: arms that the
retargeting puts in or against the robot's body are moved clear of it (:mod:`.body_clearance`).
The [0, 1] normalisation of eq. 3.14 is left to training (:meth:`RobotDescription.normalize`),
so data sets store radians.

Motion frame ``i`` of a clip sits at the centre of audio window ``i`` (samples
``[160 i, 160 i + 400)`` at 16 kHz, :mod:`audio2pose_ros.data.dataset`), i.e. at
``0.0125 + 0.01 i`` seconds: the importers sample their angle tracks at these instants.

Source files are untrusted input: the text readers open them with
:func:`~audio2pose_ros.files.open_bounded` (a regular file of bounded size, streamed),
and :func:`assemble_clip` refuses a clip in which no joint is observed at any frame of the
audio, whichever importer made it.
"""

from __future__ import annotations

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.data.importers.body_clearance import clear_of_body
from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.smoothing import butterworth_zero_phase
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ, frame_times_s

HEAD_JOINTS = ("HeadYaw", "HeadPitch")  # driven by head yaw and pitch, in this order
MAX_GAP_S = 0.25  # unobserved stretches up to this long are interpolated and count as observed

# Joints whose sign flips when left and right are exchanged (rotations about the forward or the
# vertical axis); the other joints only swap sides.
_MIRROR_NEGATED = ("HeadYaw", "HipRoll", "ShoulderRoll", "ElbowRoll", "ElbowYaw")


class ImporterError(InputError):
    """A source file cannot be imported; the message names the file and the reason."""


def head_neutral(robot: RobotDescription) -> tuple[float, float]:
    """The robot's neutral (HeadYaw, HeadPitch) in radians."""
    yaw, pitch = (float(robot.neutral_rad[robot.names.index(n)]) for n in HEAD_JOINTS)
    return yaw, pitch


def resample_to_grid(
    times_s: np.ndarray,
    values: np.ndarray,
    observed: np.ndarray,
    grid_s: np.ndarray,
    max_gap_s: float = MAX_GAP_S,
) -> tuple[np.ndarray, np.ndarray]:
    """Linearly interpolate a sampled track at the grid times (seed 003 4.2.3, 50 -> 100 Hz).

    Args:
        times_s: (N,) increasing sample times (s).
        values: (N, K) samples; entries where ``observed`` is False are ignored.
        observed: (N,) or (N, K) bool, True where a sample is valid.
        grid_s: (T,) times (s) to sample at.
        max_gap_s: grid points farther than this from an observed sample on either side (gaps,
            or beyond the ends of the track) are marked unobserved.

    Returns:
        ``(resampled, mask)``: (T, K) values, filled everywhere by interpolation (constant beyond
        the ends; NaN only for a column without any observed sample) and (T, K) bool mask.

    """
    values = np.asarray(values, dtype=np.float64)
    observed = np.asarray(observed, dtype=bool).reshape(len(times_s), -1)
    observed = np.broadcast_to(observed, values.shape)
    out = np.full((grid_s.size, values.shape[1]), np.nan)
    mask = np.zeros((grid_s.size, values.shape[1]), dtype=bool)
    for k in range(values.shape[1]):
        t = times_s[observed[:, k]]
        if t.size == 0:
            continue
        out[:, k] = np.interp(grid_s, t, values[observed[:, k], k])
        after = np.searchsorted(t, grid_s)
        before_gap = grid_s - t[np.clip(after - 1, 0, t.size - 1)]
        after_gap = t[np.clip(after, 0, t.size - 1)] - grid_s
        before_gap[after == 0] = np.inf
        after_gap[after == t.size] = np.inf
        exact = np.isclose(before_gap, 0.0) | np.isclose(after_gap, 0.0)
        inside = (before_gap <= max_gap_s) & (after_gap <= max_gap_s)
        edge = ((after == 0) & (after_gap <= max_gap_s)) | (
            (after == t.size) & (before_gap <= max_gap_s)
        )
        mask[:, k] = exact | inside | edge
    return out, mask


def finish_angles(
    angles_rad: np.ndarray, mask: np.ndarray, robot: RobotDescription
) -> tuple[np.ndarray, np.ndarray]:
    """Seed 003 4.2.3 on the 100 Hz grid: 5th-order 4 Hz Butterworth, then clamp to the limits.

    Unobserved joints stay at the robot's neutral pose (their mask is False); a column that
    is observed only in part is filtered across its gaps (which the filled-in values bridge).

    Args:
        angles_rad: (T, J) angles on the grid, in the robot's joint order; NaN where unknown.
        mask: (T, J) True where observed.
        robot: limits and neutral pose.

    Returns:
        ``(angles_rad, mask)``, both (T, J); angles are finite and inside the limits.

    """
    filled = np.where(np.isfinite(angles_rad), angles_rad, robot.neutral_rad)
    if filled.shape[0] > 1:
        filled = butterworth_zero_phase(filled, rate_hz=FRAME_RATE_HZ)
    clamped = np.clip(filled, robot.lower_rad, robot.upper_rad)
    return np.where(mask, clamped, robot.neutral_rad), mask.copy()


def smooth_track(track: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Seed 003's 4 Hz Butterworth on a (T,) grid track without joint limits; 0 where unobserved.

    For quantities that are kept with a clip but drive no joint (head roll).
    """
    filled = np.nan_to_num(np.asarray(track, dtype=np.float64))
    if filled.size > 1:
        filled = butterworth_zero_phase(filled[:, None], rate_hz=FRAME_RATE_HZ)[:, 0]
    return np.where(mask, filled, 0.0)


def mirror_angles(angles_rad: np.ndarray, robot: RobotDescription) -> np.ndarray:
    """Exchange left and right: swap L/R joints and negate yaw / roll joints (HeadPitch stays).

    For a robot that mirrors the speaker (as a mirror image would) or a video that was flipped
    horizontally (many webcam / selfie recordings). Applied twice it is the identity.

    Args:
        angles_rad: (..., J) angles in the robot's joint order.
        robot: joint names.

    Returns:
        The mirrored angles, same shape.

    """
    names = robot.names
    out = np.array(angles_rad, dtype=np.float64, copy=True)
    for j, name in enumerate(names):
        partner = _partner(name)
        source = names.index(partner) if partner in names else j
        sign = -1.0 if any(name.endswith(part) for part in _MIRROR_NEGATED) else 1.0
        out[..., j] = sign * np.asarray(angles_rad)[..., source]
    return out


def mirror_mask(mask: np.ndarray, robot: RobotDescription) -> np.ndarray:
    """The mask that goes with :func:`mirror_angles` (left and right columns swapped)."""
    names = robot.names
    order = [names.index(_partner(n)) if _partner(n) in names else j for j, n in enumerate(names)]
    return np.asarray(mask)[..., order]


def _partner(name: str) -> str:
    if name.startswith("L"):
        return "R" + name[1:]
    if name.startswith("R"):
        return "L" + name[1:]
    return name


def assemble_clip(
    times_s: np.ndarray,
    angles_rad: np.ndarray,
    observed: np.ndarray,
    head_roll_rad: np.ndarray,
    audio: np.ndarray,
    info: ClipInfo,
    robot: RobotDescription,
    mirror: bool = False,
) -> tuple[Clip, dict[str, np.ndarray]]:
    """Per-source-frame angles to a clip on the audio grid (seed 003 section 4.2.3), plus extras.

    Args:
        times_s: (N,) increasing times of the source frames (s, audio starts at 0).
        angles_rad: (N, J) angles in the robot's joint order (anything where not observed).
        observed: (N, J) bool.
        head_roll_rad: (N,) head roll (body frame, see :mod:`.head_pose`), observed with HeadYaw.
        audio: (n_samples,) 16 kHz mono float32.
        info: the clip's metadata.
        robot: joint order, limits and neutral pose.
        mirror: exchange left and right (:func:`mirror_angles`; roll changes sign).

    Returns:
        The clip and its extras: ``head_roll_rad`` (T,), ``head_roll_mask`` (T,) bool and
        ``body_moved_rad`` (T,), how far each frame's arms were moved clear of the
        robot's body (:func:`~.body_clearance.clear_of_body`, after seed 003's steps).

    Raises:
        ImporterError: no joint is observed at any frame of the audio (nothing to learn from:
            no source frame is observed, or none lies within :data:`MAX_GAP_S` of the audio).

    """
    grid = frame_times_s(audio.size)
    angles, mask = resample_to_grid(times_s, angles_rad, observed, grid)
    if not mask.any():
        raise ImporterError(
            f"clip {info.clip_id}: no joint observed at any of the {grid.size} frames of the "
            f"audio ({np.count_nonzero(observed)} observed values in {len(times_s)} source frames)"
        )
    head = observed[:, robot.names.index(HEAD_JOINTS[0])]
    roll, roll_mask = resample_to_grid(times_s, head_roll_rad[:, None], head, grid)
    angles, mask = finish_angles(angles, mask, robot)
    roll = smooth_track(roll[:, 0], roll_mask[:, 0])
    if mirror:
        angles, mask, roll = mirror_angles(angles, robot), mirror_mask(mask, robot), -roll
    angles, moved = clear_of_body(angles, mask, robot)
    clip = Clip(info, np.asarray(audio, dtype=np.float32), angles, mask)
    extras = {"head_roll_rad": roll, "head_roll_mask": roll_mask[:, 0], "body_moved_rad": moved}
    return clip, extras
