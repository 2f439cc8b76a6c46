"""Pepper's URDF and forward kinematics (ROS-free).

The URDF (``urdf/pepper.urdf``) is read with ``urdf_parser_py`` (PyPI ``urdfdom-py``, ROS's own
URDF parser): its links, its joints (origin, axis, limits) and its links' primitive collision
shapes, each value checked here (finite, sizes positive, one tree); no mesh is loaded, so
reading costs little memory (about 4 MB for the parser, against 112 MB for a parser that loads
meshes; none in a node process, where a child process parses: see
:mod:`~audio2pose_ros.robot.urdf_outline`). ``test/test_kinematics.py`` checks the forward
kinematics against Pinocchio's.
Forward kinematics chains each joint's origin and its rotation about its axis from the root link
outwards: :meth:`RobotKinematics.link_poses` for one configuration of every joint, and
:class:`DrivenFrames` for many poses of a few joints at once (the body models' kinematics: the
capsules of body-aware sampling and the exact shapes of the self-collision guard). Angles are
radians, lengths metres, poses 4x4 homogeneous matrices in the root link's frame
(``base_link``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.resources import share_path
from audio2pose_ros.robot.urdf_outline import UrdfParseError, read_outline

DEFAULT_URDF_FILE = "pepper.urdf"
MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
JOINT_TYPES = (*MOVABLE_TYPES, "fixed", "floating", "planar")
_SIN_COS_PHASE = np.array([0.0, np.pi / 2])  # sin(q + pi / 2) = cos q
BLAS_BLOCK_ELEMENTS = 1 << 16  # products of rows x inner x columns up to this stay on one thread


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


def blocked_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` in blocks of rows small enough for one thread of OpenBLAS.

    OpenBLAS splits a larger product over its threads, which it starts at import, one per core:
    pinned to one core (as the bench and a real-time node are), the product then waits for
    them to take turns, up to tens of milliseconds for a (500, 11) x (11, 145) one.
    """
    rows = max(1, BLAS_BLOCK_ELEMENTS // max(1, a.shape[1] * b.shape[1]))
    if len(a) <= rows:
        return a @ b
    return np.vstack([a[i : i + rows] @ b for i in range(0, len(a), rows)])


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
        robot = _parse(self.urdf_xml, self.urdf_path)
        reader = _Reader(self.urdf_path)
        self.name = str(robot["name"])
        links = robot["links"]
        self.link_names = tuple(str(link["name"]) for link in links)
        self.joints = _tree_order(
            [reader.joint(j) for j in robot["joints"]], self.link_names, self.urdf_path
        )
        self.collisions = tuple(
            reader.collision(link["name"], collision)
            for link in links
            for collision in link["collisions"]
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


def _parse(urdf_xml: str, source: Path) -> dict[str, Any]:
    """The parser's outline of ``urdf_xml`` (:mod:`~audio2pose_ros.robot.urdf_outline`).

    Raises:
        KinematicsError: the text is not a URDF the parser can read.
    """
    try:
        return read_outline(urdf_xml)
    except UrdfParseError as exc:
        raise KinematicsError(f"{source}: cannot parse URDF ({exc})") from None


class _Reader:
    """Checks the values of one parsed URDF; every malformed one is a :class:`KinematicsError`."""

    def __init__(self, source: Path) -> None:
        self.source = source

    def error(self, what: str) -> KinematicsError:
        return KinematicsError(f"{self.source}: cannot parse URDF ({what})")

    def numbers(self, values: Any, what: str, count: int) -> np.ndarray:
        try:
            array = np.array([float(v) for v in values], dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(f"{what} {values!r} is not numbers") from None
        if array.shape != (count,) or not np.isfinite(array).all():
            raise self.error(f"{what} {values!r} needs {count} finite numbers")
        return array

    def origin(self, pose: Mapping[str, Any] | None, what: str) -> np.ndarray:
        """(4, 4) of an ``<origin xyz rpy>`` (identity when there is none).

        URDF's roll, pitch, yaw turn about the fixed x, y, z axes in that order:
        R = Rz(yaw) Ry(pitch) Rx(roll).
        """
        transform = np.eye(4)
        if pose is None:
            return transform
        transform[:3, 3] = self.numbers(pose["xyz"] or [0, 0, 0], f"{what} origin xyz", 3)
        roll, pitch, yaw = self.numbers(pose["rpy"] or [0, 0, 0], f"{what} origin rpy", 3)
        axes = np.eye(3)
        transform[:3, :3] = (
            axis_angle_matrix(axes[2], yaw)
            @ axis_angle_matrix(axes[1], pitch)
            @ axis_angle_matrix(axes[0], roll)
        )
        return transform

    def joint(self, joint: Mapping[str, Any]) -> UrdfJoint:
        name, joint_type = joint["name"], joint["type"]
        if joint_type not in JOINT_TYPES:
            raise self.error(f"joint {name!r} has type {joint_type!r}")
        if not (joint["parent"] and joint["child"]):
            raise self.error(f"joint {name!r} lacks its <parent> or <child>")
        axis = self.numbers(
            [1.0, 0.0, 0.0] if joint["axis"] is None else joint["axis"], f"joint {name!r} axis", 3
        )
        norm = float(np.linalg.norm(axis))
        if norm == 0.0:
            raise self.error(f"joint {name!r} has a zero axis")
        limit = joint["limit"]
        bounds = (
            [0.0, 0.0, 0.0]
            if limit is None
            else self.numbers(
                [limit["lower"] or 0.0, limit["upper"] or 0.0, limit["velocity"] or 0.0],
                f"joint {name!r} limit",
                3,
            )
        )
        return UrdfJoint(
            name=name,
            joint_type=joint_type,
            parent=joint["parent"],
            child=joint["child"],
            origin=self.origin(joint["origin"], f"joint {name!r}"),
            axis=axis / norm,
            lower_rad=float(bounds[0]),
            upper_rad=float(bounds[1]),
            max_velocity_rad_s=float(bounds[2]),
        )

    def collision(self, link: str, collision: Mapping[str, Any]) -> UrdfCollision:
        geometry = collision["geometry"]
        if geometry is None:
            raise self.error(f"a <collision> of link {link!r} has no geometry")
        kind = geometry["kind"]
        what = f"a {kind} of link {link!r}"
        size: tuple[float, ...] = ()
        if kind == "box":
            size = tuple(float(v) for v in self.numbers(geometry["size"], f"{what} size", 3))
        elif kind == "sphere":
            size = (float(self.numbers([geometry["radius"]], f"{what} radius", 1)[0]),)
        elif kind == "cylinder":
            size = tuple(
                float(v)
                for v in self.numbers([geometry["radius"], geometry["length"]], f"{what} size", 2)
            )
        if size and min(size) <= 0.0:
            raise self.error(f"{what} has size {size}")
        return UrdfCollision(
            link=link, kind=kind, origin=self.origin(collision["origin"], what), size=size
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


class DrivenFrames:
    """Forward kinematics over a few revolute joints (the driven ones), all poses at once.

    Frame 0 is the root link's; frame k > 0 is the k-th driven joint's (in tree order). The
    other joints are held at zero, so each driven joint's transform from its parent frame is a
    constant C (:attr:`placements`) times its own rotation, by Rodrigues' formula
    C (I + sin q K + (1 - cos q) K^2) = (C + C K^2) + sin q (C K) - cos q (C K^2).
    A frame's placement is its parent frame's times its own transform, so :meth:`frames` places
    every frame with one stacked product per level below the root, and :meth:`place` frames
    fixed in them (the exact model's shapes); :meth:`carry` carries points (the capsules' ends)
    along their chains of transforms, root first, with matrix-vector products. All of them
    multiply the same matrices in the same order, root first.

    Attributes:
        frame_of: each link's frame (the driven joint that last moves it, 0 for none).
        link_in_frame: each link's (4, 4) placement in its frame.
        joint_names: the driven joints in tree order (frame k is joint k - 1's).
        placements: (D, 4, 4) each driven joint's placement in its parent frame at zero.
        frame_chains: per frame, the driven joints (indices into ``joint_names``) that move
            it, root first.
    """

    def __init__(self, kinematics: RobotKinematics, names: Sequence[str]) -> None:
        """Frames for the revolute joints ``names`` of ``kinematics``; poses in that order.

        Raises:
            KinematicsError: a name is not a revolute joint of the URDF.
        """
        revolute = {j.name for j in kinematics.joints if j.joint_type in ("revolute", "continuous")}
        unknown = [name for name in names if name not in revolute]
        if unknown:
            raise KinematicsError(f"not revolute joints of {kinematics.name}: {unknown}")
        links: dict[str, tuple[int, np.ndarray]] = {kinematics.root_link: (0, np.eye(4))}
        chains: list[list[int]] = [[]]  # per frame: its driven joints, root first
        terms: list[np.ndarray] = []  # per driven joint: (3, 4, 4) C + C K^2, C K, -C K^2
        index: list[int] = []  # per driven joint: its index in the poses
        placements: list[np.ndarray] = []
        driven: list[str] = []
        for joint in kinematics.joints:
            frame, place = links[joint.parent]
            constant = place @ joint.origin
            if joint.name in names:
                cross = np.zeros((4, 4))
                cross[:3, :3] = skew_matrix(joint.axis)
                square = constant @ cross @ cross
                terms.append(np.stack([constant + square, constant @ cross, -square]))
                index.append(list(names).index(joint.name))
                placements.append(constant)
                driven.append(joint.name)
                chains.append([*chains[frame], len(terms) - 1])
                links[joint.child] = (len(chains) - 1, np.eye(4))
            else:
                links[joint.child] = (frame, constant @ joint.motion(0.0))
        self.frame_of = {link: frame for link, (frame, _) in links.items()}
        self.link_in_frame = {link: place for link, (_, place) in links.items()}
        self.joint_names = tuple(driven)
        self.placements = np.array(placements).reshape(-1, 4, 4)
        self.frame_chains = tuple(tuple(chain) for chain in chains)
        # Per frame, as frames are numbered (frame 0: the identity, its angle any, its terms 0):
        # the flat (16,) constant term, and the (2 (D + 1), 16 (D + 1)) matrix that maps the
        # frames' sines and cosines, interleaved, to their flat sine and cosine terms.
        frames = len(terms) + 1
        self._constant = np.concatenate([np.eye(4).ravel(), *(term[0].ravel() for term in terms)])
        trig = np.zeros((frames, 2, frames, 16))
        for frame, term in enumerate(terms, start=1):
            trig[frame, :, frame] = term[1:].reshape(2, 16)
        self._trig = trig.reshape(2 * frames, 16 * frames)
        self._angle_index = np.repeat([0, *index], 2)  # each frame's angle, twice
        self._phase = np.tile(_SIN_COS_PHASE, frames)
        depth = max(len(chain) for chain in chains)
        # per frame, the frames whose transforms carry it to the root, padded with frame 0's
        self._chains = np.array(
            [[0] * (depth - len(chain)) + [j + 1 for j in chain] for chain in chains], dtype=np.intp
        ).reshape(len(chains), depth)
        # the frames k levels below the root, from k = 2 on, in runs of consecutive numbers (a
        # slice of them), each with their parents (one level up)
        self._levels: tuple[tuple[slice | np.ndarray, slice], ...] = tuple(
            (
                _as_index([chains.index(chains[frame][:-1]) for frame in run]),
                slice(run[0], run[-1] + 1),
            )
            for level in range(2, depth + 1)
            for run in _runs([frame for frame, chain in enumerate(chains) if len(chain) == level])
        )

    def _local(self, poses: np.ndarray) -> np.ndarray:
        """(N, D + 1, 4, 4) each frame's transform from its parent frame (frame 0's: identity).

        One product maps every frame's sine and cosine to its terms: for one pose the numpy
        calls, not the arithmetic, are the cost, so there are few.
        """
        trig = poses.take(self._angle_index, axis=1)  # (N, 2 (D + 1)): q, q + pi / 2 per frame
        trig += self._phase
        np.sin(trig, out=trig)  # sin q, cos q
        local = blocked_product(trig, self._trig)
        local += self._constant
        return local.reshape(len(poses), -1, 4, 4)

    def frames(self, poses: np.ndarray) -> np.ndarray:
        """(N, D + 1, 4, 4) root-frame placements of every frame in N poses.

        A frame's placement is its parent's times its own transform, the root's children first:
        one stacked product per level of the chains (the same products, in the same order, as
        chaining each frame's transforms from the root).
        """
        placed = self._local(poses)
        for parents, frames in self._levels:
            placed[:, frames] = placed[:, parents] @ placed[:, frames]
        return placed

    def place(self, poses: np.ndarray, frames: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """(N, P, 4, 4) root-frame placements of P frames fixed in driven ``frames``, in N poses.

        ``offsets`` (P, 4, 4) are their placements in those frames.
        """
        return np.asarray(self.frames(poses)[:, frames] @ offsets)

    def placer(self, frames: np.ndarray, offsets: np.ndarray) -> FramePlacer:
        """A :class:`FramePlacer` of :meth:`place`'s frames, one pose at a time."""
        return FramePlacer(self, frames, offsets)

    def carry(self, poses: np.ndarray, chains: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(N, P, 4) root-frame positions of P homogeneous points (P, 4) fixed in frames.

        ``chains`` is :meth:`chains` of the points' frames. Matrix-vector products only
        (numpy's stacked products of so many small matrices cost several times more than the
        arithmetic).
        """
        steps = self._local(poses)[:, chains]  # (N, P, depth, 4, 4)
        depth = chains.shape[1]
        carried = np.einsum("npab,pb->npa", steps[:, :, depth - 1], points)
        for level in range(depth - 2, -1, -1):
            carried = np.einsum("npab,npb->npa", steps[:, :, level], carried)
        return np.asarray(carried)

    def chains(self, frames: np.ndarray) -> np.ndarray:
        """(P, depth) frames (padded with frame 0's identity) that carry points in ``frames``."""
        return np.asarray(self._chains[frames])


class FramePlacer:
    """:meth:`DrivenFrames.place` of fixed frames for one pose at a time, into reused arrays.

    The same products in the same order, so the same placements to the last bit; for one pose
    numpy's calls, not the arithmetic, are the cost, and this makes about a dozen (no array
    is allocated, no view made but the parents' of each level). Each call overwrites
    :attr:`placed`; an instance serves one thread.

    Attributes:
        placed: (P, 4, 4) the frames' root-frame placements in the last pose placed.
    """

    def __init__(self, driven: DrivenFrames, frames: np.ndarray, offsets: np.ndarray) -> None:
        """Place the frames fixed at ``offsets`` (P, 4, 4) in driven ``frames`` (P,)."""
        self._driven = driven
        self._frames = np.asarray(frames, dtype=np.intp)
        self._offsets = np.asarray(offsets, dtype=np.float64)
        count = len(driven.frame_chains)
        self._trig = np.empty(len(driven._angle_index))
        self._local = np.empty((count, 4, 4))  # each frame's transform from its parent frame
        self._flat = self._local.reshape(-1)
        self._placed = np.empty((count, 4, 4))  # each frame's root-frame placement
        self._levels = [
            (parents, self._local[frames], self._placed[frames])
            for parents, frames in driven._levels
        ]
        self.placed = np.zeros((len(self._frames), 4, 4))

    def place(self, pose: np.ndarray) -> np.ndarray:
        """:attr:`placed` in the (n_joints,) ``pose``."""
        driven, trig, placed = self._driven, self._trig, self._placed
        np.take(pose, driven._angle_index, out=trig, mode="clip")  # valid: no buffer
        trig += driven._phase
        np.sin(trig, out=trig)
        np.matmul(trig, driven._trig, out=self._flat)
        self._flat += driven._constant
        np.copyto(placed, self._local)
        for parents, local, out in self._levels:
            np.matmul(placed[parents], local, out=out)
        np.matmul(placed.take(self._frames, axis=0), self._offsets, out=self.placed)
        return self.placed


def _runs(indices: list[int]) -> list[list[int]]:
    """Ascending ``indices`` cut into runs of consecutive numbers."""
    runs: list[list[int]] = []
    for index in indices:
        if runs and runs[-1][-1] + 1 == index:
            runs[-1].append(index)
        else:
            runs.append([index])
    return runs


def _as_index(indices: list[int]) -> slice | np.ndarray:
    """``indices`` as a slice where they are consecutive (a view, not a copy), else an array."""
    if indices == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return np.array(indices)
