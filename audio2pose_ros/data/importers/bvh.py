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

Files are untrusted input: :func:`read_bvh` reads only a regular file of at most
:data:`MAX_BVH_BYTES`, as a stream; counts must be whole numbers, channels one of the six names,
the frame time a period between :data:`MIN_FRAME_TIME_S` and :data:`MAX_FRAME_TIME_S`, and the
hierarchy may nest to any depth. Every refusal is an :class:`ImporterError` naming the file.
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.data.importers import head_pose, upper_body
from audio2pose_ros.data.importers.common import HEAD_JOINTS, ImporterError, assemble_clip
from audio2pose_ros.files import open_bounded, read_yaml_file
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.description import RobotDescription

MAPPINGS_FILE = "bvh_mappings.yaml"
ROLES = (
    "pelvis", "torso", "head", "left_shoulder", "left_elbow", "left_wrist",
    "right_shoulder", "right_elbow", "right_wrist",
)  # fmt: skip
_AXES = {"X": 0, "Y": 1, "Z": 2}
CHANNELS = tuple(f"{axis}{kind}" for kind in ("position", "rotation") for axis in "xyz")
# A 10-minute take of a 70-joint skeleton at 60 frames/s is about 85 MB of text: room for 30 min
MAX_BVH_BYTES = 256 * 1024 * 1024
MIN_FRAME_TIME_S = 1e-4  # 10 000 frames/s, beyond any motion capture system
MAX_FRAME_TIME_S = 1.0  # 1 frame/s, below which nothing of a gesture is left
_DIGITS = re.compile(r"[0-9]{1,12}")


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
    """Whitespace-separated tokens of a text stream, read line by line, for the hierarchy.

    Line numbers are kept for error messages; :meth:`rest` hands over what follows the last
    token read (the MOTION values) one line at a time, so the file is never held whole.
    """

    def __init__(self, lines: Iterator[str], path: Path) -> None:
        self.lines = lines
        self.path = path
        self.line = 0  # number of the line the last token came from (1-based)
        self.words: list[str] = []
        self.at = 0  # next token in self.words

    def next(self, expected: str | None = None) -> str:
        while self.at >= len(self.words):
            text = next(self.lines, None)
            if text is None:
                raise ImporterError(
                    f"{self.path}: truncated BVH (ends while reading the hierarchy)"
                )
            self.line += 1
            self.words, self.at = text.split(), 0
        token = self.words[self.at]
        self.at += 1
        if expected is not None and token.upper() != expected.upper():
            raise ImporterError(
                f"{self.path}: line {self.line}: expected {expected!r}, got {token!r}"
            )
        return token

    def number(self) -> float:
        token = self.next()
        try:
            return float(token)
        except ValueError:
            raise ImporterError(
                f"{self.path}: line {self.line}: {token!r} is not a number"
            ) from None

    def count(self, what: str, high: int) -> int:
        """A whole number in [0, ``high``], in decimal digits (no sign, point or exponent)."""
        token = self.next()
        if not _DIGITS.fullmatch(token) or int(token) > high:
            raise ImporterError(
                f"{self.path}: line {self.line}: {what} {token!r} is not a whole number in "
                f"[0, {high}]"
            )
        return int(token)

    def rest(self) -> Iterator[tuple[int, list[str]]]:
        """``(line number, tokens)`` of the rest of the current line, then of each next line."""
        yield self.line, self.words[self.at :]
        for text in self.lines:
            self.line += 1
            yield self.line, text.split()


def _channels(tokens: _Tokens) -> tuple[str, ...]:
    """The names after ``CHANNELS``: each of Xposition ... Zrotation at most once."""
    channels = tuple(tokens.next() for _ in range(tokens.count("CHANNELS count", len(CHANNELS))))
    for k, name in enumerate(channels):
        if name.lower() not in CHANNELS:
            raise ImporterError(
                f"{tokens.path}: line {tokens.line}: unknown channel {name!r} (expected "
                "Xposition, Yposition, Zposition, Xrotation, Yrotation or Zrotation)"
            )
        if name.lower() in (c.lower() for c in channels[:k]):
            raise ImporterError(f"{tokens.path}: line {tokens.line}: channel {name!r} twice")
    return channels


