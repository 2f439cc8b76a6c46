"""Pepper's body as collision geometry: how close the arms come to the body and to each other.

The geometry is the URDF's ``<collision>`` shapes (``urdf/pepper.urdf``: primitive shapes on
pepper_description's kinematics, the chest tablet included), loaded with Pinocchio (``pin``) into a
kinematic model and a separate geometry model, as Pinocchio separates them; distances between
shapes come from coal (the FCL successor Pinocchio uses). Nothing here is hand-written geometry.

**Checked pairs.** Those of :func:`~audio2pose_ros.robot.pairs.checked_pair`: every link of an arm
that the arm's joints move against the rest of the body and the other arm.

Joints the speech model does not drive (HipPitch, KneePitch, the wrists and hands) stay at zero,
where Pepper holds them while it talks; distances are signed, in metres (negative: the shapes
overlap by that much).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.robot.kinematics import default_urdf_path
from audio2pose_ros.robot.pairs import ARM_LINK_PREFIXES, checked_pair, pose_array

PUSH_OUT_STEP_RAD = 0.02  # joint-space step of push_out's climb along the clearance gradient
PUSH_OUT_MAX_STEPS = 400  # push_out gives up after this many steps (8 rad of travel)
GRADIENT_STEP_RAD = 1e-3  # finite-difference step of the clearance gradient
BLAS_BLOCK_ELEMENTS = 1 << 16  # products of rows x inner x columns up to this stay on one thread
RECENT_QUERIES = 16  # poses whose clearance is kept: a guard step asks about the same few poses


@dataclass(frozen=True)
class PathClearance:
    """What :meth:`BodyModel.sweep` found along a path of poses.

    Attributes:
        clear: every point of the path is at least the asked clearance away (within ``slack_m``
            between its samples).
        index: the first sample closer than the asked clearance (-1 when clear).
        pair: index in :attr:`BodyModel.link_pairs` of that sample's closest pair (-1 when clear).
        lowest_m: a lower bound of the clearance along the whole path when clear (m); the
            offending sample's clearance otherwise.
        slack_m: how far the path between two samples may come closer than the samples' bounds.
        queries: distance queries the sweep made (the rest of the path needed none).
    """

    clear: bool
    index: int
    pair: int
    lowest_m: float
    slack_m: float
    queries: int


_LOADED: dict[tuple[RobotDescription, Path], BodyModel] = {}


class BodyModelError(ConfigurationError):
    """The URDF lacks a joint of the robot description, or its collision shapes cannot load."""


def _bounding_radius(shape: Any) -> float:
    """Radius of a sphere about the shape's centre that contains it (m)."""
    kind = type(shape).__name__
    if kind == "Sphere":
        return float(shape.radius)
    if kind in ("Cylinder", "Capsule"):
        return float(np.hypot(shape.radius, shape.halfLength)) + (
            float(shape.radius) if kind == "Capsule" else 0.0
        )
    if kind == "Box":
        return float(np.linalg.norm(shape.halfSide))
    raise BodyModelError(f"collision shape {kind} is not supported (use boxes, cylinders, spheres)")


def _link_of(geometry_name: str) -> str:
    """``LForeArm_0`` -> ``LForeArm`` (Pinocchio numbers the shapes of a link)."""
    return geometry_name.rsplit("_", 1)[0]


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


class _PairGroup:
    """The checked pairs in a geometry model of their own, with coal's per-pair workspace."""

    def __init__(self, pin: Any, model: Any, urdf_path: Path, pairs: list[tuple[int, int]]) -> None:
        self.geometry = pin.buildGeomFromUrdf(model, str(urdf_path), pin.GeometryType.COLLISION)
        for a, b in pairs:
            self.geometry.addCollisionPair(pin.CollisionPair(a, b))
        self.data = self.geometry.createData()
        self.pairs = pairs
        self._initial_guesses = [
            (request.cached_gjk_guess.copy(), request.cached_support_func_guess.copy())
            for request in self.data.distanceRequests
        ]

    def reset_guesses(self) -> None:
        """Start every pair's distance search from its first guess again.

        coal starts each search from the previous answer's support points (several times
        faster for the small steps between commands), so an answer depends, within its 1e-6 m
        tolerance, on the queries before it. Resetting at the start of a run makes the same
        poses give the same answers in every run.
        """
        for request, (gjk, support) in zip(
            self.data.distanceRequests, self._initial_guesses, strict=True
        ):
            request.cached_gjk_guess = gjk.copy()
            request.cached_support_func_guess = support.copy()


