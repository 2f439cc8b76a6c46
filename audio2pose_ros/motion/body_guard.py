"""The self-collision guard: no command brings an arm closer to Pepper's body than a margin.

The last stage of :class:`~audio2pose_ros.motion.filter.MotionFilter` (after the joint limits)
and of offline synthesis (:func:`guard_trajectory`). Each step it receives the command the limits
allow and the previous command, and returns a command whose clearance
(:meth:`~audio2pose_ros.robot.body.BodyModel.clearance`) is at least ``margin_m``:

1. **Admissible commands pass unchanged.** A command is admissible when it is clear of the body
   by the margin *and* so is the pose where every joint would come to rest if it braked at its
   acceleration limit from the commanded velocity (and the pose halfway there). So a moving arm
   can always stop before the margin.
2. **Otherwise only the joints that must stop, brake.** The joints on the kinematic chains of
   the offending pairs (one arm; the other arm for arm-against-arm; the hip or head when the
   pair involves them) decelerate at their acceleration limit, while every other joint keeps
   the command of the limits: the head and the other arm keep following.
3. **Sliding.** Each braked joint then takes its wanted value again if the result stays
   admissible, so an arm slides along the body instead of sticking to it, and follows again as
   soon as the wanted poses are clear. An arm that has come to rest at the margin while its
   straight way passes the body goes round: its joints move along the margin towards the command
   (the wanted direction without its part along the clearance gradient), slowly
   (``LEAD_OUT_SPEED_RAD_S``, or slower where the limiter's velocity limit is lower), within
   the acceleration limits, counted as ``detour_steps``.
   An arm already within ``TOLERANCE_M`` inside the margin (where braking may leave it) needs
   only not go deeper: there the floor is its present clearance, not the margin, so every
   command that does not bring it closer passes, and the arm leaves the band by any way that
   does not approach the body (else it would be held where braking left it, short of its goal).
4. **Led out gently.** A robot that starts inside the margin (moved by hand, or a measured pose
   inside) is moved up the clearance gradient, in the offending joints only, with a speed that
   ramps up from zero to ``LEAD_OUT_SPEED_RAD_S`` (scaled down to the limiter's velocity limit,
   direction kept, when that is lower); the other joints follow their command, or
   brake if that would bring the body closer. No velocity changes faster than the joint limits
   allow, so nothing about it jumps.
5. **Last resort.** If braking cannot keep a command admissible (another joint moved into a
   resting arm in one step), the offending joints hold their previous positions, and if even that
   is not clear the whole previous command is repeated (counted as ``holds``).

Every command it returns is inside the position range and no faster than the command it was
given or the previous one, so the limits of ``motion/limits.py`` keep holding.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.robot.body import BodyModel

LEAD_OUT_SPEED_RAD_S = 0.3  # joint-space speed of leading a robot out of the margin (rad/s)
LEAD_OUT_ACCEL_RAD_S2 = 1.0  # ... reached with this acceleration from rest (rad/s^2)
DETOUR_LIFT = 0.2  # a detour's part away from the body, per unit of its part along the margin
DETOUR_REST_RAD_S = 0.05  # held joints slower than this are at rest: a detour may start
DETOUR_MIN_RAD = 1e-3  # held joints closer than this to their command need no detour
BRAKING_POINTS = (1.0,)  # fractions of the braking distance checked for clearance
MAX_WIDENINGS = 3  # times the set of braked joints may grow within one step
TOLERANCE_M = 1e-3  # braking may end this far inside the margin (m): the braking path between the
# checked points can curve closer than they are; a robot further inside is led out


@dataclass
class GuardStatus:
    """What the guard did (counters since start) and the body's state at the last command."""

    interventions: int = 0  # commands it changed (braking, sliding, leading out, holding)
    lead_out_steps: int = 0  # commands of leading a robot out of the margin
    holds: int = 0  # last-resort holds of the previous pose
    detour_steps: int = 0  # commands that moved a stopped arm round the body along the margin
    active: bool = False  # the last command was changed
    clearance_m: float = float("inf")  # clearance of the last command (m)
    links: tuple[str, str] = ("", "")  # closest pair of the last command
    last_cost_ns: int = 0  # time the last call of BodyGuard.enforce took (for the bench)