def _parse_hierarchy(tokens: _Tokens) -> list[BvhJoint]:
    """Joints of the HIERARCHY section in file order (a parent before its children).

    Nesting is followed with a stack of open joints, not recursion, so any depth is read.
    """
    tokens.next("HIERARCHY")
    tokens.next("ROOT")
    joints: list[BvhJoint] = []
    open_joints: list[int] = []

    def begin(name: str, parent: int) -> None:
        tokens.next("{")
        tokens.next("OFFSET")
        offset = np.array([tokens.number() for _ in range(3)])
        joints.append(BvhJoint(name, parent, offset, ()))
        open_joints.append(len(joints) - 1)

    begin(tokens.next(), -1)
    while open_joints:
        index = open_joints[-1]
        keyword = tokens.next()
        if keyword.upper() == "CHANNELS":
            joints[index] = replace(joints[index], channels=_channels(tokens))
        elif keyword.upper() == "JOINT":
            begin(tokens.next(), index)
        elif keyword.upper() == "END":
            tokens.next("Site")
            tokens.next("{")
            tokens.next("OFFSET")
            for _ in range(3):
                tokens.number()
            tokens.next("}")
        elif keyword == "}":
            open_joints.pop()
        else:
            raise ImporterError(f"{tokens.path}: line {tokens.line}: unexpected {keyword!r}")
    return joints


def _motion_values(tokens: _Tokens, n_frames: int, n_channels: int) -> np.ndarray:
    """The (n_frames, n_channels) values of the MOTION section, parsed line by line."""
    needed = n_frames * n_channels
    chunks: list[np.ndarray] = []
    count = 0
    for line, words in tokens.rest():
        if count >= needed:
            break
        try:
            values = np.array(words[: needed - count], dtype=np.float64)
        except ValueError:
            raise ImporterError(
                f"{tokens.path}: line {line}: non-numeric values in the MOTION section"
            ) from None
        chunks.append(values)
        count += values.size
    if count < needed:
        raise ImporterError(
            f"{tokens.path}: truncated BVH: {count} values for {n_frames} frames of "
            f"{n_channels} channels ({count // n_channels} complete frames)"
        )
    return np.concatenate(chunks).reshape(n_frames, n_channels)


def read_bvh(path: Path) -> BvhMotion:
    """Parse a BVH file (a regular file of at most :data:`MAX_BVH_BYTES`, read as a stream).

    Raises:
        ImporterError: not a regular file, too large, unreadable, malformed or truncated: a
            count that is not a whole number, an unknown channel, no channel at all, no frame,
            or a frame time outside [:data:`MIN_FRAME_TIME_S`, :data:`MAX_FRAME_TIME_S`]
            (the message names the file, and the line where it helps).

    """
    with open_bounded(path, "BVH", ImporterError, MAX_BVH_BYTES) as raw:
        text = io.TextIOWrapper(raw, encoding="utf-8", errors="replace")
        tokens = _Tokens(iter(text), path)
        try:
            joints = _parse_hierarchy(tokens)
            n_channels = sum(len(j.channels) for j in joints)
            if n_channels == 0:
                raise ImporterError(f"{path}: no CHANNELS in the hierarchy: no motion to import")
            tokens.next("MOTION")
            tokens.next("Frames:")
            n_frames = tokens.count("Frames:", MAX_BVH_BYTES // 2)  # a value takes 2 bytes or more
            tokens.next("Frame")
            tokens.next("Time:")
            frame_time_s = tokens.number()
            if n_frames == 0:
                raise ImporterError(f"{path}: 0 frames: nothing to import")
            if not MIN_FRAME_TIME_S <= frame_time_s <= MAX_FRAME_TIME_S:  # NaN included
                raise ImporterError(
                    f"{path}: line {tokens.line}: Frame Time {frame_time_s:g} s is not a period "
                    f"in [{MIN_FRAME_TIME_S:g}, {MAX_FRAME_TIME_S:g}] s"
                )
            values = _motion_values(tokens, n_frames, n_channels)
        except OSError as exc:
            raise ImporterError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return BvhMotion(joints, frame_time_s, values)


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
