"""BVH motion capture importer: parse, forward kinematics, retarget to Pepper's 11 joints.

A skeleton mapping (``config/bvh_mappings.yaml``, or a user's YAML of the same shape) names the
BVH joints that play the roles Pepper needs: ``pelvis``, ``torso`` (the chest), ``head`` and,
per side, ``shoulder`` / ``elbow`` / ``wrist`` (the joints at those places: in most skeletons
``LeftArm``, ``LeftForeArm``, ``LeftHand``). Retargeting:

- body axes (forward, left, up) come from the rest pose (all channels zero): left = left
  shoulder - right shoulder, up = head - pelvis. The rest pose must stand upright facing forward
  (T-pose or A-pose, as BVH files usually do); the chest and the pelvis carry these axes along
  with their global rotations.
- arms: shoulder, elbow and wrist positions in the chest's axes give ShoulderPitch / Roll and
  ElbowYaw / Roll (:mod:`~audio2pose_ros.data.importers.upper_body`, seed 003 section 4.2.3);
- head: the head's rotation relative to the chest, split as in
  :mod:`~audio2pose_ros.data.importers.head_pose` into HeadYaw, HeadPitch and roll (kept in extras);
- HipRoll: the chest's sideways lean relative to the pelvis.

BVH conventions: rotation channels are Euler angles in degrees applied in the listed order
(``Zrotation Xrotation Yrotation`` means ``R = Rz Rx Ry``); a child's position is its parent's
plus the parent's global rotation times (OFFSET + its position channels); the first frame of the
motion is at time 0 of the audio.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.data.importers import head_pose, upper_body
from audio2pose_ros.data.importers.common import HEAD_JOINTS, ImporterError, assemble_clip
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.yaml_files import read_yaml_file

MAPPINGS_FILE = "bvh_mappings.yaml"
ROLES = (
    "pelvis", "torso", "head", "left_shoulder", "left_elbow", "left_wrist",
    "right_shoulder", "right_elbow", "right_wrist",
)  # fmt: skip
_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass(frozen=True)
class BvhJoint:
    """One joint of the hierarchy (End Sites are not kept)."""

    name: str
    parent: int  # index into the joint list, -1 for the root
    offset: np.ndarray  # (3,) in the file's length unit
    channels: tuple[str, ...]  # e.g. ("Xposition", ..., "Zrotation", "Xrotation", "Yrotation")


@dataclass
class BvhMotion:
    """A parsed BVH file."""

    joints: list[BvhJoint]
    frame_time_s: float
    values: np.ndarray  # (n_frames, n_channels) in file order

    def index(self, name: str) -> int:
        """Position of joint ``name`` in :attr:`joints`."""
        for i, joint in enumerate(self.joints):
            if joint.name == name:
                return i
        raise KeyError(name)


class _Tokens:
    """Whitespace-separated tokens with their line numbers, for error messages."""

    def __init__(self, text: str, path: Path) -> None:
        self.items = [
            (tok, n) for n, line in enumerate(text.splitlines(), 1) for tok in line.split()
        ]
        self.pos = 0
        self.path = path

    def next(self, expected: str | None = None) -> str:
        if self.pos >= len(self.items):
            raise ImporterError(f"{self.path}: truncated BVH (ends while reading the hierarchy)")
        token, line = self.items[self.pos]
        self.pos += 1
        if expected is not None and token.upper() != expected.upper():
            raise ImporterError(f"{self.path}: line {line}: expected {expected!r}, got {token!r}")
        return token

    def number(self) -> float:
        token = self.next()
        try:
            return float(token)
        except ValueError:
            line = self.items[self.pos - 1][1]
            raise ImporterError(f"{self.path}: line {line}: {token!r} is not a number") from None


def _parse_joint(tokens: _Tokens, name: str, parent: int, joints: list[BvhJoint]) -> None:
    tokens.next("{")
    tokens.next("OFFSET")
    offset = np.array([tokens.number() for _ in range(3)])
    channels: tuple[str, ...] = ()
    index = len(joints)
    joints.append(BvhJoint(name, parent, offset, channels))
    while True:
        keyword = tokens.next()
        if keyword.upper() == "CHANNELS":
            count = int(tokens.number())
            channels = tuple(tokens.next() for _ in range(count))
            joints[index] = BvhJoint(name, parent, offset, channels)
        elif keyword.upper() == "JOINT":
            _parse_joint(tokens, tokens.next(), index, joints)
        elif keyword.upper() == "END":
            tokens.next("Site")
            tokens.next("{")
            tokens.next("OFFSET")
            for _ in range(3):
                tokens.number()
            tokens.next("}")
        elif keyword == "}":
            return
        else:
            line = tokens.items[tokens.pos - 1][1]
            raise ImporterError(f"{tokens.path}: line {line}: unexpected {keyword!r}")


def read_bvh(path: Path) -> BvhMotion:
    """Parse a BVH file.

    Raises:
        ImporterError: unreadable, malformed or truncated file (message names file and line).

    """
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ImporterError(f"{path}: cannot read ({exc})") from None
    tokens = _Tokens(text, path)
    tokens.next("HIERARCHY")
    tokens.next("ROOT")
    joints: list[BvhJoint] = []
    _parse_joint(tokens, tokens.next(), -1, joints)
    tokens.next("MOTION")
    tokens.next("Frames:")
    n_frames = int(tokens.number())
    tokens.next("Frame")
    tokens.next("Time:")
    frame_time_s = tokens.number()
    n_channels = sum(len(j.channels) for j in joints)
    numbers = [tok for tok, _ in tokens.items[tokens.pos :]]
    if n_frames <= 0 or frame_time_s <= 0:
        raise ImporterError(f"{path}: {n_frames} frames of {frame_time_s} s: nothing to import")
    if len(numbers) < n_frames * n_channels:
        raise ImporterError(
            f"{path}: truncated BVH: {len(numbers)} values for {n_frames} frames of "
            f"{n_channels} channels ({len(numbers) // max(n_channels, 1)} complete frames)"
        )
    try:
        values = np.array(numbers[: n_frames * n_channels], dtype=np.float64)
    except ValueError:
        raise ImporterError(f"{path}: non-numeric values in the MOTION section") from None
    return BvhMotion(joints, frame_time_s, values.reshape(n_frames, n_channels))


def forward_kinematics(motion: BvhMotion, rest: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Global positions and rotations of every joint in every frame.

    Args:
        motion: parsed file.
        rest: ignore the channels (the rest pose; one frame).

    Returns:
        ``(positions, rotations)``: (F, n_joints, 3) and (F, n_joints, 3, 3).

    """
    n_frames = 1 if rest else motion.values.shape[0]
    n = len(motion.joints)
    positions = np.zeros((n_frames, n, 3))
    rotations = np.tile(np.eye(3), (n_frames, n, 1, 1))
    column = 0
    for j, joint in enumerate(motion.joints):
        local_t = np.tile(joint.offset, (n_frames, 1))
        order, angles = "", []
        for name in joint.channels:
            values = np.zeros(n_frames) if rest else motion.values[:, column]
            column += 1
            axis = name[0].upper()
            if name.lower().endswith("position"):
                local_t[:, _AXES[axis]] += values
            else:
                order += axis
                angles.append(values)
        local_r = (
            Rotation.from_euler(order, np.stack(angles, axis=-1), degrees=True).as_matrix()
            if order
            else np.tile(np.eye(3), (n_frames, 1, 1))
        )
        if joint.parent < 0:
            positions[:, j], rotations[:, j] = local_t, local_r
        else:
            parent_r = rotations[:, joint.parent]
            positions[:, j] = positions[:, joint.parent] + np.einsum(
                "fij,fj->fi", parent_r, local_t
            )
            rotations[:, j] = parent_r @ local_r
    return positions, rotations


