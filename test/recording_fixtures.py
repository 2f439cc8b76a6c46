"""Recordings with known motion for the importer tests: BVH, OpenFace CSV and WAV writers.

The known motion is a set of slow sinusoids for Pepper's 11 joints (inside their limits, elbows
always bent so that ElbowYaw is defined). The BVH writer builds a small skeleton (Y up, facing
+Z, left = +X) and sets its channels so that Pepper's own kinematic chain (upper_body's
docstring) produces those angles.
"""

from __future__ import annotations

import wave
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from audio2pose_ros.data.importers.head_pose import CAMERA_TO_BODY

NAMES = (
    "HeadPitch", "HeadYaw", "LShoulderRoll", "LShoulderPitch", "LElbowRoll", "LElbowYaw",
    "RShoulderRoll", "RShoulderPitch", "RElbowRoll", "RElbowYaw", "HipRoll",
)  # fmt: skip
# (offset, amplitude, frequency Hz) per joint, radians; the arms stay 5.8 cm clear of Pepper's body,
# so the importers' last step (moving arms out of the body) leaves the motion as it is
MOTION = {
    "HeadPitch": (-0.15, 0.2, 0.4), "HeadYaw": (0.1, 0.5, 0.3),
    "LShoulderRoll": (1.1, 0.25, 0.35), "LShoulderPitch": (0.8, 0.5, 0.25),
    "LElbowRoll": (-0.9, 0.3, 0.45), "LElbowYaw": (-0.8, 0.4, 0.3),
    "RShoulderRoll": (-1.1, 0.2, 0.3), "RShoulderPitch": (1.0, 0.4, 0.2),
    "RElbowRoll": (1.0, 0.3, 0.35), "RElbowYaw": (0.6, 0.4, 0.25), "HipRoll": (0.0, 0.2, 0.3),
}  # fmt: skip
# BVH body axes at rest: columns forward (+Z), left (+X), up (+Y)
REST_AXES = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])


def known_angles(times_s: np.ndarray) -> dict[str, np.ndarray]:
    """The known motion at the given times."""
    return {n: o + a * np.sin(2 * np.pi * f * times_s) for n, (o, a, f) in MOTION.items()}


def _rot(axis: str, angle: np.ndarray) -> np.ndarray:
    return Rotation.from_euler(axis, np.asarray(angle)[:, None]).as_matrix()


