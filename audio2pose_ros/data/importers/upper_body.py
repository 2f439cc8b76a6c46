"""Pepper's shoulder, elbow and hip angles from 3-D upper-body keypoints (seed 003 section 4.2.3).

Seed 003 computes its 11 angles "from the extracted 3D joint positions" with a geometry library
and gives no formulas; the geometry here inverts Pepper's own kinematic chain (DESIGN.md
section 2, pepper_description URDF), so that angles read from a person drive the robot's joints
the same way. In the body frame (x forward, y to the person's left, z up):

- the upper arm points along ``Ry(ShoulderPitch) Rz(ShoulderRoll) x`` (pitch pi/2 = arm down,
  roll > 0 = arm out to the left), so ``roll = asin(u_y)`` and ``pitch = atan2(-u_z, u_x)``;
- in the upper-arm frame ``F = Ry(pitch) Rz(roll)`` the forearm points along
  ``Rx(ElbowYaw) Rz(ElbowRoll) x``, so ``|ElbowRoll| = acos(f_x)`` (negative on the left arm,
  positive on the right, as Pepper's limits require) and ``ElbowYaw = atan2(f_z, f_y)`` with
  the sign of ElbowRoll folded in. The small fixed pitch of Pepper's elbow frame in the URDF
  (-0.157 rad) is ignored. ElbowYaw is undefined with a straight arm: it is masked when
  ``|ElbowRoll|`` is below :data:`MIN_ELBOW_BEND_RAD`.
- HipRoll is the sideways lean of the spine (hip centre to shoulder centre) in the pelvis frame:
  ``atan2(-s_y, s_z)`` (Rx(HipRoll) z = s).

Keypoints may be given in any right-handed frame; the caller passes the body axes in that frame.
"""

from __future__ import annotations

import numpy as np

MIN_ELBOW_BEND_RAD = np.deg2rad(10.0)  # below this bend the elbow's yaw axis is undefined
ARM_JOINTS = ("ShoulderPitch", "ShoulderRoll", "ElbowYaw", "ElbowRoll")


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(norm, 1e-12)  # guard coincident keypoints (masked by the caller)


def body_frame(left: np.ndarray, right: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """Body axes from a left and a right keypoint and an approximate up direction.

    Args:
        left: (N, 3) a keypoint on the person's left (shoulder or hip).
        right: (N, 3) its right counterpart.
        up_hint: (N, 3) or (3,) roughly up (need not be orthogonal to left-right).

    Returns:
        (N, 3, 3) rotations whose columns are forward, left and up in the keypoints' frame.

    """
    y = _unit(left - right)
    up = np.broadcast_to(up_hint, y.shape)
    z = _unit(up - np.sum(up * y, axis=-1, keepdims=True) * y)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=-1)


def arm_angles(
    shoulder: np.ndarray, elbow: np.ndarray, wrist: np.ndarray, frame: np.ndarray, left_arm: bool
) -> dict[str, np.ndarray]:
    """ShoulderPitch, ShoulderRoll, ElbowYaw and ElbowRoll of one arm (rad).

    Args:
        shoulder: (N, 3) shoulder keypoints.
        elbow: (N, 3) elbow keypoints.
        wrist: (N, 3) wrist keypoints.
        frame: (N, 3, 3) body axes (columns forward, left, up), e.g. from :func:`body_frame`.
        left_arm: True for the left arm (ElbowRoll <= 0), False for the right one.

    Returns:
        Mapping from the joint names of :data:`ARM_JOINTS` to (N,) angles; ElbowYaw is NaN where
        the arm is too straight for it to be defined.

    """
    to_body = np.swapaxes(frame, -1, -2)
    u = _unit(np.einsum("nij,nj->ni", to_body, elbow - shoulder))
    f = _unit(np.einsum("nij,nj->ni", to_body, wrist - elbow))
    roll = np.arcsin(np.clip(u[:, 1], -1.0, 1.0))
    pitch = np.arctan2(-u[:, 2], u[:, 0])
    cp, sp, cr, sr = np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    # rows of F^T with F = Ry(pitch) Rz(roll): the upper-arm frame's axes in the body frame
    fx = np.stack([cp * cr, sr, -sp * cr], axis=-1)
    fy = np.stack([-cp * sr, cr, sp * sr], axis=-1)
    fz = np.stack([sp, np.zeros_like(sp), cp], axis=-1)
    local = np.stack([np.sum(fx * f, -1), np.sum(fy * f, -1), np.sum(fz * f, -1)], axis=-1)
    bend = np.arccos(np.clip(local[:, 0], -1.0, 1.0))
    sign = -1.0 if left_arm else 1.0
    yaw = np.arctan2(sign * local[:, 2], sign * local[:, 1])
    yaw = np.where(bend >= MIN_ELBOW_BEND_RAD, yaw, np.nan)
    return {"ShoulderPitch": pitch, "ShoulderRoll": roll, "ElbowYaw": yaw, "ElbowRoll": sign * bend}


def hip_roll(hip_centre: np.ndarray, shoulder_centre: np.ndarray, pelvis: np.ndarray) -> np.ndarray:
    """HipRoll (rad): sideways lean of the spine in the pelvis frame (> 0 leans to the right).

    Args:
        hip_centre: (N, 3) midpoint of the hips.
        shoulder_centre: (N, 3) midpoint of the shoulders.
        pelvis: (N, 3, 3) pelvis axes (columns forward, left, up).

    Returns:
        (N,) angles.

    """
    s = np.einsum("nij,nj->ni", np.swapaxes(pelvis, -1, -2), shoulder_centre - hip_centre)
    return np.arctan2(-s[:, 1], s[:, 2])