def load_mappings(path: str | Path | None = None) -> dict[str, dict[str, str]]:
    """Skeleton mappings: name -> role -> BVH joint (default: ``config/bvh_mappings.yaml``).

    Raises:
        ImporterError: the file is missing, not YAML, malformed, or a mapping lacks one of the
            :data:`ROLES`.

    """
    file = Path(path) if path else share_path("config", MAPPINGS_FILE)
    data = read_yaml_file(file, "skeleton mappings", ImporterError) or {}
    if not isinstance(data, Mapping):
        raise ImporterError(f"{file}: expected a mapping of skeleton names")
    mappings = {}
    for name, entry in data.items():
        joints = entry.get("joints") if isinstance(entry, Mapping) else None
        if not isinstance(joints, Mapping):
            raise ImporterError(f"{file}: skeleton {name!r} needs a 'joints' mapping")
        missing = [role for role in ROLES if role not in joints]
        if missing:
            raise ImporterError(f"{file}: skeleton {name!r} lacks roles {missing}")
        mappings[str(name)] = {role: str(joints[role]) for role in ROLES}
    return mappings


def _unwrap_finite(column: np.ndarray) -> np.ndarray:
    out = column.copy()
    finite = np.isfinite(out)
    out[finite] = np.unwrap(out[finite])
    return out


