"""Body-aware sampling: the arm part's noise fades as its previous pose nears the body (ours).

A sampler's pose is its network's mean plus time-correlated noise
(:mod:`audio2pose_ros.models.live`). The network learned from poses kept clear of Pepper's body
(:mod:`audio2pose_ros.data.importers.body_clearance`), but the noise knows nothing of the body:
on speech unlike its training data, an excursion of the noise could carry a forearm to the
torso, and the noise's correlation kept it there for a second or more. So, where
``body_band_m`` > 0, the noise of the part that moves the arms is scaled at every frame by

    f_t = clip((c_{t-1} - body_margin_m) / body_band_m, 0, 1),

where c_{t-1} is the clearance of the previous sampled pose (the smallest signed distance between
an arm link and the rest of the body): far from the body the noise is whole; within
``body_band_m`` of the margin it fades, and at the margin the pose is the network's mean, which
leads back to poses like its training data. The factor changes by at most
:data:`MAX_FACTOR_STEP` a frame: the noise term is the pose's largest part, and a factor that
jumped would make the pose jump with it (faster than the robot can follow, so the motion
filter's input gate would drop it). The pose itself is never moved: the self-collision guard of
the motion filter (:mod:`audio2pose_ros.motion.body_guard`) stays what enforces the margin on the
robot, with the exact body model (:class:`~audio2pose_ros.robot.body.BodyModel`); this keeps the
model's own motion off the body, so the guard rarely has to act.

The clearance here is the capsule model's (:class:`~audio2pose_ros.robot.capsules.CapsuleModel`):
capsules that contain the URDF's collision shapes, so it is never larger than the exact
clearance and at most about 2.3 cm smaller near the body (median 1.6 mm;
``test/test_capsules.py``); the noise fades a little early, never late. It is plain numpy, so
the sampling process holds neither Pinocchio nor coal (about 55 MB), and the model pickles with
the sampler.

The first frame (no previous pose) samples with its whole noise. A query of every pair costs
more than the rest of the frame's work for the body, so each sequence keeps the last pose it
measured and every checked pair's distance there; each pair can have come nearer since by at
most its lever (:attr:`~audio2pose_ros.robot.capsules.CapsuleModel.pair_lever_m`) times each
joint's travel. The smallest of the distances so reduced is a lower bound of the clearance, and
the factor is taken from it; the pose is measured afresh only when that bound falls within
margin + band and has lost more than :data:`BOUND_SLACK_M` since the last measurement. Far from
the body no query is made at all (the factor is 1 either way); near it, an arm that moves
slowly is measured every few frames, and the clearance the factor uses is at most
``BOUND_SLACK_M`` below the capsules'. Poses must be finite: a NaN would slip past the bound,
so it is refused first.

One sequence (a streaming predictor, :meth:`BodyNoise.factor`) gives the same factors to the
last bit while measuring about a tenth of the pairs (``test/test_body_noise.py``, on the
packaged model and the bundled speech): each pair keeps its own lower bound, its distance
where it was measured, else a bound carried from pose to pose (less its travel and
:data:`BOUND_EPS_M`, far more than the rounding of the distances). A pose is measured where
the bound above says so, but only in the pairs whose own bound is below what the nearest
measured pair can have reached (plus :data:`PREFETCH_M`): no other pair can be the nearest,
so the clearance is the same. Between measurements, the bound above is the smallest of the
pairs' own bounds less their travel; where that smallest is not a measured pair's, the pairs
below the measured ones are measured, in the pose measured last. Far from the body the pairs'
own bounds settle everything. Numpy's calls, not the pairs, are most of the cost.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.capsules import CapsuleModel
from audio2pose_ros.robot.description import RobotDescription

MAX_BODY_BAND_M = 0.5  # wider than Pepper's arm: any larger band is a mistake
MAX_FACTOR_STEP = 0.05  # per frame: the noise fades over 0.2 s, never in one jump
BOUND_SLACK_M = 0.002  # the travel bound may fall this far below a measurement before the next
BOUND_EPS_M = 1e-6  # a pair's own bound is kept this far below: rounding cannot break it
PREFETCH_M = 0.04  # a measurement also measures the pairs this far beyond the nearest's reach
_SUM, _MIN = np.add.reduce, np.minimum.reduce  # without the wrappers of sum() and min()


def check_body_noise(margin_m: float, band_m: float) -> None:
    """Raise :class:`ConfigurationError` unless 0 <= margin <= 0.5 m and 0 <= band <= 0.5 m."""
    for name, value in (("body_margin_m", margin_m), ("body_band_m", band_m)):
        if not (isinstance(value, int | float) and math.isfinite(value)):
            raise ConfigurationError(f"{name} must be a finite number, got {value!r}")
        if not 0.0 <= value <= MAX_BODY_BAND_M:
            raise ConfigurationError(f"{name} must be in [0, {MAX_BODY_BAND_M}] m, got {value}")


class BodyNoise:
    """Noise factors f_t of the module text, for previous poses in [0, 1] units."""

    def __init__(self, robot: RobotDescription, margin_m: float, band_m: float) -> None:
        """Check the margin and band (m) and load the capsule model."""
        check_body_noise(margin_m, band_m)
        self.robot, self.margin_m, self.band_m = robot, float(margin_m), float(band_m)
        self.body = CapsuleModel.load(robot)
        self._limit = self.margin_m + self.band_m  # a bound below this can make a pose stale
        self._lever_t = self.body.pair_lever_m.T
        self._every_pair = np.arange(len(self.body.link_pairs))
        self._pairs = self.body.one_pose()  # one sequence: its measured pose, pair by pair
        self._at: np.ndarray | None = None  # ... the last pose measured, (1, J) rad
        self._bounds = np.empty(0)  # ... each pair's distance there, or a lower bound of it
        self._known = np.empty(0, dtype=bool)  # ... where the distance itself
        self._nearest = np.inf  # ... the clearance there
        self._factor = 1.0  # ... and its last factor
        self._measured: np.ndarray | None = None  # per sequence: the last pose measured (rad)
        self._distances = np.empty((0, 0))  # ... every checked pair's distance there (m)
        self._clearance = np.empty(0)  # ... and the smallest of them
        self._factors = np.empty(0)  # ... and its last factor

    def reset(self) -> None:
        """Forget the sequences' poses: the same poses then give the same factors."""
        self._measured = self._at = None

    def factors(self, previous_unit: np.ndarray) -> np.ndarray:
        """(N, J) previous poses in [0, 1] of N sequences -> (N,) noise factors in [0, 1].

        Row i continues sequence i of the previous call (until :meth:`reset`, or a call with
        another number of rows). One row is one sequence's :meth:`factor`.

        Raises:
            ValueError: a pose is not finite.
        """
        previous = np.atleast_2d(previous_unit)
        if len(previous) == 1:
            self._measured = None
            return np.array([self.factor(previous[0])])
        self._at = None
        return self._factors_of_rows(previous)

    def factor(self, previous_unit: np.ndarray) -> float:
        """One sequence's noise factor in [0, 1] for its (J,) previous pose in [0, 1].

        The factor of :meth:`factors` of the pose as one row, to the last bit, which measures
        every pair of a stale pose; here each pair keeps its own lower bound, and only the
        pairs that can be the nearest are measured (the module text).

        Raises:
            ValueError: the pose is not finite.
        """
        # finite terms have a finite sum, except where it overflows: then each one is checked
        if not math.isfinite(_SUM(previous_unit)) and not np.isfinite(previous_unit).all():
            raise ValueError("body-aware sampling: the previous pose is not finite")
        pose = self.robot.denormalize(previous_unit[None])  # (1, J): the rows' products
        if self._at is None:
            self._factor = 1.0
            wanted = self._wanted(self._measure(pose))
        else:
            travel = (np.abs(pose - self._at) @ self._lever_t)[0]
            # per pair: at most its distance less its travel, the bound of the module text
            # (equal to it where the distance is known)
            near = self._bounds - travel
            nearest = int(near.argmin())
            lower = near[nearest]
            if lower >= self._limit and (lower - self.margin_m) / self.band_m >= 1.0:
                wanted = 1.0  # far from the body: not stale, and the factor is whole
            else:
                if not self._known[nearest]:  # the bound is a pair's own: make it exact
                    lower = self._settle(near, travel)
                if lower < self._limit and self._nearest - lower > BOUND_SLACK_M:
                    lower = self._measure(pose, near, travel)
                wanted = self._wanted(lower)
        step = MAX_FACTOR_STEP
        self._factor = min(max(wanted, self._factor - step), self._factor + step)
        return float(self._factor)

    def _wanted(self, lower: float) -> float:
        """clip((lower - margin) / band, 0, 1), as numpy computes it (a band of 0 included)."""
        return min(max((np.float64(lower) - self.margin_m) / self.band_m, 0.0), 1.0)

    def _settle(self, near: np.ndarray, travel: np.ndarray) -> float:
        """The smallest of the distances at the measured pose less their travel, exactly.

        Pairs measured there give theirs; the others are measured there (the placed pose)
        where their own bound falls below the smallest of those.
        """
        known = self._known
        exact = _MIN(near[known])  # a measured pose has a pair measured: the nearest
        todo = (~known & (near < exact)).nonzero()[0]
        if not len(todo):
            return exact
        distances = self._pairs.distances(todo)
        self._bounds[todo], known[todo] = distances, True
        return min(exact, _MIN(distances - travel[todo]))

    def _measure(
        self, pose: np.ndarray, near: np.ndarray | None = None, travel: np.ndarray | None = None
    ) -> float:
        """The clearance of ``pose`` (1, J), now the measured pose.

        Each pair's distance there is at least its ``near`` (its bound less its travel) less
        :data:`BOUND_EPS_M`; the nearest measured pair's is at most its distance plus its
        travel (plus the same). Only the pairs whose bound is below that, plus
        :data:`PREFETCH_M`, are measured: the others cannot be the nearest. Without ``near``
        (the first pose) every pair is measured.
        """
        if near is None or travel is None:
            todo, bounds = self._every_pair, np.empty(len(self._every_pair))
        else:
            bounds = near - BOUND_EPS_M
            reach = _MIN((self._bounds + travel)[self._known])
            todo = (bounds < reach + (BOUND_EPS_M + PREFETCH_M)).nonzero()[0]
        self._pairs.place(pose[0])
        distances = self._pairs.distances(todo)
        bounds[todo] = distances
        self._known = np.zeros(len(bounds), dtype=bool)
        self._known[todo] = True
        self._at, self._bounds, self._nearest = pose, bounds, _MIN(distances)
        return self._nearest

    def _factors_of_rows(self, previous: np.ndarray) -> np.ndarray:
        """:meth:`factors` of N rows, every pair of a stale row measured."""
        if not np.isfinite(previous).all():
            raise ValueError("body-aware sampling: the previous pose is not finite")
        poses = self.robot.denormalize(previous)
        if self._measured is None or self._measured.shape != poses.shape:
            self._measured = poses.copy()
            self._distances = np.full((len(poses), len(self.body.link_pairs)), -np.inf)
            self._clearance = np.full(len(poses), np.inf)  # unmeasured: stale at once
            self._factors = np.ones(len(poses))
        travel = np.abs(poses - self._measured) @ self._lever_t
        # no pair nearer than this: its shapes cannot have come closer
        lower = (self._distances - travel).min(axis=1)
        stale = (lower < self._limit) & (self._clearance - lower > BOUND_SLACK_M)
        if stale.all():
            self._measured, self._distances = poses, self.body.pair_distances(poses)
            lower = self._clearance = self._distances.min(axis=1)
        elif stale.any():
            self._measured[stale] = poses[stale]
            self._distances[stale] = self.body.pair_distances(poses[stale])
            lower[stale] = self._clearance[stale] = self._distances[stale].min(axis=1)
        wanted = np.minimum(np.maximum((lower - self.margin_m) / self.band_m, 0.0), 1.0)
        step = MAX_FACTOR_STEP
        self._factors = np.minimum(np.maximum(wanted, self._factors - step), self._factors + step)
        return self._factors.copy()


def body_noise_for(
    robot: RobotDescription | None,
    groups: Sequence[np.ndarray],
    margin_m: float,
    band_m: float,
) -> tuple[BodyNoise | None, int]:
    """Body-aware factors for the part of ``groups`` (joint indices) that moves an arm.

    Returns:
        The factors and the part's index; (None, -1) when the band is 0, there is no robot,
        or no part moves an arm joint.

    """
    if robot is None or not band_m:
        return None, -1
    arms = np.flatnonzero(robot.group_mask("arms"))
    part = next((k for k, joints in enumerate(groups) if np.isin(joints, arms).any()), -1)
    if part < 0:
        return None, -1
    return BodyNoise(robot, margin_m, band_m), part
