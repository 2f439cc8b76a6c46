"""Pepper's body as capsules that contain its collision shapes: a cheap, conservative clearance.

Body-aware sampling (:mod:`audio2pose_ros.models.body_noise`) asks, at most frames of speech, how
close the previous sampled pose came to the body. It needs no exact answer, only one that never
says "clear" where the body is near: this model bounds every ``<collision>`` primitive of the
URDF (read by :class:`~audio2pose_ros.robot.kinematics.RobotKinematics`; nothing here is
hand-written geometry) by capsules (segments swept by a sphere) that contain it, places them
with numpy forward kinematics, and measures segment-to-segment distances for the pairs of
:func:`~audio2pose_ros.robot.pairs.checked_pair`, all poses and pairs at once. It imports
neither Pinocchio nor coal, so the process that samples does not hold them (about 55 MB); the
self-collision guard keeps the exact model (:class:`~audio2pose_ros.robot.body.BodyModel`).

**Bounding.** A sphere is its own capsule. A cylinder of radius r and half-length h is bounded
by the capsule on its axis with radius R = r + SIDE_REACH_M and half-length s, where
R^2 = r^2 + (h - s)^2 puts the cylinder's rims on the capsule's end spheres: the capsule reaches
1 mm beyond the side and R - (h - s) beyond the middle of each flat end (most for the fattest
cylinder, the torso: 8.7 cm; an end sphere fits a flat end no better). A box is cut
along its middle side into pieces about as wide as it is thick; each piece is bounded as a
cylinder on the box's long axis whose radius is the piece's half-diagonal. Capsules contain
their shapes, so where the shapes are apart, the capsule distance is never larger than the
exact one; ``test/test_capsules.py`` measures how much smaller it is (on 3,000 poses within the
joint limits: at most 2.6 cm, and within 5 cm of the body at most 2.3 cm, median 1.6 mm).

**Travel bound.** :attr:`CapsuleModel.pair_lever_m` (like the exact model's pair levers): turning
joint j by d changes the distance of pair k by at most ``pair_lever_m[k, j] * |d|``, bounded
along the kinematic chain by the joint offsets below j, the capsule's farthest end from its
link's origin and its radius; a joint that moves both capsules of a pair counts 0.

Joints the speech model does not drive stay at zero, as in the exact model. Distances are
signed, in metres (negative: the capsules overlap by that much).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.robot.kinematics import (
    DrivenFrames,
    RobotKinematics,
    UrdfCollision,
    default_urdf_path,
)
from audio2pose_ros.robot.pairs import checked_pair, pose_array

SIDE_REACH_M = 0.001  # a capsule reaches this far beyond the side of the shape it bounds
POSE_BLOCK = 64  # poses measured at once
MAX_PIECES = 8  # a box is cut into at most this many pieces
_TINY = np.full((), 1e-12)  # squared lengths below this are points
_ZERO, _ONE = np.zeros(()), np.ones(())  # (0-d arrays: quicker in ufuncs than Python floats)


class CapsuleModelError(ConfigurationError):
    """The URDF lacks a joint of the robot description or has a shape capsules cannot bound."""


def bounding_capsules(shape: UrdfCollision) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules ``(end_a, end_b, radius)`` in the link's frame whose union contains ``shape``.

    Raises:
        CapsuleModelError: the shape is not a box, a cylinder or a sphere.
    """
    rotation, centre = shape.origin[:3, :3], shape.origin[:3, 3]
    if shape.kind == "sphere":
        return [(centre.copy(), centre.copy(), shape.size[0])]
    if shape.kind == "cylinder":
        radius, half = shape.size[0], 0.5 * shape.size[1]
        axis, pieces = rotation[:, 2], [(np.zeros(3), radius)]
    elif shape.kind == "box":
        halves = 0.5 * np.asarray(shape.size)
        long, middle, thin = np.argsort(halves)[::-1]
        count = min(MAX_PIECES, math.ceil(halves[middle] / halves[thin] - 1e-9))
        width = halves[middle] / count  # half-width of each piece along the middle side
        half, axis = float(halves[long]), rotation[:, long]
        offsets = (2 * np.arange(count) - (count - 1)) * width
        pieces = [(rotation[:, middle] * o, float(np.hypot(width, halves[thin]))) for o in offsets]
    else:
        raise CapsuleModelError(
            f"collision shape {shape.kind} of link {shape.link} is not supported "
            f"(use boxes, cylinders, spheres)"
        )
    out = []
    for offset, section in pieces:
        inset = min(half, math.sqrt(SIDE_REACH_M * (2.0 * section + SIDE_REACH_M)))
        reach, capsule_radius = half - inset, float(np.hypot(section, inset))
        middle_point = centre + offset
        out.append((middle_point - reach * axis, middle_point + reach * axis, capsule_radius))
    return out


