"""A simulated Pepper: the package's URDF in pybullet, driven the way naoqi_driver drives Pepper.

What a robot does with our commands (how fast it moves, how far it lags, what its measured joint
states look like) is tested against this model when no Pepper is at hand:

- **Commands** have ALMotion's ``setAngles`` meaning, which naoqi_driver calls for every
  ``JointAnglesWithSpeed``: non-blocking, each command replaces the previous target of its
  joints, and ``speed`` is a fraction of each joint's maximum velocity. Every joint is a pybullet
  position-controlled motor whose speed is capped at that fraction of its velocity limit (as
  qiBullet, SoftBank's research simulator, maps ``setAngles``), with targets clamped into the
  joint's range. A ros2_control trajectory is followed point by point in time, at full speed.
- **Physics**: pybullet steps of ``STEP_S`` with the base fixed and gravity compensated (Pepper's
  motors hold the arms; what matters here is speed and lag, not sag). A joint that a step
  carries past its limit (pybullet's motors overshoot a target at the limit by up to about
  0.01 rad) is put back on it at rest, as a mechanical stop would hold it.
- **Measured**: positions and velocities of the robot description's joints, as naoqi_driver
  publishes them on ``joint_states``.
- **Self-collisions executed**: every step the measured pose is checked against the body model
  (:class:`~audio2pose_ros.robot.body.BodyModel`); poses with an arm inside the body are counted.

What it is not: Pepper's own motor dynamics, ALMotion's arm collision protection, or its
smoothing of ``setAngles`` targets.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription, load_robot
from audio2pose_ros.robot.kinematics import default_urdf_path
from audio2pose_ros.robot.quiet import quiet_c_output

STEP_S = 1.0 / 200.0  # pybullet time step (s); the node advances the simulation in these steps
MOTOR_FORCE_N_M = 50.0  # enough to reach any target at the capped speed (no sag, no overshoot)
POSITION_GAIN = 0.5  # pybullet's positionGain of the motors: converges within a few steps


@dataclass
class SimulationCounts:
    """What the simulated robot did (since start)."""

    commands: int = 0
    refused: int = 0  # commands with unknown joints, non-finite angles or a bad speed
    steps: int = 0
    self_collision_steps: int = 0  # steps with an arm link inside the body
    deepest_m: float = 0.0  # deepest penetration seen (m)


class SimulatedPepper:
    """Pepper's joints in pybullet, commanded like ALMotion (see the module text)."""

    def __init__(
        self, robot: RobotDescription | None = None, urdf_path: Path | None = None
    ) -> None:
        """Load the URDF with its base fixed, at the robot's neutral pose, at rest."""
        import pybullet

        self.robot = robot or load_robot()
        self._p: Any = pybullet
        self._client = pybullet.connect(pybullet.DIRECT)
        path = str(urdf_path or default_urdf_path())
        with quiet_c_output():  # the URDF importer warns of links without inertia
            self._body = pybullet.loadURDF(path, useFixedBase=True, physicsClientId=self._client)
        pybullet.setTimeStep(STEP_S, physicsClientId=self._client)
        pybullet.setGravity(0.0, 0.0, 0.0, physicsClientId=self._client)
        by_name = {
            pybullet.getJointInfo(self._body, i, physicsClientId=self._client)[1].decode(): i
            for i in range(pybullet.getNumJoints(self._body, physicsClientId=self._client))
        }
        missing = [name for name in self.robot.names if name not in by_name]
        if missing:
            raise InputError(f"{path} has no joints {missing} of the robot description")
        self._index = [by_name[name] for name in self.robot.names]
        self._position_of = {name: i for i, name in enumerate(self.robot.names)}
        self.body = BodyModel.load(self.robot, Path(path))
        self.counts = SimulationCounts()
        self.time_s = 0.0
        self._trajectory: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        neutral = self.robot.neutral_rad
        for joint, value in zip(self._index, neutral, strict=True):
            pybullet.resetJointState(self._body, joint, float(value), physicsClientId=self._client)
        self._targets = neutral.copy()
        self._speeds = self.robot.max_velocity_rad_s.copy()
        self._drive()

    def close(self) -> None:
        """Disconnect from pybullet."""
        if self._client >= 0:
            self._p.disconnect(physicsClientId=self._client)
            self._client = -1

    def _joints(self, names: Sequence[str], values: Sequence[float]) -> np.ndarray:
        if len(names) != len(values):
            raise InputError(f"{len(names)} joint names but {len(values)} angles")
        unknown = [name for name in names if name not in self._position_of]
        if unknown:
            raise InputError(f"unknown joints {unknown}")
        angles = np.asarray(values, dtype=np.float64)
        if not np.isfinite(angles).all():
            raise InputError("angles must be finite")
        return np.array([self._position_of[name] for name in names], dtype=np.int64)

    def set_angles(self, names: Sequence[str], angles: Sequence[float], speed: float) -> None:
        """ALMotion ``setAngles``: new targets for ``names`` at ``speed`` x their velocity limit.

        Raises:
            InputError: unknown joints, mismatched lengths, non-finite angles, or a speed
                outside (0, 1]. Nothing is changed then.
        """
        try:
            index = self._joints(names, angles)
            if not (np.isfinite(speed) and 0.0 < speed <= 1.0):
                raise InputError(f"speed must be in (0, 1], got {speed!r}")
        except InputError:
            self.counts.refused += 1
            raise
        self.counts.commands += 1
        self._trajectory = None
        lower, upper = self.robot.lower_rad[index], self.robot.upper_rad[index]
        self._targets[index] = np.clip(np.asarray(angles, dtype=np.float64), lower, upper)
        self._speeds[index] = self.robot.max_velocity_rad_s[index] * speed
        self._drive()

    def follow(self, names: Sequence[str], times_s: Sequence[float], positions: np.ndarray) -> None:
        """A ros2_control trajectory: pass each point at its time (from now), linearly between.

        Raises:
            InputError: unknown joints, a shape that does not match, non-finite values, or
                times that are not increasing and non-negative.
        """
        points = np.asarray(positions, dtype=np.float64)
        times = np.asarray(times_s, dtype=np.float64)
        try:
            if points.ndim != 2 or points.shape != (len(times), len(names)) or len(times) == 0:
                raise InputError(f"trajectory of shape {points.shape} for {len(names)} joints")
            index = self._joints(names, points[0])
            if not (np.isfinite(points).all() and np.isfinite(times).all()):
                raise InputError("trajectory values must be finite")
            if times[0] < 0.0 or np.any(np.diff(times) <= 0.0):
                raise InputError("trajectory times must be non-negative and increasing")
        except InputError:
            self.counts.refused += 1
            raise
        self.counts.commands += 1
        lower, upper = self.robot.lower_rad[index], self.robot.upper_rad[index]
        start = self.measured()[0][index]
        self._trajectory = (
            index,
            np.concatenate([[self.time_s], self.time_s + times]),
            np.vstack([start, np.clip(points, lower, upper)]),
        )
        self._speeds[index] = self.robot.max_velocity_rad_s[index]

    def _drive(self) -> None:
        p = self._p
        for joint, target, speed in zip(self._index, self._targets, self._speeds, strict=True):
            p.setJointMotorControl2(
                self._body,
                joint,
                p.POSITION_CONTROL,
                targetPosition=float(target),
                maxVelocity=float(speed),
                force=MOTOR_FORCE_N_M,
                positionGain=POSITION_GAIN,
                physicsClientId=self._client,
            )

    def step(self, duration_s: float) -> None:
        """Advance the simulation by ``duration_s`` (whole steps of ``STEP_S``)."""
        for _ in range(max(1, round(duration_s / STEP_S))):
            if self._trajectory is not None:  # the trajectory's pose one step ahead
                index, times, points = self._trajectory
                ahead = self.time_s + STEP_S
                self._targets[index] = [np.interp(ahead, times, column) for column in points.T]
                self._drive()
            self._p.stepSimulation(physicsClientId=self._client)
            self.time_s += STEP_S
            self.counts.steps += 1
            position = self._stop_at_limits(self.measured()[0])
            clearance = float(self.body.clearance(position))
            if clearance < 0.0:
                self.counts.self_collision_steps += 1
                self.counts.deepest_m = max(self.counts.deepest_m, -clearance)

    def _stop_at_limits(self, position: np.ndarray) -> np.ndarray:
        """Put every joint beyond its limit back on it, at rest; the positions after that."""
        held = np.clip(position, self.robot.lower_rad, self.robot.upper_rad)
        for k in np.flatnonzero(held != position):
            self._p.resetJointState(
                self._body, self._index[k], float(held[k]), 0.0, physicsClientId=self._client
            )
        return held

    def measured(self) -> tuple[np.ndarray, np.ndarray]:
        """``(positions_rad, velocities_rad_s)`` of the robot description's joints."""
        states = self._p.getJointStates(self._body, self._index, physicsClientId=self._client)
        positions = np.array([s[0] for s in states])
        velocities = np.array([s[1] for s in states])
        return positions, velocities
