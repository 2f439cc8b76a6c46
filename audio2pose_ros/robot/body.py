"""Pepper's body as collision geometry: how close the arms come to the body and to each other.

The geometry is the URDF's ``<collision>`` shapes (``urdf/pepper.urdf``: primitive shapes on
pepper_description's kinematics, the chest tablet included), loaded with Pinocchio (``pin``) into a
kinematic model and a separate geometry model, as Pinocchio separates them; distances between
shapes come from coal (the FCL successor Pinocchio uses). Nothing here is hand-written geometry.

**Checked pairs.** Every link of an arm that the arm's joints move (bicep, elbow, forearm, wrist,
hand) against every link of the rest of the body (torso with the tablet and the neck base, neck,
head, hip, pelvis, legs and base) and against every link of the other arm (its shoulder
included). Not checked, like an allowed-collision matrix: links of one arm against each other
(adjacent, they overlap by construction), and the shoulder balls against the body: they turn about
their own centre, fixed to the torso, so their clearance does not depend on any command (the head
cannot reach them within its limits; ``test/test_body.py`` checks both by sampling).

Joints the speech model does not drive (HipPitch, KneePitch, the wrists and hands) stay at zero,
where Pepper holds them while it talks; distances are signed, in metres (negative: the shapes
overlap by that much).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.robot.kinematics import default_urdf_path

ARM_LINK_PREFIXES = {
    "left": ("LBicep", "LElbow", "LForeArm", "l_wrist", "l_gripper"),
    "right": ("RBicep", "RElbow", "RForeArm", "r_wrist", "r_gripper"),
}
SHOULDER_LINKS = {"left": "LShoulder", "right": "RShoulder"}
PUSH_OUT_STEP_RAD = 0.02  # joint-space step of push_out's climb along the clearance gradient
PUSH_OUT_MAX_STEPS = 400  # push_out gives up after this many steps (8 rad of travel)
GRADIENT_STEP_RAD = 1e-3  # finite-difference step of the clearance gradient
RECENT_QUERIES = 16  # poses whose clearance is kept: a guard step asks about the same few poses


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
                if a != b and self._checked(names[a], names[b]):
                    pairs.append((a, b))
                    masks.append(self._driven_joints(chain[a], chain[b]))
        if not pairs:
            raise BodyModelError(f"{urdf_path}: no arm link to check against the body")
        self.lever_m = self._levers(geometry)
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

    @staticmethod
    def _checked(link_a: str, link_b: str) -> bool:
        """Whether the pair (``link_a``, ``link_b``) is checked, counting each pair once."""
        for side, links in ARM_LINK_PREFIXES.items():
            if link_a not in links:
                continue
            if link_b in (*links, SHOULDER_LINKS[side]):
                return False  # the arm's own links
            other = "right" if side == "left" else "left"
            if link_b in ARM_LINK_PREFIXES[other]:
                return side == "left"  # arm against arm: once, from the left
            return True  # the body, or the other arm's shoulder
        return False

    def _levers(self, geometry: Any) -> np.ndarray:
        """Per robot joint, the farthest any collision shape it moves can be from its axis (m).

        Bounded along the kinematic chain: the offsets of the joints below it, the shape's
        placement and its bounding radius. Turning joint j by d moves no point further than
        ``lever_m[j] * |d|``, so a clearance larger than that sum cannot be lost
        (:meth:`certainly_clear`).
        """
        model = self._model
        levers = np.zeros(self.robot.n_joints)
        joint_ids = [model.getJointId(name) for name in self.robot.names]
        for obj in geometry.geometryObjects:
            radius = _bounding_radius(obj.geometry) + float(
                np.linalg.norm(obj.placement.translation)
            )
            chain = [int(j) for j in model.supports[obj.parentJoint]]
            for i, joint in enumerate(joint_ids):
                if joint in chain:
                    below = chain[chain.index(joint) + 1 :]
                    reach = radius + sum(
                        float(np.linalg.norm(model.jointPlacements[j].translation)) for j in below
                    )
                    levers[i] = max(levers[i], reach)
        return levers

    def certainly_clear(self, pose_rad: np.ndarray, moved_rad: np.ndarray, margin_m: float) -> bool:
        """Whether ``moved_rad`` is clear by ``margin_m`` without a query, from ``pose_rad``'s."""
        travel = float(np.dot(self.lever_m, np.abs(moved_rad - pose_rad)))
        return float(self._query(pose_rad)[0]) - travel >= margin_m

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

    def _query(self, pose_rad: np.ndarray) -> tuple[float, int]:
        """The closest pair's distance (m) and index in :attr:`link_pairs` (recent ones cached)."""
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

    def _pose_array(self, poses_rad: np.ndarray) -> np.ndarray:
        poses = np.asarray(poses_rad, dtype=np.float64)
        if poses.shape[-1:] != (self.robot.n_joints,) or poses.ndim > 2:
            raise ValueError(
                f"poses must be (n_joints,) or (N, n_joints) with n_joints = "
                f"{self.robot.n_joints}, got shape {poses.shape}"
            )
        if not np.isfinite(poses).all():
            raise ValueError("poses must be finite")
        return poses

    def wrist_positions(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2, 3) positions (m) of the left and right wrist in the torso's frame.

        The torso frame (x forward, y left, z up) moves with the hip, so the positions describe
        where the hands are relative to the chest, whatever the hip does.
        """
        poses = np.atleast_2d(self._pose_array(poses_rad))
        pin, model, data = self._pin, self._model, self._data
        frames = [model.getFrameId(name) for name in ("torso", "l_wrist", "r_wrist")]
        out = np.empty((len(poses), 2, 3))
        for i, pose in enumerate(poses):
            self._placements(pose)
            pin.updateFramePlacements(model, data)
            torso = data.oMf[frames[0]]
            for k, frame in enumerate(frames[1:]):
                out[i, k] = torso.actInv(data.oMf[frame]).translation
        return out

    def shoulder_positions(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2, 3) positions (m) of the left and right shoulder joints in the torso's frame.

        The shoulders are fixed to the torso, so these are the same in every pose; a wrist above
        its shoulder is :meth:`wrist_positions` higher than this.
        """
        poses = np.atleast_2d(self._pose_array(poses_rad))
        pin, model, data = self._pin, self._model, self._data
        frames = [model.getFrameId(name) for name in ("torso", "LShoulder", "RShoulder")]
        out = np.empty((len(poses), 2, 3))
        for i, pose in enumerate(poses):
            self._placements(pose)
            pin.updateFramePlacements(model, data)
            torso = data.oMf[frames[0]]
            for k, frame in enumerate(frames[1:]):
                out[i, k] = torso.actInv(data.oMf[frame]).translation
        return out

    def wrist_heights(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, 2) height (m) of the left and right wrist above its own shoulder joint."""
        poses = np.atleast_2d(self._pose_array(poses_rad))
        shoulders = self.shoulder_positions(poses[:1])[0, :, 2]
        return np.asarray(self.wrist_positions(poses)[..., 2] - shoulders)

    def pair_distances(self, pose_rad: np.ndarray) -> np.ndarray:
        """Signed distance (m) of every pair of :attr:`link_pairs` in one pose.

        Always computed afresh: the cache of :meth:`_query` keeps the smallest distance only.
        """
        group = self._place_pairs(self._pose_array(pose_rad).reshape(-1))
        self._pin.computeDistances(group.geometry, group.data)
        return np.array([r.min_distance for r in group.data.distanceResults])

    def clearance(self, poses_rad: np.ndarray) -> np.ndarray:
        """Smallest signed distance (m) of the checked pairs: shape () for one pose, (N,) for N."""
        poses = self._pose_array(poses_rad)
        if poses.ndim == 1:
            return np.asarray(self._query(poses)[0])
        return np.array([self._query(pose)[0] for pose in poses])

    def closest_pair(self, pose_rad: np.ndarray) -> tuple[float, str, str]:
        """``(distance_m, arm_link, other_link)`` of the closest checked pair in one pose."""
        distance, k = self._query(self._pose_array(pose_rad).reshape(-1))
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
        clearance, k = self._query(pose_rad)
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
        k = self._query(pose)[1]
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
