"""Pepper's URDF and forward kinematics (ROS-free).

The URDF (``urdf/pepper.urdf``) is read with the standard library's XML parser: its links, its
joints (origin, axis, limits) and its links' primitive collision shapes, nothing else (no meshes
are loaded, so reading costs no more memory than the file); ``test/test_kinematics.py`` checks
the joints against ``yourdfpy``'s reading and the forward kinematics against Pinocchio's.
Forward kinematics chains each joint's origin and its rotation about its axis from the root link
outwards. Angles are radians, lengths metres, poses 4x4 homogeneous matrices in the root link's
frame (``base_link``).
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.resources import share_path

DEFAULT_URDF_FILE = "pepper.urdf"
MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
JOINT_TYPES = (*MOVABLE_TYPES, "fixed", "floating", "planar")


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


@dataclass(frozen=True)
class UrdfCollision:
    """One ``<collision>`` shape of a link, as the URDF states it (metres).

    ``kind`` is the geometry's tag: ``box`` (``size`` = its three side lengths), ``cylinder``
    (radius, length; its axis is the shape frame's z), ``sphere`` (radius), or another tag
    (``mesh``) with no size: the file names it, but nothing here loads it.
    """

    link: str
    kind: str
    origin: np.ndarray  # (4, 4) link frame -> shape frame
    size: tuple[float, ...]


def skew_matrix(axis: np.ndarray) -> np.ndarray:
    """(3, 3) K with K v = axis x v."""
    x, y, z = axis
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def axis_angle_matrix(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues' formula)."""
    skew = skew_matrix(axis)
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
        try:
            root = ElementTree.fromstring(self.urdf_xml)
        except ElementTree.ParseError as exc:
            raise KinematicsError(f"{self.urdf_path}: cannot parse URDF ({exc})") from None
        if root.tag != "robot":
            raise KinematicsError(f"{self.urdf_path}: the root element is not <robot>")
        reader = _Reader(self.urdf_path)
        self.name = reader.attribute(root, "name")
        links = root.findall("link")
        self.link_names = tuple(reader.attribute(link, "name") for link in links)
        self.joints = _tree_order(
            [reader.joint(j) for j in root.findall("joint")], self.link_names, self.urdf_path
        )
        self.collisions = tuple(
            reader.collision(name, element)
            for name, link in zip(self.link_names, links, strict=True)
            for element in link.findall("collision")
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


class _Reader:
    """Reads the elements of one URDF file; every malformed value is a :class:`KinematicsError`."""

    def __init__(self, source: Path) -> None:
        self.source = source

    def error(self, what: str) -> KinematicsError:
        return KinematicsError(f"{self.source}: cannot parse URDF ({what})")

    def attribute(self, element: ElementTree.Element, name: str) -> str:
        value = element.get(name)
        if value is None:
            raise self.error(f"<{element.tag}> lacks its {name!r} attribute")
        return value

    def numbers(
        self, element: ElementTree.Element, name: str, count: int, default: str
    ) -> np.ndarray:
        text = element.get(name, default)
        try:
            values = np.array([float(v) for v in text.split()])
        except ValueError:
            raise self.error(f"<{element.tag} {name}={text!r}> is not numbers") from None
        if values.shape != (count,) or not np.isfinite(values).all():
            raise self.error(f"<{element.tag} {name}={text!r}> needs {count} finite numbers")
        return values

    def origin(self, parent: ElementTree.Element) -> np.ndarray:
        """(4, 4) of the ``<origin xyz rpy>`` in ``parent`` (identity when there is none).

        URDF's roll, pitch, yaw turn about the fixed x, y, z axes in that order:
        R = Rz(yaw) Ry(pitch) Rx(roll).
        """
        transform = np.eye(4)
        element = parent.find("origin")
        if element is None:
            return transform
        transform[:3, 3] = self.numbers(element, "xyz", 3, "0 0 0")
        roll, pitch, yaw = self.numbers(element, "rpy", 3, "0 0 0")
        axes = np.eye(3)
        transform[:3, :3] = (
            axis_angle_matrix(axes[2], yaw)
            @ axis_angle_matrix(axes[1], pitch)
            @ axis_angle_matrix(axes[0], roll)
        )
        return transform

    def joint(self, element: ElementTree.Element) -> UrdfJoint:
        name, joint_type = self.attribute(element, "name"), self.attribute(element, "type")
        if joint_type not in JOINT_TYPES:
            raise self.error(f"joint {name!r} has type {joint_type!r}")
        ends = []
        for tag in ("parent", "child"):
            end = element.find(tag)
            if end is None:
                raise self.error(f"joint {name!r} lacks its <{tag}>")
            ends.append(self.attribute(end, "link"))
        axis_element = element.find("axis")
        axis = (
            np.array([1.0, 0.0, 0.0])
            if axis_element is None
            else self.numbers(axis_element, "xyz", 3, "1 0 0")
        )
        norm = float(np.linalg.norm(axis))
        if norm == 0.0:
            raise self.error(f"joint {name!r} has a zero axis")
        limit = element.find("limit")
        bounds = [0.0, 0.0, 0.0]
        if limit is not None:
            for k, key in enumerate(("lower", "upper", "velocity")):
                bounds[k] = float(self.numbers(limit, key, 1, "0")[0])
        return UrdfJoint(
            name=name,
            joint_type=joint_type,
            parent=ends[0],
            child=ends[1],
            origin=self.origin(element),
            axis=axis / norm,
            lower_rad=bounds[0],
            upper_rad=bounds[1],
            max_velocity_rad_s=bounds[2],
        )

    def collision(self, link: str, element: ElementTree.Element) -> UrdfCollision:
        geometry = element.find("geometry")
        shape = None if geometry is None else next(iter(geometry), None)
        if shape is None:
            raise self.error(f"a <collision> of link {link!r} has no geometry")
        sizes = {"box": ("size", 3), "cylinder": ("radius", 1), "sphere": ("radius", 1)}
        size: tuple[float, ...] = ()
        if shape.tag in sizes:
            key, count = sizes[shape.tag]
            size = tuple(float(v) for v in self.numbers(shape, key, count, ""))
            if shape.tag == "cylinder":
                size = (*size, float(self.numbers(shape, "length", 1, "")[0]))
            if min(size) <= 0.0:
                raise self.error(f"a {shape.tag} of link {link!r} has size {size}")
        return UrdfCollision(link=link, kind=shape.tag, origin=self.origin(element), size=size)


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