def segment_distances(
    start_a: np.ndarray, end_a: np.ndarray, start_b: np.ndarray, end_b: np.ndarray
) -> np.ndarray:
    """Distances between the segments [start_a, end_a] and [start_b, end_b], row by row (m).

    Arrays (M, 3); see :func:`_segment_gaps`.
    """
    vectors = np.stack([end_a - start_a, end_b - start_b, start_a - start_b], axis=1)
    return _segment_gaps(vectors.T[:, None])[0]


def _segment_gaps(vectors: np.ndarray) -> np.ndarray:
    """(3, N, 3, P) components of d1 = b1 - a1, d2 = b2 - a2, r = a1 - a2 -> (N, P) distances.

    The closest points a1 + s d1 and a2 + t d2 come from clamping the line parameters to
    [0, 1]: s from the lines' closest points, t on segment 2 for that s, and s again for that t
    (Ericson, *Real-Time Collision Detection*, 2005, section 5.1.9, with its cases folded into
    the last step: recomputing an s that was not clamped gives it back). Zero-length segments
    (spheres) and parallel ones need no case of their own: a zero length makes its parameter 0,
    and between parallel segments any first s leads to a closest pair.
    """
    products = vectors[:, :, :2, None] * vectors[:, :, None]  # (3, N, 2, 3, P)
    gram = products[0] + products[1]  # (N, 2, 3, P): summed as sum(axis=0) sums, in place
    gram += products[2]
    a, b, c = gram[:, 0, 0], gram[:, 0, 1], gram[:, 0, 2]
    e, f = gram[:, 1, 1], gram[:, 1, 2]
    s = b * f
    s -= c * e
    denominator = a * e
    denominator -= b * b
    s /= np.maximum(denominator, _TINY, out=denominator)
    t = b * _unit(s)
    t += f
    t /= np.maximum(e, _TINY)
    s = b * _unit(t)
    s -= c
    s /= np.maximum(a, _TINY)
    gap = _unit(s) * vectors[:, :, 0]  # r + s d1 - t d2: (3, N, P)
    gap += vectors[:, :, 2]
    gap -= t * vectors[:, :, 1]
    gap *= gap
    distances = gap[0] + gap[1]
    distances += gap[2]
    return np.sqrt(distances, out=distances)


def _unit(x: np.ndarray) -> np.ndarray:
    """``x`` clamped to [0, 1], in place (two ufuncs: quicker than ``np.clip`` on small arrays)."""
    np.maximum(x, _ZERO, out=x)
    return np.minimum(x, _ONE, out=x)


_LOADED: dict[tuple[RobotDescription, Path], CapsuleModel] = {}