def write_bvh(path: Path, n_frames: int, frame_time_s: float, body_yaw_rad: float = 0.3) -> None:
    """Write a BVH whose retargeting gives :func:`known_angles` (whole body turned by a yaw)."""
    t = np.arange(n_frames) * frame_time_s
    q = known_angles(t)
    b = REST_AXES
    to_bvh = lambda r: b @ r @ b.T  # noqa: E731 - body-axis rotation written in BVH axes
    g_pelvis = to_bvh(_rot("z", np.full(n_frames, body_yaw_rad)))
    g_chest = g_pelvis @ to_bvh(_rot("x", q["HipRoll"]))
    g_head = g_chest @ to_bvh(_rot("z", q["HeadYaw"]) @ _rot("y", q["HeadPitch"]))
    globals_ = {"Hips": g_pelvis, "Spine3": g_chest, "Head": g_head}
    for side, rest_turn in (("L", -np.pi / 2), ("R", np.pi / 2)):
        bone_to_x = _rot("z", np.full(n_frames, rest_turn))  # rest bone direction -> body x
        upper = _rot("y", q[f"{side}ShoulderPitch"]) @ _rot("z", q[f"{side}ShoulderRoll"])
        elbow = _rot("x", q[f"{side}ElbowYaw"]) @ _rot("z", q[f"{side}ElbowRoll"])
        prefix = "Left" if side == "L" else "Right"
        globals_[f"{prefix}Arm"] = g_chest @ to_bvh(upper @ bone_to_x)
        globals_[f"{prefix}ForeArm"] = g_chest @ to_bvh(upper @ elbow @ bone_to_x)
        globals_[f"{prefix}Hand"] = globals_[f"{prefix}ForeArm"]
    parents = {
        "Hips": None, "Spine3": "Hips", "Head": "Spine3",
        "LeftArm": "Spine3", "LeftForeArm": "LeftArm", "LeftHand": "LeftForeArm",
        "RightArm": "Spine3", "RightForeArm": "RightArm", "RightHand": "RightForeArm",
    }  # fmt: skip
    offsets = {
        "Hips": (0, 90, 0), "Spine3": (0, 40, 0), "Head": (0, 25, 0),
        "LeftArm": (15, 20, 0), "LeftForeArm": (25, 0, 0), "LeftHand": (25, 0, 0),
        "RightArm": (-15, 20, 0), "RightForeArm": (-25, 0, 0), "RightHand": (-25, 0, 0),
    }  # fmt: skip
    columns = [np.zeros((n_frames, 3))]  # root position channels
    for name, parent in parents.items():
        local = (
            globals_[name]
            if parent is None
            else np.swapaxes(globals_[parent], 1, 2) @ globals_[name]
        )
        columns.append(Rotation.from_matrix(local).as_euler("ZXY", degrees=True))
    children = {p: [c for c, pp in parents.items() if pp == p] for p in parents}

    def joint_text(name: str, depth: int) -> list[str]:
        pad = "  " * depth
        head = "ROOT" if parents[name] is None else "JOINT"
        lines = [
            f"{pad}{head} {name}",
            f"{pad}{{",
            f"{pad}  OFFSET {' '.join(map(str, offsets[name]))}",
        ]
        channels = "Zrotation Xrotation Yrotation"
        if parents[name] is None:
            channels = "Xposition Yposition Zposition " + channels
        lines.append(f"{pad}  CHANNELS {len(channels.split())} {channels}")
        for child in children[name]:
            lines += joint_text(child, depth + 1)
        if not children[name]:
            lines += [f"{pad}  End Site", f"{pad}  {{", f"{pad}    OFFSET 0 5 0", f"{pad}  }}"]
        return [*lines, f"{pad}}}"]

    motion = np.concatenate(columns, axis=1)
    text = ["HIERARCHY", *joint_text("Hips", 0), "MOTION", f"Frames: {n_frames}"]
    text.append(f"Frame Time: {frame_time_s}")
    text += [" ".join(f"{v:.6f}" for v in row) for row in motion]
    path.write_text("\n".join(text) + "\n", encoding="utf-8")


def openface_rotation(yaw_rad: np.ndarray, pitch_rad: np.ndarray) -> np.ndarray:
    """OpenFace pose_Rx, pose_Ry, pose_Rz (N, 3) of a head turned by yaw and pitch (body frame)."""
    body = _rot("z", yaw_rad) @ _rot("y", pitch_rad)
    camera = CAMERA_TO_BODY @ body @ CAMERA_TO_BODY.T
    return Rotation.from_matrix(camera).as_euler("XYZ")


def write_openface_csv(
    path: Path, times_s: np.ndarray, pose_r: np.ndarray, success: np.ndarray
) -> None:
    """An OpenFace 2.0 style CSV (header names after ", " as FeatureExtraction writes them)."""
    header = ["frame", "face_id", "timestamp", "confidence", "success", "gaze_0_x"]
    header += ["pose_Tx", "pose_Ty", "pose_Tz", "pose_Rx", "pose_Ry", "pose_Rz", "AU01_r"]
    lines = [", ".join(header)]
    for i, (t, r, ok) in enumerate(zip(times_s, pose_r, success, strict=True)):
        values = [i + 1, 0, f"{t:.3f}", 0.98 if ok else 0.0, int(ok), 0.1, 10, 20, 500]
        lines.append(", ".join(str(v) for v in [*values, *(f"{x:.6f}" for x in r), 0.5]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_wav(path: Path, seconds: float, rate_hz: int = 16000, seed: int = 0) -> None:
    """A mono 16-bit WAV of quiet noise."""
    rng = np.random.default_rng(seed)
    samples = (0.1 * rng.standard_normal(int(seconds * rate_hz)) * 32767).astype("<i2")
    with wave.open(str(path), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(rate_hz)
        out.writeframes(samples.tobytes())
