"""The robot description: driven joints, their order, limits and neutral pose.

One YAML file (``config/pepper_robot.yaml``) is the single source of truth; nodes, models,
training, the URDF check and the tests all read it through :func:`load_robot`. Angles are radians,
velocities rad/s, accelerations rad/s^2.

A description is validated when it is loaded, whatever its source (file or checkpoint header):
every field present with its type (numbers as YAML numbers, not strings), limits finite,
``min_rad < max_rad``, the neutral pose inside, velocity and acceleration limits positive and
finite, joint names unique, at most :data:`MAX_JOINTS` joints and a file of at most
:data:`MAX_FILE_BYTES`. Any refusal is a :class:`RobotDescriptionError` (a
:class:`~audio2pose_ros.errors.ConfigurationError`) naming the file, the joint and the field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.files import read_yaml_file
from audio2pose_ros.resources import share_path

DEFAULT_ROBOT_FILE = "pepper_robot.yaml"
JOINT_GROUPS = ("head", "arms", "hip")
MAX_FILE_BYTES = 1 << 20  # a robot description YAML; Pepper's is 2 KB
MAX_JOINTS = 64
_NUMBER_FIELDS = (
    "min_rad",
    "max_rad",
    "max_velocity_rad_s",
    "max_acceleration_rad_s2",
    "neutral_rad",
)


class RobotDescriptionError(ConfigurationError):
    """A robot description file is missing fields or holds inconsistent values."""


@dataclass(frozen=True)
class JointLimits:
    """Limits and neutral position of one joint (all SI units)."""

    name: str
    group: str
    min_rad: float
    max_rad: float
    max_velocity_rad_s: float
    max_acceleration_rad_s2: float
    neutral_rad: float

    def __post_init__(self) -> None:
        """Reject limits that cannot be satisfied, naming the joint and the values."""
        for field in _NUMBER_FIELDS:
            if not math.isfinite(getattr(self, field)):
                raise RobotDescriptionError(
                    f"joint {self.name}: {field} {getattr(self, field)} is not finite"
                )
        if self.group not in JOINT_GROUPS:
            raise RobotDescriptionError(
                f"joint {self.name}: group {self.group!r} is not one of {JOINT_GROUPS}"
            )
        if not self.min_rad < self.max_rad:
            raise RobotDescriptionError(
                f"joint {self.name}: min_rad {self.min_rad} must be below max_rad {self.max_rad}"
            )
        if not self.min_rad <= self.neutral_rad <= self.max_rad:
            raise RobotDescriptionError(
                f"joint {self.name}: neutral_rad {self.neutral_rad} is outside "
                f"[{self.min_rad}, {self.max_rad}]"
            )
        if self.max_velocity_rad_s <= 0 or self.max_acceleration_rad_s2 <= 0:
            raise RobotDescriptionError(
                f"joint {self.name}: velocity and acceleration limits must be positive, got "
                f"{self.max_velocity_rad_s} rad/s and {self.max_acceleration_rad_s2} rad/s^2"
            )


@dataclass(frozen=True)
class RobotDescription:
    """An ordered set of driven joints; the order is the model's output order (seed 003 Table 3.1).

    Array properties are read-only float64 vectors in joint order.
    """

    name: str
    joints: tuple[JointLimits, ...]

    def __post_init__(self) -> None:
        """Reject empty descriptions and duplicated joint names."""
        if not self.joints:
            raise RobotDescriptionError(f"robot {self.name}: no joints")
        if len(self.joints) > MAX_JOINTS:
            raise RobotDescriptionError(
                f"robot {self.name}: {len(self.joints)} joints, at most {MAX_JOINTS} allowed"
            )
        names = [j.name for j in self.joints]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise RobotDescriptionError(f"robot {self.name}: duplicated joints {duplicates}")

    def _vector(self, field: str) -> np.ndarray:
        """The joints' ``field`` as a read-only vector, built once per description.

        The streaming path asks for the limits at every frame; the description is frozen, so
        each vector is kept in the instance's own dictionary on first use.
        """
        cache: dict[str, np.ndarray] = self.__dict__.setdefault("_vectors", {})
        values = cache.get(field)
        if values is None:
            values = np.array([getattr(j, field) for j in self.joints], dtype=np.float64)
            values.flags.writeable = False
            cache[field] = values
        return values

    @property
    def names(self) -> tuple[str, ...]:
        """Joint names in model order."""
        return tuple(j.name for j in self.joints)

    @property
    def n_joints(self) -> int:
        """Number of driven joints (11 for Pepper)."""
        return len(self.joints)

    @property
    def lower_rad(self) -> np.ndarray:
        """Lower position limits."""
        return self._vector("min_rad")

    @property
    def upper_rad(self) -> np.ndarray:
        """Upper position limits."""
        return self._vector("max_rad")

    @property
    def max_velocity_rad_s(self) -> np.ndarray:
        """Velocity limits."""
        return self._vector("max_velocity_rad_s")

    @property
    def max_acceleration_rad_s2(self) -> np.ndarray:
        """Acceleration limits."""
        return self._vector("max_acceleration_rad_s2")

    @property
    def neutral_rad(self) -> np.ndarray:
        """Neutral (rest) pose."""
        return self._vector("neutral_rad")

    def group_mask(self, group: str) -> np.ndarray:
        """Boolean mask of the joints in ``group`` ('head', 'arms' or 'hip')."""
        if group not in JOINT_GROUPS:
            raise ValueError(f"unknown joint group {group!r}; expected one of {JOINT_GROUPS}")
        return np.array([j.group == group for j in self.joints])

    def normalize(self, angles_rad: np.ndarray) -> np.ndarray:
        """Map angles to [0, 1] by each joint's range: seed 003 eq. 3.14, nu(theta).

        Args:
            angles_rad: (..., n_joints) angles in radians.

        Returns:
            Array of the same shape; values inside the limits land in [0, 1].

        """
        return (np.asarray(angles_rad) - self.lower_rad) / (self.upper_rad - self.lower_rad)

    def denormalize(self, unit: np.ndarray) -> np.ndarray:
        """Invert :meth:`normalize` (seed 003 section 3.4.2, nu^-1).

        Written as ``(1 - u) lower + u upper`` so that 0 and 1 give the limits exactly (the form
        ``lower + u (upper - lower)`` can land one rounding step above ``upper``).
        """
        u = np.asarray(unit)
        return (1.0 - u) * self.lower_rad + u * self.upper_rad

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form, stored in checkpoints so a model knows the robot it was trained for."""
        return {
            "robot": self.name,
            "joints": [
                {
                    "name": j.name,
                    "group": j.group,
                    "min_rad": j.min_rad,
                    "max_rad": j.max_rad,
                    "max_velocity_rad_s": j.max_velocity_rad_s,
                    "max_acceleration_rad_s2": j.max_acceleration_rad_s2,
                    "neutral_rad": j.neutral_rad,
                }
                for j in self.joints
            ],
        }

    @classmethod
    def from_dict(cls, data: object, source: str = "<dict>") -> RobotDescription:
        """Build a validated description from :meth:`to_dict` output or the YAML file's content.

        Raises:
            RobotDescriptionError: a field is missing or has the wrong type, or the limits are
                inconsistent; the message names ``source``, the joint and the field.
        """
        if not isinstance(data, Mapping):
            raise RobotDescriptionError(
                f"{source}: expected a mapping with 'robot' and 'joints', got {type(data).__name__}"
            )
        name, joints = data.get("robot"), data.get("joints")
        if not isinstance(name, str) or not name:
            raise RobotDescriptionError(f"{source}: field robot must be a non-empty string")
        if not isinstance(joints, list):
            raise RobotDescriptionError(f"{source}: field joints must be a list of joints")
        if len(joints) > MAX_JOINTS:
            raise RobotDescriptionError(
                f"{source}: {len(joints)} joints, at most {MAX_JOINTS} allowed"
            )
        try:
            return cls(
                name=name,
                joints=tuple(
                    _joint_from_mapping(entry, f"{source}: joints[{i}]")
                    for i, entry in enumerate(joints)
                ),
            )
        except RobotDescriptionError as exc:
            message = str(exc)
            raise RobotDescriptionError(
                message if message.startswith(source) else f"{source}: {message}"
            ) from None

    def differences(self, other: RobotDescription, tolerance: float = 1e-6) -> list[str]:
        """List, in words, how ``other`` differs in joint order and position limits.

        Only what a model depends on is compared: the joint order and the position ranges used
        for [0, 1] normalisation. Velocity, acceleration and neutral pose may differ freely.
        """
        if self.names != other.names:
            return [f"joint order {list(other.names)} != {list(self.names)}"]
        problems = []
        for mine, theirs in zip(self.joints, other.joints, strict=True):
            if abs(mine.min_rad - theirs.min_rad) > tolerance or (
                abs(mine.max_rad - theirs.max_rad) > tolerance
            ):
                problems.append(
                    f"{mine.name} range [{theirs.min_rad}, {theirs.max_rad}] != "
                    f"[{mine.min_rad}, {mine.max_rad}]"
                )
        return problems


