"""Body-aware sampling: the arm part's noise fades as its previous pose nears the body (ours).

A sampler's pose is its network's mean plus time-correlated noise
(:mod:`audio2pose_ros.models.live`). The network learned from poses kept clear of Pepper's body
(:mod:`audio2pose_ros.data.importers.body_clearance`), but the noise knows nothing of the body:
on speech unlike its training data, an excursion of the noise could carry a forearm to the
torso, and the noise's correlation kept it there for a second or more. So, where
``body_band_m`` > 0, the noise of the part that moves the arms is scaled at every frame by

    f_t = clip((c_{t-1} - body_margin_m) / body_band_m, 0, 1),

where c_{t-1} is the clearance of the previous sampled pose (the smallest signed distance between
an arm link and the rest of the body, :meth:`~audio2pose_ros.robot.body.BodyModel.clearance`):
far from the body the noise is whole; within ``body_band_m`` of the margin it fades, and at the
margin the pose is the network's mean, which leads back to poses like its training data. The
factor changes by at most :data:`MAX_FACTOR_STEP` a frame: the noise term is the pose's largest
part, and a factor that jumped would make the pose jump with it (faster than the robot can
follow, so the motion filter's input gate would drop it). The
pose itself is never moved: the self-collision guard of the motion filter
(:mod:`audio2pose_ros.motion.body_guard`) stays what enforces the margin on the robot; this keeps
the model's own motion off the body, so the guard rarely has to act.

The first frame (no previous pose) samples with its whole noise. A distance query costs about
0.1 ms, so each sequence keeps the last pose it measured: while that pose's clearance, less the
most the arms can have come nearer since (:attr:`~audio2pose_ros.robot.body.BodyModel.lever_m`
times each joint's travel), is still beyond margin + band, the factor is 1 without a query (the
query would give 1 too). Each :class:`BodyNoise` loads its own
:class:`~audio2pose_ros.robot.body.BodyModel` (Pinocchio's workspaces are not shared between
threads) when it is made, so that a streaming predictor's first frame does not wait for
Pinocchio, coal and the URDF (0.3 s here, seconds on a cold, busy machine); it drops the model
when pickled and loads it again on first use.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.robot.kinematics import default_urdf_path

MAX_BODY_BAND_M = 0.5  # wider than Pepper's arm: any larger band is a mistake
MAX_FACTOR_STEP = 0.05  # per frame: the noise fades over 0.2 s, never in one jump


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
        """Check the margin and band (m) and load the body model."""
        check_body_noise(margin_m, band_m)
        self.robot, self.margin_m, self.band_m = robot, float(margin_m), float(band_m)
        self._body: BodyModel | None = BodyModel(robot, default_urdf_path())
        self._measured: np.ndarray | None = None  # per sequence: the last pose measured (rad)
        self._clearance = np.empty(0)  # ... and its clearance (m)
        self._factors = np.empty(0)  # ... and its last factor

    @property
    def loaded(self) -> bool:
        """Whether the body model is loaded (False only after unpickling, until first use)."""
        return self._body is not None

    def __getstate__(self) -> dict[str, Any]:
        """Pickle without the body model (Pinocchio's objects do not pickle)."""
        return {**self.__dict__, "_body": None}

    def reset(self) -> None:
        """Forget the sequences' poses and start the distance searches afresh.

        The same poses then give the same factors, whatever was sampled before.
        """
        self._measured = None
        if self._body is not None:
            self._body.reset()

    def factors(self, previous_unit: np.ndarray) -> np.ndarray:
        """(N, J) previous poses in [0, 1] of N sequences -> (N,) noise factors in [0, 1].

        Row i continues sequence i of the previous call (until :meth:`reset`).
        """
        if self._body is None:
            self._body = BodyModel(self.robot, default_urdf_path())
        poses = self.robot.denormalize(np.atleast_2d(previous_unit))
        if self._measured is None or self._measured.shape != poses.shape:
            self._measured, self._clearance = poses.copy(), np.full(len(poses), -np.inf)
            self._factors = np.ones(len(poses))
        travel = np.abs(poses - self._measured) @ self._body.lever_m
        lower = self._clearance - travel  # no nearer than this: the arms cannot have come closer
        stale = lower < self.margin_m + self.band_m
        if stale.any():
            self._measured[stale] = poses[stale]
            self._clearance[stale] = self._body.clearance(poses[stale])
            lower[stale] = self._clearance[stale]
        wanted = np.clip((lower - self.margin_m) / self.band_m, 0.0, 1.0)
        step = MAX_FACTOR_STEP
        self._factors = np.clip(wanted, self._factors - step, self._factors + step)
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
