"""Pepper's URDF and forward kinematics (ROS-free).

The URDF (``urdf/pepper.urdf``) is parsed with ``yourdfpy``; forward kinematics chains each
joint's origin and its rotation about its axis from the root link outwards. Angles are radians,
lengths metres, poses 4x4 homogeneous matrices in the root link's frame (``base_link``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.resources import share_path

if TYPE_CHECKING:
    import yourdfpy

DEFAULT_URDF_FILE = "pepper.urdf"
MOVABLE_TYPES = ("revolute", "continuous", "prismatic")


class KinematicsError(ConfigurationError):
    """The URDF is malformed or a joint configuration names unknown joints."""


def default_urdf_path() -> Path:
    """The packaged Pepper URDF (primitive shapes, see the comment at its top)."""
    return share_path("urdf", DEFAULT_URDF_FILE)


@dataclass(frozen=True)
class UrdfJoint:
    """One joint as the URDF states it (SI units; limits are 0 for fixed joints)."""

    name: str
    joint_type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) parent -> joint frame at zero position
    axis: np.ndarray  # (3,) unit axis in the joint frame
    lower_rad: float
    upper_rad: float
    max_velocity_rad_s: float

    @property
    def movable(self) -> bool:
        """Whether the joint has a position (revolute, continuous or prismatic)."""
        return self.joint_type in MOVABLE_TYPES

    def motion(self, position: float) -> np.ndarray:
        """(4, 4) transform of the joint's own motion at ``position`` (rad, or m if prismatic)."""
        transform = np.eye(4)
        if self.joint_type == "prismatic":
            transform[:3, 3] = self.axis * position
        elif self.movable:
            transform[:3, :3] = axis_angle_matrix(self.axis, position)
        return transform


def axis_angle_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues' formula)."""
    x, y, z = axis
    skew = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle_rad) * skew + (1.0 - np.cos(angle_rad)) * (skew @ skew)


class RobotKinematics:
    """A URDF's kinematic tree with forward kinematics for any joint configuration."""

    def __init__(self, urdf_path: str | Path | None = None) -> None:
        """Parse ``urdf_path`` (default: the packaged Pepper URDF).

        Raises:
            KinematicsError: the file does not parse or is not a single tree.
            FileNotFoundError: the file does not exist.

        """
        self.urdf_path = Path(urdf_path) if urdf_path else default_urdf_path()
        if not self.urdf_path.is_file():
            raise FileNotFoundError(f"URDF {self.urdf_path} not found")
        self.urdf_xml = self.urdf_path.read_text(encoding="utf-8")
        import yourdfpy  # local import: it pulls in trimesh (~0.7 s)

        try:
            model = yourdfpy.URDF.load(
                str(self.urdf_path), build_scene_graph=False, load_meshes=False
            )
        except Exception as exc:  # yourdfpy raises lxml and its own errors alike
            raise KinematicsError(f"{self.urdf_path}: cannot parse URDF ({exc})") from None
        self.name = model.robot.name
        self.link_names = tuple(link.name for link in model.robot.links)
        self.joints = _tree_order(
            [_joint_from_urdf(j) for j in model.robot.joints], self.link_names, self.urdf_path
        )
        self.root_link = self.joints[0].parent
        self._by_name = {j.name: j for j in self.joints}

    @property
    def movable_joint_names(self) -> tuple[str, ...]:
        """Names of the joints with a position, in tree order."""
        return tuple(j.name for j in self.joints if j.movable)

    def joint(self, name: str) -> UrdfJoint:
        """The joint called ``name``."""
        try:
            return self._by_name[name]
        except KeyError:
            raise KinematicsError(f"joint {name!r} is not in {self.urdf_path.name}") from None

    def default_positions(self) -> dict[str, float]:
        """Every movable joint at zero, moved inside its limits where zero is outside them."""
        return {
            j.name: float(np.clip(0.0, j.lower_rad, j.upper_rad)) for j in self.joints if j.movable
        }

    def resolve(self, positions: Mapping[str, float]) -> dict[str, float]:
        """Complete a partial configuration with :meth:`default_positions`.

        Raises:
            KinematicsError: ``positions`` names a joint that is not movable in this URDF.

        """
        full = self.default_positions()
        unknown = sorted(set(positions) - set(full))
        if unknown:
            raise KinematicsError(f"not movable joints of {self.name}: {unknown}")
        full.update({name: float(value) for name, value in positions.items()})
        return full

    def joint_transforms(self, positions: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Parent -> child transform of every joint (what /tf carries), keyed by joint name.

        Args:
            positions: joint name -> position (rad); joints left out stay at their default.

        """
        full = self.resolve(positions)
        return {j.name: j.origin @ j.motion(full.get(j.name, 0.0)) for j in self.joints}

    def link_poses(self, positions: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Pose of every link in the root link's frame, keyed by link name.

        Args:
            positions: joint name -> position (rad); joints left out stay at their default.

        """
        poses = {self.root_link: np.eye(4)}
        for name, local in self.joint_transforms(positions).items():
            joint = self._by_name[name]
            poses[joint.child] = poses[joint.parent] @ local
        return poses


def _joint_from_urdf(joint: yourdfpy.Joint) -> UrdfJoint:
    limit = joint.limit
    axis = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), dtype=float)
    origin = np.asarray(joint.origin if joint.origin is not None else np.eye(4), dtype=float)
    return UrdfJoint(
        name=joint.name,
        joint_type=joint.type,
        parent=joint.parent,
        child=joint.child,
        origin=origin,
        axis=axis / np.linalg.norm(axis),
        lower_rad=float(limit.lower) if limit is not None and limit.lower is not None else 0.0,
        upper_rad=float(limit.upper) if limit is not None and limit.upper is not None else 0.0,
        max_velocity_rad_s=(
            float(limit.velocity) if limit is not None and limit.velocity is not None else 0.0
        ),
    )


def _tree_order(
    joints: list[UrdfJoint], link_names: tuple[str, ...], source: Path
) -> tuple[UrdfJoint, ...]:
    """Sort joints parents first; reject anything that is not one tree over the links."""
    children = [j.child for j in joints]
    roots = [link for link in link_names if link not in children]
    if len(roots) != 1 or len(set(children)) != len(children):
        raise KinematicsError(f"{source}: links do not form one tree (roots {roots})")
    ordered: list[UrdfJoint] = []
    frontier = [roots[0]]
    while frontier:
        link = frontier.pop(0)
        for joint in joints:
            if joint.parent == link:
                ordered.append(joint)
                frontier.append(joint.child)
    if len(ordered) != len(joints):
        raise KinematicsError(f"{source}: some joints are not connected to {roots[0]}")
    return tuple(ordered)