def _joint_from_mapping(entry: object, where: str) -> JointLimits:
    """One joint from its mapping, every field checked for presence and type."""
    if not isinstance(entry, Mapping):
        raise RobotDescriptionError(f"{where}: expected a mapping, got {type(entry).__name__}")
    label = f"{where} ({entry['name']})" if isinstance(entry.get("name"), str) else where
    values: dict[str, Any] = {}
    for field in ("name", "group", *_NUMBER_FIELDS):
        if field not in entry:
            raise RobotDescriptionError(f"{label}: field {field} is missing")
        value = entry[field]
        if field in _NUMBER_FIELDS:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise RobotDescriptionError(
                    f"{label}: field {field} must be a number, got {value!r:.40}"
                )
            values[field] = float(value)
        elif not isinstance(value, str) or not value:
            raise RobotDescriptionError(
                f"{label}: field {field} must be a non-empty string, got {value!r:.40}"
            )
        else:
            values[field] = value
    unknown = sorted(str(k) for k in entry if k not in values)
    if unknown:
        raise RobotDescriptionError(f"{label}: unknown fields {unknown[:5]}")
    return JointLimits(
        name=values["name"],
        group=values["group"],
        min_rad=values["min_rad"],
        max_rad=values["max_rad"],
        max_velocity_rad_s=values["max_velocity_rad_s"],
        max_acceleration_rad_s2=values["max_acceleration_rad_s2"],
        neutral_rad=values["neutral_rad"],
    )


def load_robot(path: str | Path | None = None) -> RobotDescription:
    """Load and validate a robot description YAML; ``None`` or ``""`` loads the packaged Pepper.

    Raises:
        RobotDescriptionError: the file is missing, unreadable, larger than
            :data:`MAX_FILE_BYTES`, not YAML, malformed, or its limits are inconsistent (the
            message names the file and the field).

    """
    file = Path(path) if path else share_path("config", DEFAULT_ROBOT_FILE)
    data = read_yaml_file(file, "robot description", RobotDescriptionError, MAX_FILE_BYTES)
    return RobotDescription.from_dict(data, source=str(file))
