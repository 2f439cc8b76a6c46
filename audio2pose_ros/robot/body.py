"""Pepper's body as collision geometry: how close the arms come to the body and to each other.

The geometry is the URDF's ``<collision>`` shapes (``urdf/pepper.urdf``: primitive shapes on
pepper_description's kinematics, the chest tablet included), read by
:class:`~audio2pose_ros.robot.kinematics.RobotKinematics` and placed by its numpy forward
kinematics (:class:`~audio2pose_ros.robot.kinematics.DrivenFrames`, shared with the capsules of
body-aware sampling); distances between the shapes come from coal (the FCL successor, the
library Pinocchio measures with; hpp-fcl, its name before version 3, where a ROS distro's
Pinocchio brings that), with the settings Pinocchio gives it. Nothing here is
hand-written geometry. (Pinocchio loaded this model until it was found to hold about 21 MB in
the motion filter's process for forward kinematics alone; ``test/test_body.py`` checks the
placements, distances and levers against it.)

**Checked pairs.** Those of :func:`~audio2pose_ros.robot.pairs.checked_pair`: every link of an arm
that the arm's joints move against the rest of the body and the other arm. The shapes are
numbered as urdfdom, hence Pinocchio, numbers them (depth first from the root link, a link's
children in the order of their joints' names, a link's shapes in file order), so the pairs,
and the first of equally close pairs, are the ones Pinocchio's model gave.

**Only the pairs that can be closest are measured.** Each pair's last distance is kept with the
pose it was measured at; turning joint j by d changes pair k's distance by at most
``pair_lever_m[k, j] * |d|``, so a pair whose bound from its last distance stays above the
closest distance measured in this pose (by more than ``CULL_SLACK_M``, coal's tolerance with
room to spare) cannot be the closest, and is not measured again (:meth:`BodyModel.query`).

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
from audio2pose_ros.robot.kinematics import (
    DrivenFrames,
    KinematicsError,
    RobotKinematics,
    UrdfCollision,
    blocked_product,
    default_urdf_path,
)
from audio2pose_ros.robot.pairs import ARM_LINK_PREFIXES, checked_pair, pose_array

PUSH_OUT_STEP_RAD = 0.02  # joint-space step of push_out's climb along the clearance gradient
PUSH_OUT_MAX_STEPS = 400  # push_out gives up after this many steps (8 rad of travel)
GRADIENT_STEP_RAD = 1e-3  # finite-difference step of the clearance gradient
RECENT_QUERIES = 16  # poses whose clearance is kept: a guard step asks about the same few poses
CULL_SLACK_M = 1e-5  # a pair is skipped only if its bound exceeds the closest one by this (m);
# coal answers within 1e-6 m


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


def _bounding_radius(shape: UrdfCollision) -> float:
    """Radius of a sphere about the shape's centre that contains it (m)."""
    if shape.kind == "sphere":
        return shape.size[0]
    if shape.kind == "cylinder":
        return float(np.hypot(shape.size[0], 0.5 * shape.size[1]))
    return float(np.linalg.norm(0.5 * np.asarray(shape.size)))


def _collision_library() -> Any:
    """coal, or hpp-fcl: its name before version 3, which Humble's Pinocchio 3 brings.

    Raises:
        BodyModelError: neither is installed.
    """
    try:
        import coal
    except ImportError:
        pass
    else:
        return coal
    try:
        import hppfcl  # pragma: no cover - Humble's distro packages
    except ImportError as error:
        raise BodyModelError(
            f"the body model needs coal (pip: coal; a ROS distro's pinocchio brings it): {error}"
        ) from None
    return hppfcl  # pragma: no cover


def _coal_shape(coal: Any, shape: UrdfCollision) -> Any:
    """The coal geometry of a URDF box, cylinder or sphere (as Pinocchio builds it)."""
    if shape.kind == "box":
        return coal.Box(*shape.size)
    if shape.kind == "cylinder":
        return coal.Cylinder(*shape.size)
    if shape.kind == "sphere":
        return coal.Sphere(shape.size[0])
    raise BodyModelError(
        f"collision shape {shape.kind} of link {shape.link} is not supported "
        f"(use boxes, cylinders, spheres)"
    )


def _shapes_in_tree_order(kinematics: RobotKinematics) -> list[UrdfCollision]:
    """The collision shapes depth first from the root link, children by their joints' names."""
    children: dict[str, list[tuple[str, str]]] = {}
    for joint in kinematics.joints:
        children.setdefault(joint.parent, []).append((joint.name, joint.child))
    by_link: dict[str, list[UrdfCollision]] = {}
    for shape in kinematics.collisions:
        by_link.setdefault(shape.link, []).append(shape)
    ordered: list[UrdfCollision] = []
    stack = [kinematics.root_link]
    while stack:
        link = stack.pop()
        ordered.extend(by_link.get(link, ()))
        stack.extend(child for _, child in sorted(children.get(link, ()), reverse=True))
    return ordered


