"""Joint limit enforcement: position, then velocity, then acceleration (applied last, in one place).

Everything that leaves the package for a robot passes :meth:`JointLimiter.enforce`. The order is
the ros2_control saturation limiter's: clamp the position target into the (margin-shrunk) range,
limit the velocity needed to reach it, then limit the change of velocity. A braking bound keeps
the velocity low enough near a position limit that the joint can always stop inside it at the
acceleration limit, so all three limits hold together from any feasible start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.parameters import param, validate_settings
from audio2pose_ros.robot.description import RobotDescription

MIN_DT_S = 1e-6  # shorter steps are timer noise: velocities over them would only amplify rounding


def stop_rate(velocity_rad_s: np.ndarray, decel_rad_s2: np.ndarray) -> float:
    """How fast every joint can brake together (1/s): the lowest ``decel / |v|`` of a moving joint.

    Braking together scales every joint's velocity by one factor that falls at this rate, so
    the joints stop at the same moment and each decelerates at most at its ``decel_rad_s2``.
    inf when no joint moves.
    """
    speed = np.abs(velocity_rad_s)
    moving = speed > 0.0
    if not moving.any():
        return math.inf
    return float((decel_rad_s2[moving] / speed[moving]).min())


def brake_together(velocity_rad_s: np.ndarray, decel_rad_s2: np.ndarray, dt_s: float) -> np.ndarray:
    """The velocity after braking every joint together for ``dt_s`` (:func:`stop_rate`).

    The direction is kept: the joints move on along the straight line they move on now, and
    whatever the ticks, they stop on it within ``velocity / (2 * stop_rate)`` of where they
    are (each tick moves at the tick's final speed, less than the continuous braking).
    """
    rate = stop_rate(velocity_rad_s, decel_rad_s2)
    scale = max(0.0, 1.0 - rate * dt_s) if math.isfinite(rate) else 0.0
    return np.asarray(velocity_rad_s * scale, dtype=np.float64)


@dataclass(frozen=True)
class LimitSettings:
    """How much of the robot's published limits the limiter allows (node parameters).

    Attributes:
        position_margin_rad: keep this far inside each position limit (rad, default 0.01).
        velocity_fraction: fraction of each joint's velocity limit (default 0.5).
        acceleration_fraction: fraction of each joint's acceleration limit (default 1.0).
    """

    position_margin_rad: float = field(
        default=0.01,
        metadata=param(
            "stay this far inside each position limit of the robot description",
            minimum=0.0,
            maximum=0.5,
            read_only=True,
            unit="rad",
        ),
    )
    velocity_fraction: float = field(
        default=0.5,
        metadata=param(
            "fraction of each joint's velocity limit that commands may use",
            minimum=0.01,
            maximum=1.0,
        ),
    )
    acceleration_fraction: float = field(
        default=1.0,
        metadata=param(
            "fraction of each joint's acceleration limit that commands may use",
            minimum=0.01,
            maximum=1.0,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its parameter declaration (ConfigurationError)."""
        validate_settings(self)


@dataclass
class LimitCounts:
    """How often each limit changed a command since the last :meth:`reset` (for diagnostics)."""

    non_finite: int = 0
    position: int = 0
    velocity: int = 0
    acceleration: int = 0

    def reset(self) -> None:
        """Zero all counters."""
        self.non_finite = self.position = self.velocity = self.acceleration = 0


def check_limit_settings(robot: RobotDescription, settings: LimitSettings) -> None:
    """Check that ``settings`` leave every joint of ``robot`` a range (cheap; changes nothing).

    Raises:
        ConfigurationError: the margin leaves no range for some joint.
    """
    margin = settings.position_margin_rad
    half_range = (robot.upper_rad - robot.lower_rad) / 2.0
    if np.any(margin >= half_range):
        raise ConfigurationError(
            f"parameter position_margin_rad: value {margin} leaves no range for some joint of "
            f"{robot.name}; allowed: less than {half_range.min():g}"
        )


class JointLimiter:
    """Saturating limiter for a vector of joints, with per-joint limits from a robot description.

    The limiter is stateless apart from its counters: the caller passes the previous commanded
    position and velocity, so it can be tested without a node.
    """

    def __init__(
        self,
        robot: RobotDescription,
        settings: LimitSettings | None = None,
        braking_rad_s2: np.ndarray | None = None,
    ) -> None:
        """Derive the effective limits from ``robot`` and ``settings``.

        ``braking_rad_s2`` is the previous limiter's braking deceleration per joint, when the
        settings change at run time (:attr:`braking_rad_s2`): a lowered acceleration limit then
        applies to slowing down only once each joint can stop at it.

        Raises:
            ConfigurationError: the margin leaves no range for some joint.
        """
        self.settings = settings or LimitSettings()
        check_limit_settings(robot, self.settings)
        margin = self.settings.position_margin_rad
        self.robot_lower_rad, self.robot_upper_rad = robot.lower_rad, robot.upper_rad
        self.lower_rad = robot.lower_rad + margin
        self.upper_rad = robot.upper_rad - margin
        self.max_velocity_rad_s = robot.max_velocity_rad_s * self.settings.velocity_fraction
        self.max_acceleration_rad_s2 = (
            robot.max_acceleration_rad_s2 * self.settings.acceleration_fraction
        )
        # Deceleration allowed per joint: the acceleration limit, or more, up to the previous
        # limit, while a joint moving at the speed the previous limit allowed could not stop at
        # the new one before its position limit (a live-lowered acceleration_fraction): it
        # brakes as it would have, never harder, instead of being stopped there in one command.
        self.braking_rad_s2 = self.max_acceleration_rad_s2.copy()
        if braking_rad_s2 is not None:
            carried = np.asarray(braking_rad_s2, dtype=np.float64)
            if carried.shape == self.braking_rad_s2.shape and np.isfinite(carried).all():
                self.braking_rad_s2 = np.maximum(self.braking_rad_s2, carried)
        self.counts = LimitCounts()
        self._middle_rad = (self.lower_rad + self.upper_rad) / 2.0  # where non-finite goes
        self._distances = np.empty((3, len(self.lower_rad)))  # enforce's braking distances
        self._range_of: tuple[bytes, tuple[np.ndarray, np.ndarray]] | None = None

    def clamp_position(self, positions_rad: np.ndarray) -> np.ndarray:
        """Clamp positions into the margin-shrunk range (non-finite values become the midpoint)."""
        positions = np.asarray(positions_rad, dtype=np.float64)
        finite = np.where(np.isfinite(positions), positions, self._middle_rad)
        return np.minimum(np.maximum(finite, self.lower_rad), self.upper_rad)

    def clamp_to_robot(self, positions_rad: np.ndarray) -> np.ndarray:
        """Clamp positions into the robot's own range, without the margin (non-finite: midpoint).

        A pose the robot is in (measured at start-up) may lie inside the margin; the command
        starts there and moves inward at the limits (:meth:`allowed_range`) instead of jumping.
        """
        positions = np.asarray(positions_rad, dtype=np.float64)
        finite = np.where(np.isfinite(positions), positions, self._middle_rad)
        return np.minimum(np.maximum(finite, self.robot_lower_rad), self.robot_upper_rad)

    def allowed_range(self, previous_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) a command may take after ``previous_rad``.

        The margin-shrunk range, widened to a previous position that lies between it and the
        robot's limit: such a joint may stay or move inward, never further out, so it reaches
        the margin-shrunk range at the velocity and acceleration limits.

        A filter step asks this for the same previous command three times (the limits, the
        guard, the final check): the last answer is kept, read-only.
        """
        key = np.asarray(previous_rad, dtype=np.float64).tobytes()
        if self._range_of is not None and self._range_of[0] == key:
            return self._range_of[1]
        previous = self.clamp_to_robot(previous_rad)
        lower, upper = np.minimum(self.lower_rad, previous), np.maximum(self.upper_rad, previous)
        lower.flags.writeable = upper.flags.writeable = False
        self._range_of = (key, (lower, upper))
        return lower, upper

    def _braking_velocity(self, distance_rad: np.ndarray, dt_s: float) -> np.ndarray:
        """Largest speed from which the joint can still stop within ``distance_rad``.

        Solves v*dt + v^2 / (2a) = d for v, a conservative bound for a discrete-time stop at
        deceleration a (the distance covered while braking is at most v^2 / (2a)), a the
        joint's braking deceleration (:attr:`braking_rad_s2`). Takes any array whose last axis
        is the joints.
        """
        accel = self.braking_rad_s2
        distance = np.maximum(distance_rad, 0.0)
        return accel * (np.sqrt(dt_s * dt_s + 2.0 * distance / accel) - dt_s)

    def enforce(
        self,
        desired_rad: np.ndarray,
        previous_rad: np.ndarray,
        previous_velocity_rad_s: np.ndarray,
        dt_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return the command closest to ``desired_rad`` that respects every limit.

        Args:
            desired_rad: (n_joints,) wanted positions; NaN/inf entries hold the previous position.
            previous_rad: (n_joints,) last commanded positions (inside the robot's limits;
                a joint between its limit and the margin moves inward, :meth:`allowed_range`).
            previous_velocity_rad_s: (n_joints,) last commanded velocities.
            dt_s: time since the previous command in seconds; a value below ``MIN_DT_S`` or
                non-finite means no time has passed, and the previous command is returned
                unchanged.

        Returns:
            ``(positions_rad, velocities_rad_s)``, both (n_joints,).
        """
        previous = np.asarray(previous_rad, dtype=np.float64)
        previous_velocity = np.asarray(previous_velocity_rad_s, dtype=np.float64)
        if not (math.isfinite(dt_s) and dt_s >= MIN_DT_S):
            return previous.copy(), previous_velocity.copy()
        desired = np.asarray(desired_rad, dtype=np.float64)
        finite = np.isfinite(desired)
        if not finite.all():
            self.counts.non_finite += int(np.count_nonzero(~finite))
            desired = np.where(finite, desired, previous)
        lower, upper = self.lower_rad, self.upper_rad

        # 1. Position.
        clamped = np.minimum(np.maximum(desired, lower), upper)
        self.counts.position += int(np.count_nonzero(clamped != desired))

        # 2. Velocity. Besides the velocity limit, the speed is bounded so that the joint can
        # still stop at the acceleration limit: before the target (no overshoot and no limit
        # cycle around it) and before each position limit. One call for all three distances.
        error = clamped - previous
        distances = self._distances
        distance = np.abs(error, out=distances[0])
        np.subtract(upper, previous, out=distances[1])
        np.subtract(previous, lower, out=distances[2])
        to_target, to_upper, to_lower = self._braking_velocity(distances, dt_s)
        with np.errstate(over="ignore"):  # a vanishing dt_s gives inf, bounded just below
            wanted_speed = distance / dt_s
        speed = np.minimum(np.minimum(wanted_speed, self.max_velocity_rad_s), to_target)
        limited = np.minimum(np.maximum(np.copysign(speed, error), -to_lower), to_upper)
        self.counts.velocity += int(np.count_nonzero(np.abs(limited) < wanted_speed))

        # 3. Acceleration: speeding up at the acceleration limit, slowing down towards zero at
        # the braking deceleration (also when the joint is to reverse: it first has to stop),
        # and on past zero at the acceleration limit again.
        speed_up = self.max_acceleration_rad_s2 * dt_s
        slow_down = self.braking_rad_s2 * dt_s
        v = previous_velocity
        lowest = np.where(
            v > 0.0, np.maximum(v - slow_down, np.minimum(0.0, v - speed_up)), v - speed_up
        )
        highest = np.where(
            v < 0.0, np.minimum(v + slow_down, np.maximum(0.0, v + speed_up)), v + speed_up
        )
        accelerated = np.minimum(np.maximum(limited, lowest), highest)
        self.counts.acceleration += int(np.count_nonzero(accelerated != limited))

        # Final guard against rounding: positions never leave the range (nor, for a joint that
        # started between its limit and the margin, move further out).
        unclamped = previous + accelerated * dt_s
        low, high = self.allowed_range(previous)
        positions = np.minimum(np.maximum(unclamped, low), high)
        velocities = np.where(positions == unclamped, accelerated, (positions - previous) / dt_s)
        self._relax_braking(positions, velocities)
        return positions, velocities

    def _relax_braking(self, positions: np.ndarray, velocities: np.ndarray) -> None:
        """Braking beyond the acceleration limit is kept only while a joint still needs it.

        A joint needs v^2 / (2d) to stop within the distance d to the position limit it moves
        towards; once that is within the acceleration limit, it brakes at the limit again.
        """
        if not (self.braking_rad_s2 > self.max_acceleration_rad_s2).any():
            return
        room = np.where(velocities > 0.0, self.upper_rad - positions, positions - self.lower_rad)
        with np.errstate(divide="ignore", invalid="ignore"):
            needed = np.where(
                velocities != 0.0, velocities**2 / (2.0 * np.maximum(room, 1e-9)), 0.0
            )
        self.braking_rad_s2 = np.clip(needed, self.max_acceleration_rad_s2, self.braking_rad_s2)