class CapsuleModel:
    """Conservative clearance of Pepper's arms from its body, for poses in the robot's order.

    Plain numpy arrays: it pickles, and one instance may serve several threads.
    """

    def __init__(self, robot: RobotDescription, urdf_path: Path | None = None) -> None:
        """Bound ``urdf_path``'s collision shapes (default: the packaged URDF) by capsules.

        Raises:
            CapsuleModelError: the URDF lacks one of the robot's joints, has a shape capsules
                cannot bound, or no arm link to check.
        """
        kinematics = RobotKinematics(urdf_path or default_urdf_path())
        self.robot = robot
        movable = kinematics.movable_joint_names
        missing = [name for name in robot.names if name not in movable]
        if missing:
            raise CapsuleModelError(f"{kinematics.urdf_path} has no movable joints {missing}")
        self._frames = DrivenFrames(kinematics, robot.names)
        capsules = [
            (shape.link, *capsule)
            for shape in kinematics.collisions
            for capsule in bounding_capsules(shape)
        ]
        self.capsule_links = tuple(link for link, *_ in capsules)
        # each capsule's ends in the frame of the driven joint that last moves its link
        self._capsule_frame = np.array([self._frames.frame_of[link] for link in self.capsule_links])
        placed = [self._frames.link_in_frame[link] for link in self.capsule_links]
        self._ends = np.array(
            [
                [place[:3, :3] @ end + place[:3, 3] for end in (a, b)]
                for place, (_, a, b, _) in zip(placed, capsules, strict=True)
            ]
        ).reshape(-1, 2, 3)
        # each capsule end (2 C of them, a capsule's two in a row) homogeneous, and its frame
        self._points = np.concatenate(
            [self._ends.reshape(-1, 3), np.ones((2 * len(capsules), 1))], 1
        )
        self._point_chains = self._frames.chains(np.repeat(self._capsule_frame, 2))
        self._radii = np.array([radius for *_, radius in capsules])
        pairs = [
            (i, j)
            for i, a in enumerate(self.capsule_links)
            for j, b in enumerate(self.capsule_links)
            if checked_pair(a, b)
        ]
        if not pairs:
            raise CapsuleModelError(f"{kinematics.urdf_path}: no arm link to check")
        self._pair_a = np.array([i for i, _ in pairs])
        self._pair_b = np.array([j for _, j in pairs])
        self._pair_radii = self._radii[self._pair_a] + self._radii[self._pair_b]
        # per pair, the points (capsule ends, a capsule's two in a row) that give d1, d2, r
        a1, a2 = 2 * self._pair_a, 2 * self._pair_b
        b1, b2 = a1 + 1, a2 + 1
        self._pair_heads, self._pair_tails = np.stack([b1, b2, a1]), np.stack([a1, a2, a2])
        self.link_pairs = tuple((self.capsule_links[i], self.capsule_links[j]) for i, j in pairs)
        levers = self._levers(kinematics)
        # a joint that moves both capsules of a pair moves them together: it cannot change
        # their distance (as in the exact model's pair levers)
        moved = levers > 0.0
        self.pair_lever_m = np.where(
            moved[self._pair_a] & ~moved[self._pair_b], levers[self._pair_a], 0.0
        ) + np.where(moved[self._pair_b] & ~moved[self._pair_a], levers[self._pair_b], 0.0)

    @classmethod
    def load(
        cls, robot: RobotDescription | None = None, urdf_path: Path | None = None
    ) -> CapsuleModel:
        """The packaged Pepper URDF and robot description unless others are given.

        One model per robot description and URDF is kept and shared by the callers of one
        process (it holds no state between queries).
        """
        key = (robot or load_robot(), Path(urdf_path or default_urdf_path()).resolve())
        model = _LOADED.get(key)
        if model is None:
            model = _LOADED[key] = cls(*key)
        return model

    def _levers(self, kinematics: RobotKinematics) -> np.ndarray:
        """(n_capsules, n_joints): how far each capsule can be from each joint's axis (m).

        The joint offsets below the joint on the capsule's chain, plus the capsule's farthest
        end from its link's origin and its radius; 0 for a joint that does not move it.
        """
        by_child = {joint.child: joint for joint in kinematics.joints}
        levers = np.zeros((len(self._radii), self.robot.n_joints))
        for c, link in enumerate(self.capsule_links):
            place = self._frames.link_in_frame[link]  # the ends back in the link's own frame
            ends = (self._ends[c] - place[:3, 3]) @ place[:3, :3]
            reach = float(np.linalg.norm(ends, axis=1).max() + self._radii[c])
            while link in by_child:  # up the chain: the joint whose child the link is
                joint = by_child[link]
                if joint.name in self.robot.names:
                    levers[c, self.robot.names.index(joint.name)] = reach
                reach += float(np.linalg.norm(joint.origin[:3, 3]))
                link = joint.parent
        return levers

    def _pose_array(self, poses_rad: np.ndarray) -> np.ndarray:
        return pose_array(poses_rad, self.robot.n_joints)

    def capsule_ends(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, n_capsules, 2, 3) ends of every capsule (m, root link's frame) in N poses."""
        points = self._points_of(np.atleast_2d(self._pose_array(poses_rad)))  # (N, 2 C, 3)
        return points.reshape(len(points), -1, 2, 3)

    def _points_of(self, poses: np.ndarray) -> np.ndarray:
        """(N, 2 C, 3) capsule ends of N checked (N, n_joints) poses."""
        return self._frames.carry(poses, self._point_chains, self._points)[..., :3]

    def pair_distances(self, poses_rad: np.ndarray) -> np.ndarray:
        """(N, n_pairs) signed distances (m) of the checked capsule pairs (:attr:`link_pairs`)."""
        poses = np.atleast_2d(self._pose_array(poses_rad))
        if len(poses) > POSE_BLOCK:  # bounded working memory (about 4 MB a block)
            blocks = range(0, len(poses), POSE_BLOCK)
            return np.concatenate([self._distances(poses[i : i + POSE_BLOCK]) for i in blocks])
        return self._distances(poses)

    def _distances(self, poses: np.ndarray) -> np.ndarray:
        """:meth:`pair_distances` of checked (N, n_joints) poses."""
        points = self._points_of(poses)
        # each pair's d1 = b1 - a1, d2 = b2 - a2, r = a1 - a2, components first: (3, N, 3, P)
        columns = np.ascontiguousarray(points.transpose(2, 0, 1))  # (3, N, 2 C)
        vectors = columns.take(self._pair_heads, axis=2) - columns.take(self._pair_tails, axis=2)
        return _segment_gaps(vectors) - self._pair_radii

    def one_pose(self) -> PosePairs:
        """A :class:`PosePairs` of this model (one pose at a time, chosen pairs)."""
        return PosePairs(self)

    def clearance(self, poses_rad: np.ndarray) -> np.ndarray:
        """Smallest signed distance (m) of the checked pairs: shape () for one pose, (N,) for N.

        Never larger than :meth:`~audio2pose_ros.robot.body.BodyModel.clearance` where that is
        at least 0 (the capsules contain the shapes).
        """
        poses = self._pose_array(poses_rad)
        smallest = self.pair_distances(poses).min(axis=1)
        return smallest[0] if poses.ndim == 1 else smallest


class PosePairs:
    """:meth:`CapsuleModel.pair_distances` of one pose at a time, of the pairs asked for only.

    :meth:`place` carries every capsule end into a pose (one
    :class:`~audio2pose_ros.robot.kinematics.PointCarrier`, into reused arrays);
    :meth:`distances` measures chosen pairs there, with the arithmetic of
    :meth:`CapsuleModel.pair_distances`, so each pair's distance is the same to the last bit
    (``test/test_capsules.py``). Body-aware sampling measures the few pairs that can be the
    nearest, not all of them. An instance serves one thread; it pickles as its model and the
    pose placed.
    """

    def __init__(self, model: CapsuleModel) -> None:
        """Measure ``model``'s pairs; no pose placed yet."""
        self._model = model
        self._carrier = model._frames.carrier(model._point_chains, model._points)
        self._columns = self._carrier.carried[:, :3].T  # (3, 2 C), a view of the carried ends
        # per pair, the points that give d1, d2, r (the heads) and those they are taken from
        self._ends = np.concatenate([model._pair_heads, model._pair_tails])  # (6, P)
        self._pose: np.ndarray | None = None

    def __reduce__(
        self,
    ) -> tuple[type[PosePairs], tuple[CapsuleModel], np.ndarray | None]:
        return PosePairs, (self._model,), self._pose

    def __setstate__(self, pose: np.ndarray | None) -> None:
        if pose is not None:
            self.place(pose)

    def place(self, pose_rad: np.ndarray) -> None:
        """Carry the capsules into the (n_joints,) pose (finite angles, the robot's order)."""
        self._pose = np.array(pose_rad, dtype=np.float64)
        self._carrier.carry(self._pose)

    def distances(self, pairs: np.ndarray) -> np.ndarray:
        """(M,) signed distances (m) in the placed pose of ``pairs`` (indices of link_pairs)."""
        points = self._columns.take(self._ends.take(pairs, axis=1), axis=1)  # (3, 6, M)
        vectors = points[:, :3] - points[:, 3:]  # d1, d2, r: (3, 3, M)
        distances = _segment_gaps(vectors[:, None])[0]
        distances -= self._model._pair_radii.take(pairs)
        return distances