class _PairGroup:
    """The checked pairs' coal distance functors, with coal's per-pair workspace.

    Each pair has its own request, so each distance search starts from the support points of
    that pair's previous answer (Pinocchio's setting: several times faster for the small steps
    between commands).
    """

    def __init__(self, coal: Any, shapes: list[Any], pairs: list[tuple[int, int]]) -> None:
        self.shapes = shapes  # the functors point to them: they must live as long
        self.functors = [coal.ComputeDistance(shapes[a], shapes[b]) for a, b in pairs]
        self.requests = []
        for _ in pairs:
            request = coal.DistanceRequest()
            request.gjk_initial_guess = coal.GJKInitialGuess.CachedGuess
            self.requests.append(request)
        self.results = [coal.DistanceResult() for _ in pairs]
        self.pairs = pairs
        # per pair: its shapes, functor, request and result, for one lookup a measurement
        self.calls = [
            (a, b, functor, request, result)
            for (a, b), functor, request, result in zip(
                pairs, self.functors, self.requests, self.results, strict=True
            )
        ]
        self._initial_guesses = [
            (request.cached_gjk_guess.copy(), request.cached_support_func_guess.copy())
            for request in self.requests
        ]

    def reset_guesses(self) -> None:
        """Start every pair's distance search from its first guess again.

        coal starts each search from the previous answer's support points, so an answer
        depends, within its 1e-6 m tolerance, on the queries before it. Resetting at the start
        of a run makes the same poses give the same answers in every run.
        """
        for request, (gjk, support) in zip(self.requests, self._initial_guesses, strict=True):
            request.cached_gjk_guess = gjk.copy()
            request.cached_support_func_guess = support.copy()