class BodyGuard:
    """Keeps commands at least ``margin_m`` away from the robot's body (see the module text)."""

    def __init__(self, body: BodyModel, margin_m: float) -> None:
        """Guard commands for ``body`` with clearance ``margin_m`` (m, at least 0).

        Raises:
            ValueError: the margin is negative or not finite.
        """
        if not (np.isfinite(margin_m) and margin_m >= 0.0):
            raise ValueError(f"body margin must be a finite number >= 0 m, got {margin_m!r}")
        self.body = body
        self.margin_m = float(margin_m)
        self.status = GuardStatus()
        self._floor_m = self.margin_m  # the clearance commands need this step (see the module)
        self._lead_out_s = 0.0
        self._bounds = (body.robot.lower_rad, body.robot.upper_rad)
        self._max_speed = body.robot.max_velocity_rad_s  # the limiter's, from each step on

    def reset(self) -> None:
        """Start again from rest: forget the lead-out ramp and the body model's earlier queries."""
        self._lead_out_s = 0.0
        self.body.reset()

    def _clear(self, pose: np.ndarray) -> bool:
        return bool(self.body.clearance(pose) >= self._floor_m)

    def _stop_pose(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray, fraction: float
    ) -> np.ndarray:
        lower, upper = self._bounds
        return np.clip(pose + fraction * velocity * np.abs(velocity) / (2.0 * accel), lower, upper)

    def _candidates(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> list[np.ndarray]:
        """The pose and the points of its braking path that must all be clear."""
        if not np.any(velocity != 0.0):
            return [pose]
        return [pose, *(self._stop_pose(pose, velocity, accel, f) for f in BRAKING_POINTS)]

    def _admissible(self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray) -> bool:
        candidates = self._candidates(pose, velocity, accel)
        if not self._clear(candidates[0]):
            return False
        return all(  # points of the braking path no joint can bring closer need no query
            self.body.certainly_clear(pose, candidate, self._floor_m) or self._clear(candidate)
            for candidate in candidates[1:]
        )

    def _braking_close_enough(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> bool:
        """Braked commands may end up to ``TOLERANCE_M`` inside the margin (see its comment)."""
        limit = self.margin_m - TOLERANCE_M
        return all(
            self.body.clearance(candidate) >= limit
            for candidate in self._candidates(pose, velocity, accel)
        )

    def _offending(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> np.ndarray | None:
        """None if (pose, velocity) is admissible, else the joints of the pairs too close."""
        joints = np.zeros(self.body.robot.n_joints, dtype=bool)
        clear = True
        candidates = self._candidates(pose, velocity, accel)
        for i, candidate in enumerate(candidates):
            if i and self.body.certainly_clear(pose, candidate, self._floor_m):
                continue
            clearance, more = self.body.violations(candidate, self._floor_m)
            if clearance < self._floor_m:
                clear = False
                joints |= more
        return None if clear else joints

    def enforce(
        self,
        positions_rad: np.ndarray,
        velocities_rad_s: np.ndarray,
        previous_rad: np.ndarray,
        previous_velocity_rad_s: np.ndarray,
        dt_s: float,
        limiter: JointLimiter,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return the admissible command closest to ``positions_rad`` (see the module text).

        Args:
            positions_rad: (n_joints,) command of the joint limits.
            velocities_rad_s: (n_joints,) its velocity.
            previous_rad: (n_joints,) the previous command (what the robot was sent last).
            previous_velocity_rad_s: (n_joints,) its velocity.
            dt_s: time between the two commands (s); without time passing, the previous
                command is kept if the new one is not clear.
            limiter: the joint limits the command already obeys: its position range bounds
                every pose the guard makes, its acceleration limit is the braking deceleration.

        Returns:
            ``(positions_rad, velocities_rad_s)``.
        """
        start_ns = time.perf_counter_ns()
        status = self.status
        want = np.asarray(positions_rad, dtype=np.float64)
        want_velocity = np.asarray(velocities_rad_s, dtype=np.float64)
        previous = np.asarray(previous_rad, dtype=np.float64)
        previous_velocity = np.asarray(previous_velocity_rad_s, dtype=np.float64)
        accel = limiter.max_acceleration_rad_s2
        self._bounds = limiter.allowed_range(previous)
        self._max_speed = limiter.max_velocity_rad_s
        previous_clearance = float(self.body.clearance(previous))
        self._floor_m = min(self.margin_m, previous_clearance)
        result: tuple[np.ndarray, np.ndarray]
        if not (np.isfinite(dt_s) and dt_s > 0.0):
            result = (want, want_velocity) if self._clear(want) else (previous, previous_velocity)
        elif previous_clearance < self.margin_m - TOLERANCE_M:
            result = self._lead_out(want, want_velocity, previous, previous_velocity, dt_s, accel)
        else:
            self._lead_out_s = 0.0
            result = self._restrain(want, want_velocity, previous, previous_velocity, dt_s, accel)
        positions, velocities = result
        status.active = not np.array_equal(positions, want)
        status.interventions += int(status.active)
        distance, link_a, link_b = self.body.closest_pair(positions)
        status.clearance_m, status.links = distance, (link_a, link_b)
        status.last_cost_ns = time.perf_counter_ns() - start_ns
        return positions.copy(), velocities.copy()

    def _restrain(
        self,
        want: np.ndarray,
        want_velocity: np.ndarray,
        previous: np.ndarray,
        previous_velocity: np.ndarray,
        dt_s: float,
        accel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        offending = self._offending(want, want_velocity, accel)
        if offending is None:
            return want, want_velocity
        lower, upper = self._bounds
        held = offending
        for _ in range(MAX_WIDENINGS):
            braked_speed = np.maximum(np.abs(previous_velocity) - accel * dt_s, 0.0)
            velocity = np.where(held, np.copysign(braked_speed, previous_velocity), want_velocity)
            pose = np.where(held, np.clip(previous + velocity * dt_s, lower, upper), want)
            velocity = np.where(held, (pose - previous) / dt_s, velocity)
            more = self._offending(pose, velocity, accel)
            if more is None or self._braking_close_enough(pose, velocity, accel):
                pose, velocity = self._slide(pose, velocity, want, want_velocity, held, accel)
                return self._detour(
                    pose, velocity, want, previous, previous_velocity, held, dt_s, accel
                )
            if not np.any(more & ~held):
                break
            held = held | more
        # Last resort: the offending joints stay where they are; failing that, everything does.
        self.status.holds += 1
        pose = np.where(held, previous, want)
        velocity = np.where(held, 0.0, want_velocity)
        if self._clear(pose):
            return pose, velocity
        return previous.copy(), np.zeros_like(previous)

    def _slide(
        self,
        pose: np.ndarray,
        velocity: np.ndarray,
        want: np.ndarray,
        want_velocity: np.ndarray,
        held: np.ndarray,
        accel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Let each braked joint take its wanted value again where that stays admissible."""
        for joint in np.flatnonzero(held):
            if pose[joint] == want[joint]:
                continue
            trial, trial_velocity = pose.copy(), velocity.copy()
            trial[joint], trial_velocity[joint] = want[joint], want_velocity[joint]
            if self._admissible(trial, trial_velocity, accel):
                pose, velocity = trial, trial_velocity
        return pose, velocity

    def _detour(
        self,
        pose: np.ndarray,
        velocity: np.ndarray,
        want: np.ndarray,
        previous: np.ndarray,
        previous_velocity: np.ndarray,
        held: np.ndarray,
        dt_s: float,
        accel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Move a stopped arm round the body towards its command, along the margin.

        Braking and sliding leave an arm at rest at the margin when the straight way to its
        command passes the body. Then the held joints move along the margin: the wanted
        direction without its part towards the body (the clearance gradient), lifted a little
        away from it, at most ``LEAD_OUT_SPEED_RAD_S`` and within the acceleration limits; the
        arm follows its command again once the straight way is clear. Kept only if admissible.
        """
        resting = np.all(np.abs(velocity[held]) < DETOUR_REST_RAD_S)
        wanted = np.where(held, want - pose, 0.0)
        if not resting or float(np.abs(wanted).max()) < DETOUR_MIN_RAD:
            return pose, velocity
        gradient = self.body.gradient(previous, held)
        squared = float(gradient @ gradient)
        towards = float(wanted @ gradient)
        if squared < 1e-12 or towards >= 0.0:
            return pose, velocity  # the way is not into the body: braking had another cause
        tangent = wanted - towards / squared * gradient
        length = float(np.linalg.norm(tangent))
        if length < DETOUR_MIN_RAD:
            return pose, velocity  # the command is straight through the body: nowhere to go
        direction = tangent / length + DETOUR_LIFT * gradient / np.sqrt(squared)
        speed = min(LEAD_OUT_SPEED_RAD_S, length / dt_s)
        target = self._within_speed(direction / float(np.linalg.norm(direction)) * speed)
        change = np.clip(target - previous_velocity, -accel * dt_s, accel * dt_s)
        lower, upper = self._bounds
        trial = np.where(
            held, np.clip(previous + (previous_velocity + change) * dt_s, lower, upper), pose
        )
        trial_velocity = np.where(held, (trial - previous) / dt_s, velocity)
        if self._admissible(trial, trial_velocity, accel):
            self.status.detour_steps += 1
            return trial, trial_velocity
        return pose, velocity

    def _within_speed(self, velocity: np.ndarray) -> np.ndarray:
        """``velocity`` scaled down, direction kept, to the limiter's velocity limit per joint.

        The guard's own slow moves (lead-out, detour) are slower than a joint's limit at the
        default ``velocity_fraction``, but the fraction may be set far lower.
        """
        ratio = np.abs(velocity) / self._max_speed
        worst = float(ratio.max()) if ratio.size else 0.0
        return velocity / worst if worst > 1.0 else velocity

    def _lead_out(
        self,
        want: np.ndarray,
        want_velocity: np.ndarray,
        previous: np.ndarray,
        previous_velocity: np.ndarray,
        dt_s: float,
        accel: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Move the offending joints up the clearance gradient, slowly; brake what goes deeper.

        The offending joints' velocity approaches the lead-out velocity (along the gradient,
        ramped from zero at ``LEAD_OUT_ACCEL_RAD_S2`` up to ``LEAD_OUT_SPEED_RAD_S``) no faster
        than their acceleration limit allows, so a moving arm brakes into it rather than
        jumping. The other joints follow their command unless that brings the body closer than
        the led-out pose alone; then they brake at their acceleration limit.
        """
        self.status.lead_out_steps += 1
        body = self.body
        lower, upper = self._bounds
        _, joints = body.violations(previous, self.margin_m)
        gradient = body.gradient(previous, joints)
        norm = float(np.linalg.norm(gradient))
        self._lead_out_s += dt_s
        speed = min(LEAD_OUT_SPEED_RAD_S, LEAD_OUT_ACCEL_RAD_S2 * self._lead_out_s)
        target = (
            np.zeros_like(previous) if norm < 1e-9 else self._within_speed(gradient / norm * speed)
        )
        change = np.clip(target - previous_velocity, -accel * dt_s, accel * dt_s)
        led_velocity = np.where(joints, previous_velocity + change, 0.0)
        led = np.where(joints, np.clip(previous + led_velocity * dt_s, lower, upper), previous)
        pose = np.where(joints, led, want)
        if body.clearance(pose) < body.clearance(led):
            braked_speed = np.maximum(np.abs(previous_velocity) - accel * dt_s, 0.0)
            braked = np.clip(
                previous + np.copysign(braked_speed, previous_velocity) * dt_s, lower, upper
            )
            pose = np.where(joints, led, braked)
        return pose, (pose - previous) / dt_s


def guard_trajectory(guard: BodyGuard, trajectory_rad: np.ndarray, rate_hz: float) -> np.ndarray:
    """Run a whole (n_frames, n_joints) trajectory through ``guard``, from its first pose at rest.

    The offline counterpart of the filter's last two stages: ``audio2pose synth`` and ``render``
    pass their trajectories through it, so offline motion obeys the same margin as live
    commands. Each pose first goes through the joint limits (the robot's full position ranges,
    velocity and acceleration limits), then the guard, which brakes at the acceleration limits.
    """
    trajectory = np.asarray(trajectory_rad, dtype=np.float64)
    if len(trajectory) == 0:
        return trajectory.copy()
    limiter = JointLimiter(
        guard.body.robot,
        LimitSettings(position_margin_rad=0.0, velocity_fraction=1.0, acceleration_fraction=1.0),
    )
    dt_s = 1.0 / rate_hz
    out = np.empty_like(trajectory)
    previous = limiter.clamp_position(trajectory[0])
    velocity = np.zeros(trajectory.shape[1])
    guard.reset()
    if guard.body.clearance(previous) < guard.margin_m:
        previous = guard.body.push_out(previous, guard.margin_m)  # offline: start clear
    for i, desired in enumerate(trajectory):
        # the joint limits first, as in the filter: after the guard has held an arm, it
        # rejoins its trajectory within the velocity and acceleration limits, not in one jump
        want, want_velocity = limiter.enforce(desired, previous, velocity, dt_s)
        previous, velocity = guard.enforce(want, want_velocity, previous, velocity, dt_s, limiter)
        out[i] = previous
    return out