class BodyModel:
    """Clearance of Pepper's arms from its body, for poses in the robot description's joint order.

    Build it once with :meth:`load`; every query takes a pose and returns distances. One instance
    holds Pinocchio's per-query workspaces (``Data``), so give each thread its own.
    """

    def __init__(self, robot: RobotDescription, urdf_path: Path) -> None:
        """Load the kinematic and collision models of ``urdf_path`` for ``robot``'s joints.

        Raises:
            BodyModelError: the URDF cannot be loaded or lacks one of the robot's joints.
        """
        try:
            import pinocchio
        except ImportError as error:  # pragma: no cover - a dependency of the package
            raise BodyModelError(f"the body model needs pinocchio (pip: pin): {error}") from None
        self._pin: Any = pinocchio
        self.robot = robot
        self.urdf_path = urdf_path
        try:
            model = pinocchio.buildModelFromUrdf(str(urdf_path))
            geometry = pinocchio.buildGeomFromUrdf(
                model, str(urdf_path), pinocchio.GeometryType.COLLISION
            )
        except (RuntimeError, ValueError, OSError) as error:
            raise BodyModelError(f"{urdf_path}: cannot load its collision model: {error}") from None
        self._model = model
        self._q_index = np.zeros(robot.n_joints, dtype=np.int64)
        for i, name in enumerate(robot.names):
            if not model.existJointName(name):
                raise BodyModelError(f"{urdf_path} has no joint {name!r} of the robot description")
            self._q_index[i] = model.joints[model.getJointId(name)].idx_q
        self._q = pinocchio.neutral(model)
        self._data = model.createData()
        objects = geometry.geometryObjects
        names = [_link_of(obj.name) for obj in objects]
        # A link of an arm counts as moved by all of its arm's joints (those of the hand's chain):
        # the guard stops or slides a whole arm, so pairs group by arm, head and hip.
        hand_joint = {
            link: objects[names.index(links[-1])].parentJoint
            for links in ARM_LINK_PREFIXES.values()
            for link in links
            if links[-1] in names
        }
        chain = [
            hand_joint.get(name, obj.parentJoint) for name, obj in zip(names, objects, strict=True)
        ]
        pairs: list[tuple[int, int]] = []
        masks: list[np.ndarray] = []
        for a in range(len(objects)):
            for b in range(len(objects)):
                if a != b and checked_pair(names[a], names[b]):
                    pairs.append((a, b))
                    masks.append(self._driven_joints(chain[a], chain[b]))
        if not pairs:
            raise BodyModelError(f"{urdf_path}: no arm link to check against the body")
        shape_levers, moved = self._levers(geometry)
        self.lever_m = shape_levers.max(axis=0)
        # a joint on both shapes' chains moves them together: it cannot change their distance
        self.pair_lever_m = np.array(
            [
                np.where(moved[a] & ~moved[b], shape_levers[a], 0.0)
                + np.where(moved[b] & ~moved[a], shape_levers[b], 0.0)
                for a, b in pairs
            ]
        )
        self._pairs = _PairGroup(pinocchio, model, urdf_path, pairs)
        self._pair_joints = np.array(masks, dtype=bool)  # (n_pairs, n_joints)
        self.link_pairs: tuple[tuple[str, str], ...] = tuple((names[a], names[b]) for a, b in pairs)
        self._recent: dict[bytes, tuple[float, int]] = {}  # the last few queries

    @classmethod
    def load(
        cls, robot: RobotDescription | None = None, urdf_path: Path | None = None
    ) -> BodyModel:
        """The packaged Pepper URDF and robot description unless others are given.

        Loading takes about 60 ms, so one model per robot description and URDF is kept and
        shared by the callers of one process; a run that must be reproducible starts with
        :meth:`reset`.
        """
        key = (robot or load_robot(), Path(urdf_path or default_urdf_path()).resolve())
        model = _LOADED.get(key)
        if model is None:
            model = _LOADED[key] = cls(*key)
        return model

    def _levers(self, geometry: Any) -> tuple[np.ndarray, np.ndarray]:
        """Per collision shape and robot joint, how far the shape can be from the joint's axis.

        Bounded along the kinematic chain: the offsets of the joints below it, the shape's
        placement and its bounding radius (m; 0 for a joint that does not move the shape).
        Turning joint j by d moves no point of shape s further than ``levers[s, j] * |d|``, so
        a clearance larger than the sum cannot be lost (:meth:`sweep`).

        Returns:
            ``(levers, moved)``: (n_shapes, n_joints) lever lengths (m) and whether each joint
            moves each shape.
        """
        model = self._model
        objects = geometry.geometryObjects
        levers = np.zeros((len(objects), self.robot.n_joints))
        moved = np.zeros((len(objects), self.robot.n_joints), dtype=bool)
        joint_ids = [model.getJointId(name) for name in self.robot.names]
        for s, obj in enumerate(objects):
            radius = _bounding_radius(obj.geometry) + float(
                np.linalg.norm(obj.placement.translation)
            )
            chain = [int(j) for j in model.supports[obj.parentJoint]]
            for i, joint in enumerate(joint_ids):
                if joint in chain:
                    below = chain[chain.index(joint) + 1 :]
                    levers[s, i] = radius + sum(
                        float(np.linalg.norm(model.jointPlacements[j].translation)) for j in below
                    )
                    moved[s, i] = True
        return levers, moved

    def _driven_joints(self, joint_a: int, joint_b: int) -> np.ndarray:
        """Mask of the robot's joints on the kinematic chains of two URDF joints."""
        model = self._model
        supports = {int(j) for joint in (joint_a, joint_b) for j in model.supports[joint]}
        names = {model.names[j] for j in supports}
        return np.array([name in names for name in self.robot.names])

    def _placements(self, pose_rad: np.ndarray) -> None:
        self._q[self._q_index] = pose_rad
        self._pin.forwardKinematics(self._model, self._data, self._q)

    def _place_pairs(self, pose_rad: np.ndarray) -> _PairGroup:
        """Place the checked pairs' shapes in one pose; returns the pair group to query."""
        group = self._pairs
        self._placements(pose_rad)
        self._pin.updateGeometryPlacements(self._model, self._data, group.geometry, group.data)
        return group

    def query(self, pose_rad: np.ndarray) -> tuple[float, int]:
        """The closest pair's distance (m) and its index in :attr:`link_pairs`, for one pose.

        The pose is a finite (n_joints,) array; the last ``RECENT_QUERIES`` answers are kept.
        """
        key = pose_rad.tobytes()
        cached = self._recent.get(key)
        if cached is not None:
            return cached
        group = self._place_pairs(pose_rad)
        k = int(self._pin.computeDistances(group.geometry, group.data))
        distance = float(group.data.distanceResults[k].min_distance)
        if len(self._recent) >= RECENT_QUERIES:
            self._recent.pop(next(iter(self._recent)))  # oldest first (dicts keep order)
        self._recent[key] = (distance, k)
        return distance, k

    def _some_pairs(self, pose_rad: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """Signed distances (m) of the pairs ``pairs`` (indices) alone in one pose."""
        group = self._place_pairs(pose_rad)
        distance = self._pin.computeDistance
        return np.array([distance(group.geometry, group.data, int(k)).min_distance for k in pairs])

    def sweep(
        self, points_rad: np.ndarray, floor_m: float, counts: np.ndarray | None = None
    ) -> PathClearance:
        """Whether the path through ``points_rad`` keeps ``floor_m`` (conservative advancement).

        The path is the polyline through the (m, n_joints) points; with ``counts`` (m - 1
        positive integers) its piece p is sampled at ``counts[p]`` evenly spaced samples
        (fractions 1/c, 2/c, ..., 1 of it; the first point is sample 0), else at its ends only.
        Pair k's distance cannot fall by more than ``pair_lever_m[k] @ |q - q_known|`` from a
        pose where it is known (only the joints that move one of its shapes and not the other
        count), and ``|q - q_known|`` is at most each joint's travel along the path between
        the two (equal where the joint moves one way). From the first sample's clearance, the
        pairs that this bound keeps at ``floor_m`` or more along the whole path are done; the
        others (the few near the moving arm) are queried alone, pair by pair, at the first
        sample their bound does not keep clear, and so on. Between two samples the path can
        come closer than their bounds by at most half its travel there (``slack_m``), so
        samples dense for the fastest joint and the thinnest shape make the check continuous to
        that slack. A path far from the body costs one (usually cached) query; the rest is
        arithmetic on the pieces, not on the samples (only the queried samples are made).

        Args:
            points_rad: (m, n_joints) finite points of the path, in order.
            floor_m: clearance every sample must keep (m).
            counts: (m - 1,) samples of each piece (default: one, its end).

        Returns:
            The :class:`PathClearance`; its ``index`` counts the samples from 0.
        """
        points = np.asarray(points_rad, dtype=np.float64)
        levers = self.pair_lever_m.T  # (n_joints, n_pairs)
        distance, k = self.query(points[0])
        if distance < floor_m:
            return PathClearance(False, 0, k, distance, 0.0, 1)
        if len(points) == 1:
            return PathClearance(True, -1, -1, distance, 0.0, 1)
        pieces = np.diff(points, axis=0)
        per = np.ones(len(pieces)) if counts is None else np.asarray(counts, dtype=np.float64)
        spans = np.abs(pieces)  # (pieces, n_joints): each joint's travel along each piece
        walked = np.zeros_like(points)  # each joint's travel from the first point to each
        np.cumsum(spans, axis=0, out=walked[1:])
        reach = walked[-1] @ levers  # (n_pairs,): how far each pair can move along the path
        slack = 0.5 * float(blocked_product(spans / per[:, None], levers).max())
        near = np.flatnonzero(distance - reach < floor_m)
        far = np.delete(reach, near)
        lowest = distance - (float(far.max()) if far.size else 0.0)
        queries = 1
        if not near.size:
            return PathClearance(True, -1, -1, lowest - slack, slack, queries)
        # how far each near pair can have moved from the first point, at each point (never
        # falls), and along each piece; sample j of piece p has moved[p] + j / per[p] * along[p]
        moved = blocked_product(walked, levers[:, near])  # (points, near)
        along = np.diff(moved, axis=0)  # (pieces, near)
        ends = np.cumsum(per).astype(np.int64)  # the sample at the end of each piece
        now, last = 0, int(ends[-1])  # the present sample, the last one
        at = moved[0]
        known = np.full(near.size, distance)  # at the first sample: no pair is nearer than that
        while True:
            lowest = min(lowest, float(known.min()))
            # a later sample is kept clear of pair j while it has moved no further than this
            allowed = at + known - floor_m
            keep = moved[-1] > allowed  # pairs that need another query further on
            done = ~keep
            if done.any():
                lowest = min(lowest, float((known - moved[-1] + at)[done].min()))
            if not keep.any() or now == last:
                break
            near, moved, along = near[keep], moved[:, keep], along[:, keep]
            at, known, allowed = at[keep], known[keep], allowed[keep]
            # each pair's first piece that ends beyond, and its first sample there
            first = np.argmax(moved[1:] > allowed, axis=0)
            share = (allowed - moved[first, np.arange(near.size)]) / np.maximum(
                along[first, np.arange(near.size)], 1e-300
            )
            steps = np.clip(np.floor(share * per[first]) + 1.0, 1.0, per[first])
            samples = ends[first] - per[first].astype(np.int64) + steps.astype(np.int64)
            target = min(max(int(samples.min()), now + 1), last)
            piece = int(np.searchsorted(ends, target))
            step = target - int(ends[piece] - per[piece])
            before = moved[piece] + (step - 1) / per[piece] * along[piece]
            if target - 1 > now:  # the samples passed: bounded by the one before the target
                lowest = min(lowest, float((known - before + at).min()))
            fraction = step / per[piece]
            pose = points[piece] + fraction * pieces[piece]
            at = moved[piece] + fraction * along[piece]
            known = self._some_pairs(pose, near)
            queries, now = queries + 1, target
            if known.min() < floor_m:
                worst = int(np.argmin(known))
                pair, nearest = int(near[worst]), float(known[worst])
                return PathClearance(False, target, pair, nearest, slack, queries)
        return PathClearance(True, -1, -1, lowest - slack, slack, queries)

    def pair_joints(self, pair: int) -> np.ndarray:
        """Mask of the joints that move pair ``pair`` of :attr:`link_pairs` (a whole arm)."""
        return self._pair_joints[pair].copy()

    def _pose_array(self, poses_rad: np.ndarray) -> np.ndarray:
        return pose_array(poses_rad, self.robot.n_joints)

    def _frame_positions(self, poses_rad: np.ndarray, frames: tuple[str, str]) -> np.ndarray:
        """(N, 2, 3) positions (m) of two URDF frames in the torso's frame, for N poses."""
        poses = np.atleast_2d(self._pose_array(poses_rad))
        pin, model, data = self._pin, self._model, self._data
        ids = [model.getFrameId(name) for name in ("torso", *frames)]
        out = np.empty((len(poses), 2, 3))
        for i, pose in enumerate(poses):
            self._placements(pose)
            pin.updateFramePlacements(model, data)
            torso = data.oMf[ids[0]]
            for k, frame in enumerate(ids[1:]):
                out[i, k] = torso.actInv(data.oMf[frame]).translation
        return out

    def wrist_positions(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2, 3) positions (m) of the left and right wrist in the torso's frame.

        The torso frame (x forward, y left, z up) moves with the hip, so the positions describe
        where the hands are relative to the chest, whatever the hip does.
        """
        return self._frame_positions(poses_rad, ("l_wrist", "r_wrist"))

    def shoulder_positions(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2, 3) positions (m) of the left and right shoulder joints in the torso's frame.

        The shoulders are fixed to the torso, so these are the same in every pose; a wrist above
        its shoulder is :meth:`wrist_positions` higher than this.
        """
        return self._frame_positions(poses_rad, ("LShoulder", "RShoulder"))

    def wrist_heights(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2) height (m) of the left and right wrist above its own shoulder joint."""
        poses = np.atleast_2d(self._pose_array(poses_rad))
        shoulders = self.shoulder_positions(poses[:1])[0, :, 2]
        return np.asarray(self.wrist_positions(poses)[..., 2] - shoulders)

    def pair_distances(self, pose_rad: np.ndarray) -> np.ndarray:
        """Signed distance (m) of every pair of :attr:`link_pairs` in one pose.

        Always computed afresh: the cache of :meth:`query` keeps the smallest distance only.
        """
        group = self._place_pairs(self._pose_array(pose_rad).reshape(-1))
        self._pin.computeDistances(group.geometry, group.data)
        return np.array([r.min_distance for r in group.data.distanceResults])

    def clearance(self, poses_rad: np.ndarray) -> np.ndarray:
        """Smallest signed distance (m) of the checked pairs: shape () for one pose, (N,) for N."""
        poses = self._pose_array(poses_rad)
        if poses.ndim == 1:
            return np.asarray(self.query(poses)[0])
        return np.array([self.query(pose)[0] for pose in poses])

    def closest_pair(self, pose_rad: np.ndarray) -> tuple[float, str, str]:
        """``(distance_m, arm_link, other_link)`` of the closest checked pair in one pose."""
        distance, k = self.query(self._pose_array(pose_rad).reshape(-1))
        return distance, *self.link_pairs[k]

    def violations(self, pose_rad: np.ndarray, margin_m: float) -> tuple[float, np.ndarray]:
        """Clearance of one pose and the joints that move its closest pair, if that is too close.

        Args:
            pose_rad: (n_joints,) finite pose.
            margin_m: required clearance (m).

        Returns:
            ``(clearance_m, joints)``: the smallest distance and a boolean (n_joints,) mask of the
            joints on the kinematic chains of the closest pair when it is closer than
            ``margin_m`` (all False when the pose is clear). Other pairs closer than the margin
            show once the closest one is resolved (the guard widens its set of braked joints).
        """
        clearance, k = self.query(pose_rad)
        if clearance >= margin_m:
            return clearance, np.zeros(self.robot.n_joints, dtype=bool)
        return clearance, self._pair_joints[k].copy()

    def reset(self) -> None:
        """Forget earlier queries: the answers of a run then depend on its own poses alone."""
        self._recent.clear()
        self._pairs.reset_guesses()

    def _pair_distance(self, pose_rad: np.ndarray, k: int) -> float:
        """Signed distance (m) of pair ``k`` of :attr:`link_pairs` alone in one pose."""
        group = self._place_pairs(pose_rad)
        return float(self._pin.computeDistance(group.geometry, group.data, k).min_distance)

    def gradient(self, pose_rad: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Central-difference gradient (m/rad) of the clearance in the ``joints`` (mask) only.

        The clearance is the smallest distance of the checked pairs, so its gradient is its
        closest pair's: only that pair is queried at the displaced poses (on the bundled URDF,
        one pair of the 145 costs about a fiftieth of them all). Where another pair is as
        close, the gradient is the one of the pair :meth:`closest_pair` names.
        """
        gradient = np.zeros(self.robot.n_joints)
        pose = np.array(pose_rad, dtype=np.float64)
        k = self.query(pose)[1]
        for i in np.flatnonzero(joints):
            saved = pose[i]
            pose[i] = saved + GRADIENT_STEP_RAD
            up = self._pair_distance(pose, k)
            pose[i] = saved - GRADIENT_STEP_RAD
            down = self._pair_distance(pose, k)
            pose[i] = saved
            gradient[i] = (up - down) / (2.0 * GRADIENT_STEP_RAD)
        return gradient

    def push_out(self, poses_rad: np.ndarray, margin_m: float) -> np.ndarray:
        """Move every pose closer than ``margin_m`` to a nearby clear pose; clear poses stay.

        Only the joints of the offending pairs move (an arm, and the hip or head when the pair
        involves them), up the clearance gradient in small steps within the joint limits, until
        the clearance reaches the margin. Used to clean training targets retargeted from people,
        whose bodies are not Pepper's.

        Args:
            poses_rad: (N, n_joints) or (n_joints,) finite poses.
            margin_m: required clearance (m), at least 0.

        Returns:
            Poses of the same shape, each with clearance >= ``margin_m`` unless no such pose was
            found within ``PUSH_OUT_MAX_STEPS`` steps (then the clearest pose found).
        """
        poses = self._pose_array(poses_rad)
        lower, upper = self.robot.lower_rad, self.robot.upper_rad
        out = np.array(np.atleast_2d(poses), dtype=np.float64)
        for row in out:
            clearance, joints = self.violations(row, margin_m)
            for _ in range(PUSH_OUT_MAX_STEPS):
                if clearance >= margin_m:
                    break
                gradient = self.gradient(row, joints)
                norm = float(np.linalg.norm(gradient))
                if norm < 1e-9:  # flat: move the joints towards their neutral pose instead
                    direction = np.where(joints, self.robot.neutral_rad - row, 0.0)
                    norm = float(np.linalg.norm(direction))
                    if norm < 1e-9:
                        break
                    gradient = direction
                row[:] = np.clip(row + PUSH_OUT_STEP_RAD * gradient / norm, lower, upper)
                clearance, more = self.violations(row, margin_m)
                joints |= more
        return out.reshape(poses.shape)