class BodyModel:
    """Clearance of Pepper's arms from its body, for poses in the robot description's joint order.

    Build it once with :meth:`load`; every query takes a pose and returns distances. One instance
    holds coal's per-query workspaces, so give each thread its own.
    """

    def __init__(self, robot: RobotDescription, urdf_path: Path) -> None:
        """Load the kinematics and collision shapes of ``urdf_path`` for ``robot``'s joints.

        Raises:
            BodyModelError: the URDF cannot be loaded, lacks one of the robot's joints or has a
                shape other than a box, a cylinder or a sphere.
        """
        coal = _collision_library()
        self.robot = robot
        self.urdf_path = urdf_path
        try:
            kinematics = RobotKinematics(urdf_path)
        except (KinematicsError, OSError) as error:
            raise BodyModelError(f"{urdf_path}: cannot load its collision model: {error}") from None
        movable = kinematics.movable_joint_names
        for name in robot.names:
            if name not in movable:
                raise BodyModelError(f"{urdf_path} has no joint {name!r} of the robot description")
        try:
            self._frames = DrivenFrames(kinematics, robot.names)
            # every movable joint a frame, as in Pinocchio's model: the levers' chains
            tree = DrivenFrames(kinematics, movable)
        except KinematicsError as error:
            raise BodyModelError(f"{urdf_path}: {error}") from None
        shapes = _shapes_in_tree_order(kinematics)
        names = [shape.link for shape in shapes]
        geometries = [_coal_shape(coal, shape) for shape in shapes]
        self._shape_frames = np.array([self._frames.frame_of[link] for link in names])
        self._shape_in_frame = np.array(
            [self._frames.link_in_frame[s.link] @ s.origin for s in shapes]
        ).reshape(-1, 4, 4)
        self.shape_links: tuple[str, ...] = tuple(names)
        # A link of an arm counts as moved by all of its arm's joints (those of the hand's chain):
        # the guard stops or slides a whole arm, so pairs group by arm, head and hip.
        hand = {link: links[-1] for links in ARM_LINK_PREFIXES.values() for link in links}
        chain = [
            tree.frame_chains[tree.frame_of[hand[name] if hand.get(name) in names else name]]
            for name in names
        ]
        pairs: list[tuple[int, int]] = []
        masks: list[np.ndarray] = []
        for a in range(len(shapes)):
            for b in range(len(shapes)):
                if a != b and checked_pair(names[a], names[b]):
                    pairs.append((a, b))
                    moving = {tree.joint_names[j] for j in (*chain[a], *chain[b])}
                    masks.append(np.array([name in moving for name in robot.names]))
        if not pairs:
            raise BodyModelError(f"{urdf_path}: no arm link to check against the body")
        shape_levers, moved = self._levers(tree, shapes)
        self.lever_m = shape_levers.max(axis=0)
        # a joint on both shapes' chains moves them together: it cannot change their distance
        self.pair_lever_m = np.array(
            [
                np.where(moved[a] & ~moved[b], shape_levers[a], 0.0)
                + np.where(moved[b] & ~moved[a], shape_levers[b], 0.0)
                for a, b in pairs
            ]
        )
        self._pairs = _PairGroup(coal, geometries, pairs)
        transform = getattr(coal, "Transform3s", None) or coal.Transform3f  # hpp-fcl: 3f
        self._transforms = [transform() for _ in shapes]
        self._placed = b""  # the pose the shapes are placed in
        self._placer = self._frames.placer(self._shape_frames, self._shape_in_frame)
        placed = self._placer.placed  # their placement in that pose
        self._rotations, self._translations = placed[:, :3, :3], placed[:, :3, 3]
        self._moved = [True] * len(shapes)  # coal's transform of a shape is not yet there
        self._pair_joints = np.array(masks, dtype=bool)  # (n_pairs, n_joints)
        self.link_pairs: tuple[tuple[str, str], ...] = tuple((names[a], names[b]) for a, b in pairs)
        self._recent: dict[bytes, tuple[float, int]] = {}  # the last few queries
        # each pair's last measured distance and the pose it was measured at (-inf: none)
        self._known_m = np.full(len(pairs), -np.inf)
        self._known_at = np.zeros((len(pairs), robot.n_joints))

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

    def _levers(
        self, tree: DrivenFrames, shapes: list[UrdfCollision]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per collision shape and robot joint, how far the shape can be from the joint's axis.

        Bounded along the kinematic chain of every movable joint (``tree``): the offsets of the
        joints below it, the shape's placement and its bounding radius (m; 0 for a joint that
        does not move the shape). Turning joint j by d moves no point of shape s further than
        ``levers[s, j] * |d|``, so a clearance larger than the sum cannot be lost
        (:meth:`sweep`).

        Returns:
            ``(levers, moved)``: (n_shapes, n_joints) lever lengths (m) and whether each joint
            moves each shape.
        """
        levers = np.zeros((len(shapes), self.robot.n_joints))
        moved = np.zeros((len(shapes), self.robot.n_joints), dtype=bool)
        offsets = [float(np.linalg.norm(placement[:3, 3])) for placement in tree.placements]
        for s, shape in enumerate(shapes):
            placement = tree.link_in_frame[shape.link] @ shape.origin
            radius = _bounding_radius(shape) + float(np.linalg.norm(placement[:3, 3]))
            chain = tree.frame_chains[tree.frame_of[shape.link]]
            for position, joint in enumerate(chain):
                name = tree.joint_names[joint]
                if name in self.robot.names:
                    i = self.robot.names.index(name)
                    levers[s, i] = radius + sum(offsets[j] for j in chain[position + 1 :])
                    moved[s, i] = True
        return levers, moved

    def placements(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, n_shapes, 4, 4) placements of the collision shapes (:attr:`shape_links`) in N poses.

        In the root link's frame, as Pinocchio's ``oMg``.
        """
        poses = np.atleast_2d(self._pose_array(poses_rad))
        return self._frames.place(poses, self._shape_frames, self._shape_in_frame)

    def _place(self, pose_rad: np.ndarray) -> None:
        """Place the shapes in one (checked) pose; coal's transforms follow as pairs need them."""
        key = pose_rad.tobytes()
        if key == self._placed:
            return
        self._placer.place(pose_rad)
        self._moved = [True] * len(self._transforms)
        self._placed = key

    def _measure(self, pose_rad: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """Signed distances (m) of the pairs ``pairs`` (indices) in the placed pose ``pose_rad``.

        Each is kept, with the pose, as the pair's last known distance.
        """
        calls, transforms, moved = self._pairs.calls, self._transforms, self._moved
        out = []
        for k in pairs.tolist():
            a, b, distance, request, result = calls[k]
            for shape in (a, b):
                if moved[shape]:  # coal's transform of the shape is not yet in this pose
                    transforms[shape].setRotation(self._rotations[shape])
                    transforms[shape].setTranslation(self._translations[shape])
                    moved[shape] = False
            result.clear()
            distance(transforms[a], transforms[b], request, result)
            out.append(result.min_distance)
        distances = np.array(out)
        self._known_m[pairs] = distances
        self._known_at[pairs] = pose_rad
        return distances

    def query(self, pose_rad: np.ndarray) -> tuple[float, int]:
        """The closest pair's distance (m) and its index in :attr:`link_pairs`, for one pose.

        The pose is a finite (n_joints,) array; the last ``RECENT_QUERIES`` answers are kept.
        Measured are the pairs whose bound (see the module text) is no higher than the largest
        distance the pair of the lowest bound can have now; among equally close pairs, the
        first counts.
        """
        key = pose_rad.tobytes()
        cached = self._recent.get(key)
        if cached is not None:
            return cached
        self._place(pose_rad)
        # how far each pair's distance can have changed since it was measured
        reach = np.einsum("pj,pj->p", self.pair_lever_m, np.abs(pose_rad - self._known_at))
        bounds = self._known_m - reach
        lowest = int(np.argmin(bounds))
        if self._known_m[lowest] == -np.inf:  # a pair never measured (since reset): all
            pairs = np.arange(len(bounds))
        else:
            ceiling = self._known_m[lowest] + reach[lowest]
            pairs = (bounds <= ceiling + CULL_SLACK_M).nonzero()[0]
        distances = self._measure(pose_rad, pairs)
        closest = int(np.argmin(distances))  # the first of equally close pairs
        answer = (float(distances[closest]), int(pairs[closest]))
        if len(self._recent) >= RECENT_QUERIES:
            self._recent.pop(next(iter(self._recent)))  # oldest first (dicts keep order)
        self._recent[key] = answer
        return answer

    def pair_bounds(self, pose_rad: np.ndarray) -> np.ndarray:
        """Lower bounds (m) of every pair's distance in one pose, from the last measurements alone.

        No query: pair k's distance at ``pose_rad`` is at least its last measured distance less
        ``pair_lever_m[k] @ |pose_rad - q_known|`` (see the module text), less ``CULL_SLACK_M``
        for coal's tolerance; -inf for a pair never measured (since :meth:`reset`). A pose q
        near ``pose_rad`` keeps at least ``bounds - pair_lever_m @ |q - pose_rad|``.

        Returns:
            (n_pairs,) bounds, in the order of :attr:`link_pairs`.
        """
        reach = np.einsum("pj,pj->p", self.pair_lever_m, np.abs(pose_rad - self._known_at))
        return np.asarray(self._known_m - reach - CULL_SLACK_M)

    def _some_pairs(self, pose_rad: np.ndarray, pairs: np.ndarray) -> np.ndarray:
        """Signed distances (m) of the pairs ``pairs`` (indices) alone in one pose."""
        self._place(pose_rad)
        return self._measure(pose_rad, pairs)

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
        pieces = points[1:] - points[:-1]
        per = np.ones(len(pieces)) if counts is None else np.asarray(counts, dtype=np.float64)
        spans = np.abs(pieces)  # (pieces, n_joints): each joint's travel along each piece
        walked = np.zeros_like(points)  # each joint's travel from the first point to each
        np.cumsum(spans, axis=0, out=walked[1:])
        reach = walked[-1] @ levers  # (n_pairs,): how far each pair can move along the path
        slack = 0.5 * float(blocked_product(spans / per[:, None], levers).max())
        close = distance - reach < floor_m
        near = close.nonzero()[0]
        far = reach[~close]
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

    def _frame_positions(self, poses_rad: np.ndarray, links: tuple[str, str]) -> np.ndarray:
        """(N, 2, 3) positions (m) of two links' frames in the torso's frame, for N poses."""
        poses = np.atleast_2d(self._pose_array(poses_rad))
        frames = self._frames
        names = ("torso", *links)
        placed = frames.place(
            poses,
            np.array([frames.frame_of[name] for name in names]),
            np.array([frames.link_in_frame[name] for name in names]),
        )
        torso, offsets = placed[:, :1], placed[:, 1:, :3, 3] - placed[:, :1, :3, 3]
        # the torso's inverse applied to the points: R^T (p - t)
        return np.asarray(np.einsum("npba,npb->npa", torso[:, :, :3, :3], offsets))

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
        pose = self._pose_array(pose_rad).reshape(-1)
        return self._some_pairs(pose, np.arange(len(self.link_pairs)))

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
        self._known_m[:] = -np.inf

    def _pair_distance(self, pose_rad: np.ndarray, k: int) -> float:
        """Signed distance (m) of pair ``k`` of :attr:`link_pairs` alone in one pose."""
        return float(self._some_pairs(pose_rad, np.array([k]))[0])

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