def retarget(
    motion: BvhMotion, mapping: Mapping[str, str], robot: RobotDescription, path: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pepper's angles for every BVH frame.

    Returns:
        ``(angles_rad, observed, head_roll_rad)``: (F, J), (F, J) bool, (F,).

    Raises:
        ImporterError: the mapping names joints that the file does not have.

    """
    try:
        idx = {role: motion.index(mapping[role]) for role in ROLES}
    except KeyError as exc:
        names = [j.name for j in motion.joints]
        raise ImporterError(
            f"{path}: no joint {exc.args[0]!r} for the skeleton mapping; the file has {names}"
        ) from None
    rest_p, _ = forward_kinematics(motion, rest=True)
    left = rest_p[0, idx["left_shoulder"]] - rest_p[0, idx["right_shoulder"]]
    rest_axes = upper_body.body_frame(
        left[None], np.zeros((1, 3)), (rest_p[0, idx["head"]] - rest_p[0, idx["pelvis"]])[None]
    )[0]
    positions, rotations = forward_kinematics(motion)
    chest = rotations[:, idx["torso"]] @ rest_axes  # (F, 3, 3) columns forward, left, up
    pelvis = rotations[:, idx["pelvis"]] @ rest_axes
    angles = np.full((positions.shape[0], robot.n_joints), np.nan)
    for side, prefix in (("left", "L"), ("right", "R")):
        arm = upper_body.arm_angles(
            positions[:, idx[f"{side}_shoulder"]],
            positions[:, idx[f"{side}_elbow"]],
            positions[:, idx[f"{side}_wrist"]],
            chest,
            side == "left",
        )
        for joint, values in arm.items():
            if prefix + joint in robot.names:
                angles[:, robot.names.index(prefix + joint)] = values
    head_body = np.swapaxes(chest, -1, -2) @ rotations[:, idx["head"]] @ rest_axes
    ypr = head_pose.body_rotation_to_angles(head_body)
    for k, name in enumerate(HEAD_JOINTS):
        angles[:, robot.names.index(name)] = ypr[:, k]
    if "HipRoll" in robot.names:
        spine = np.einsum("fji,fj->fi", pelvis, chest[:, :, 2])  # chest up in pelvis axes
        angles[:, robot.names.index("HipRoll")] = np.arctan2(-spine[:, 1], spine[:, 2])
    angles = np.stack([_unwrap_finite(c) for c in angles.T], axis=-1)
    return angles, np.isfinite(angles), _unwrap_finite(ypr[:, 2])


def import_bvh(
    path: Path,
    audio: np.ndarray,
    info: ClipInfo,
    robot: RobotDescription,
    mapping: Mapping[str, str],
    mirror: bool = False,
) -> tuple[Clip, dict[str, np.ndarray]]:
    """Import a BVH file with its audio as a clip (all 11 joints) plus extras (head roll).

    Args:
        path: the BVH file.
        audio: (n_samples,) 16 kHz mono float32; the first motion frame is at sample 0.
        info: the clip's metadata.
        robot: joint order, limits and neutral pose.
        mapping: role -> BVH joint name (one entry of :func:`load_mappings`).
        mirror: exchange left and right.

    Raises:
        ImporterError: malformed or truncated file, or joints missing for the mapping.

    """
    motion = read_bvh(path)
    angles, observed, roll = retarget(motion, mapping, robot, path)
    times = np.arange(motion.values.shape[0]) * motion.frame_time_s
    return assemble_clip(times, angles, observed, roll, audio, info, robot, mirror)
