"""The self-collision guard: no command brings an arm closer to Pepper's body than a margin.

The last stage of :class:`~audio2pose_ros.motion.filter.MotionFilter` (after the joint limits)
and of offline synthesis (:func:`guard_trajectory`). Each step it receives the command the limits
allow and the previous command, and returns a command whose clearance
(:meth:`~audio2pose_ros.robot.body.BodyModel.clearance`) is at least ``margin_m``:

1. **Admissible commands pass unchanged.** A command is admissible when its whole path is clear
   of the body by the guard's floor (below): the step from the previous command to it, and the
   braking path on which every moving joint would come to rest if they braked together from
   the commanded velocity (:func:`~audio2pose_ros.motion.limits.brake_together`: velocities
   scaled down by one factor, as fast as the joint slowest to stop allows at its acceleration
   limit). That path is the straight line the joints move along, the same whatever the
   length of the ticks that brake them (the filter's timer is uneven on a loaded computer),
   so braking from any command follows the path checked for the one before: braking every
   joint is always admissible, within the tolerance below. The path is checked continuously
   (:meth:`~audio2pose_ros.robot.body.BodyModel.sweep`: conservative advancement, with samples
   no further apart than ``SAMPLE_TRAVEL_M`` of travel of any checked pair, so that no shape,
   however thin, is passed between two samples), so a moving arm can always stop before the
   floor, and no step between two commands crosses the body.
   **Most commands need no query.** Each checked pair's distance at the previous command is
   bounded from the pair's last measured distance
   (:meth:`~audio2pose_ros.robot.body.BodyModel.pair_bounds`: less its levers times each
   joint's travel since), and along the whole path it falls by at most its levers times each
   joint's travel along it (the step, plus the braking distance ``|v| / (2 r)``, r the rate of
   :func:`~audio2pose_ros.motion.limits.stop_rate`). Where the
   lowest bound keeps the floor, the exact check could only find the path clear, so the
   command is admissible without a query (counted as ``bound_checks``); else it is queried as
   above. The previous command's clearance is such a bound too while the bound is at least the
   margin (the floor is then the margin, as with its exact value). Only outside the margin: a
   robot inside it (3, 4) is always measured. The decisions are those of the exact check (only
   coal's answers may differ, within its 1e-6 m tolerance: they depend on the queries before
   them, of which there are fewer). The clearance the guard reports of a command the bound
   passed is the bound (``GuardStatus.clearance_exact`` False); a changed command's is measured.
2. **Otherwise only the joints that must stop, brake.** The joints on the kinematic chains of
   the offending pairs (one arm; the other arm for arm-against-arm; the hip or head when the
   pair involves them) brake together, each within its acceleration limit, while every other
   joint keeps the command of the limits: the head and the other arm keep following. When
   that is not enough, the braked joints widen to those of the pair still too close, and at
   last to every joint: the rest of the previous command's checked braking path.
3. **Sliding.** Each braked joint then takes its wanted value again if the result stays
   admissible, so an arm slides along the body instead of sticking to it, and follows again as
   soon as the wanted poses are clear. An arm that has come to rest at the margin while its
   straight way passes the body goes round: its joints move along the margin towards the command
   (the wanted direction without its part along the clearance gradient), slowly
   (``LEAD_OUT_SPEED_RAD_S``, or slower where the limiter's velocity limit is lower), within
   the acceleration limits, counted as ``detour_steps``; with both arms at the margin, the
   closest pair's arm goes round first.
   An arm already within ``TOLERANCE_M`` inside the floor (where braking may leave it) needs
   only not go deeper: there the floor is its present clearance, so every command that does not
   bring it closer passes, and the arm leaves the band by any way that does not approach the
   body (else it would be held where braking left it, short of its goal).
4. **Led out gently.** A robot inside the margin (it started there, or the margin was raised)
   has the joints of its closest pair moved up the clearance gradient, with a speed that ramps
   up from zero to ``LEAD_OUT_SPEED_RAD_S`` (scaled down to the limiter's velocity limit,
   direction kept, when that is lower); the other joints follow their command, or brake if
   that would bring the body closer. The result is then checked as any command (1-3): every
   moving joint, not only the led ones, must be able to stop clear of the floor.
5. **Last resort** (counted as ``holds``; no sequence of commands the limiter allows needs
   it, on any ticks). If even braking every joint falls short of the floor beyond the
   tolerance, the guard still brakes every joint along the previous command's checked path,
   within the acceleration limits. Only a previous command that is not the guard's own (a
   caller's state, moving too fast to stop in time) has no checked path: then the offending
   joints hold their previous positions, and if even that is not clear the whole previous
   command is repeated, faster than the acceleration limit.

**The floor under live parameter changes.** The floor is the clearance the guard guarantees.
It is the margin, except after the margin was raised: a moving arm was promised only the old
margin, and may need its braking path to stop. Then the floor is the old margin, and rises
towards the new one only as far as every command's whole path is known clear of it
(``PathClearance.lowest_m``), while the arms inside the new margin are led out; it never falls,
so no command, and no step between two, comes within the old margin. A lowered margin takes
effect at once. After a lowered ``acceleration_fraction`` the arms may be moving faster than the
new limit can stop before the body: the guard brakes at the previous limit until every moving
joint's braking path at the new limit is clear. A changed ``velocity_fraction`` needs nothing:
every command's braking path is checked from its own velocity.

Every command it returns is inside the position range and no faster than the command it was
given or the previous one, so the limits of ``motion/limits.py`` keep holding.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.limits import JointLimiter, LimitSettings, brake_together, stop_rate
from audio2pose_ros.robot.body import BodyModel, PathClearance
from audio2pose_ros.robot.kinematics import blocked_product

LEAD_OUT_SPEED_RAD_S = 0.3  # joint-space speed of leading a robot out of the margin (rad/s)
LEAD_OUT_ACCEL_RAD_S2 = 1.0  # ... reached with this acceleration from rest (rad/s^2)
DETOUR_LIFT = 0.2  # a detour's part away from the body, per unit of its part along the margin
DETOUR_REST_RAD_S = 0.05  # held joints slower than this are at rest: a detour may start
DETOUR_MIN_RAD = 1e-3  # held joints closer than this to their command need no detour
MAX_WIDENINGS = 4  # times the set of braked joints may grow within one step
TOLERANCE_M = 1e-3  # braking may end this far inside the floor (m): the braking path between the
# checked points can curve closer than they are; a robot further inside is led out
SAMPLE_TRAVEL_M = 1e-3  # largest travel of any checked pair between two samples of a path (m):
# the path between them comes at most half of it closer than the samples
MAX_SAMPLES = 2000  # samples of one straight piece of a path at most
PLAN_RTOL = 1e-9  # a previous velocity within this (relative) of the guard's own, scaled down,
# is still on the braking path the guard checked for it
PATH_SLACK_M = 0.5 * TOLERANCE_M  # the samples between two commands and of the braking path may
# come this much closer than the margin (the path between samples another half a sample travel)
RECENT_PATHS = 8  # paths whose sweep is kept: a guard step checks the same command again


@dataclass
class GuardStatus:
    """What the guard did (counters since start) and the body's state at the last command."""

    interventions: int = 0  # commands it changed (braking, sliding, leading out, holding)
    lead_out_steps: int = 0  # commands of leading a robot out of the margin
    holds: int = 0  # last-resort holds of the previous pose (faster than the acceleration limit)
    detour_steps: int = 0  # commands that moved a stopped arm round the body along the margin
    active: bool = False  # the last command was changed
    clearance_m: float = float("inf")  # clearance of the last command (m), or a lower bound
    floor_m: float = float("inf")  # clearance the guard guarantees now (m): the margin, or less
    # while it rises to a raised margin
    links: tuple[str, str] = ("", "")  # closest pair of the last command
    clearance_exact: bool = True  # clearance_m and links were measured; False: the last command
    # was cleared by the travel bound, clearance_m is a lower bound and links its pair
    bound_checks: int = 0  # admissibility checks the travel bound answered without a query
    last_cost_ns: int = 0  # time the last call of BodyGuard.enforce took (for the bench)


class BodyGuard:
    """Keeps commands at least ``margin_m`` away from the robot's body (see the module text)."""

    def __init__(self, body: BodyModel, margin_m: float, travel_bound: bool = True) -> None:
        """Guard commands for ``body`` with clearance ``margin_m`` (m, at least 0).

        ``travel_bound=False`` makes every check query the body (module text, 1): the decisions
        are the same, so this is the reference the bound is tested against.

        Raises:
            ValueError: the margin is negative or not finite.
        """
        if not (np.isfinite(margin_m) and margin_m >= 0.0):
            raise ValueError(f"body margin must be a finite number >= 0 m, got {margin_m!r}")
        self.body = body
        self.margin_m = float(margin_m)
        self.status = GuardStatus()
        self._guaranteed_m: float | None = None  # the floor, None until the first command
        self._floor_m = self.margin_m  # the clearance commands need this step (see the module)
        self._lead_out_s = 0.0
        self._bounds = (body.robot.lower_rad, body.robot.upper_rad)
        self._max_speed = body.robot.max_velocity_rad_s  # the limiter's, from each step on
        self._brake_accel: np.ndarray | None = None  # deceleration the last command relies on
        self._speed_up = np.zeros(body.robot.n_joints)  # the acceleration limit (rad/s^2)
        self._previous = np.zeros(body.robot.n_joints)  # the previous command, this step
        self._paths: dict[bytes, PathClearance] = {}
        self._travel = body.pair_lever_m  # (n_pairs, n_joints): a pair's travel per rad (m/rad)
        self._travel_bound = travel_bound
        self._pair_bounds_m: np.ndarray | None = None  # each pair's bound at the previous command
        self._last: tuple[bytes, np.ndarray] | None = None  # the last command returned and its
        # velocity: its braking path is known clear (checked, or part of a checked one)
        self._bounded = b""  # the last pose the travel bound cleared, this step

    def reset(self) -> None:
        """Start again from rest: forget the lead-out ramp, the floor and earlier queries."""
        self._lead_out_s = 0.0
        self._guaranteed_m = None
        self._brake_accel = None
        self._last = None
        self._paths.clear()
        self.body.reset()

    def _pose_bound(self, travel: np.ndarray) -> tuple[float, int]:
        """A lower bound of the clearance of every pose within ``travel`` of the previous command.

        ``travel`` is per joint; the bound comes from each pair's bound at the previous command
        (:meth:`_previous_clearance`), with no query; -inf without them.

        Returns:
            ``(bound_m, pair)``: the bound and the pair (index in ``link_pairs``) it is of.
        """
        if self._pair_bounds_m is None:
            return -np.inf, -1
        bounds = self._pair_bounds_m - self._travel @ travel
        pair = int(bounds.argmin())
        return float(bounds[pair]), pair

    def _path_bound(self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray) -> float:
        """A lower bound of the clearance along :meth:`_path`'s whole path, without a query.

        Each joint's travel from the previous command along the path is at most its step to
        ``pose``, plus how far ``pose`` lies outside the position range (the braking path is
        clipped into it), plus its braking distance ``|v| / (2 r)`` (braking together at the
        rate r of :func:`~audio2pose_ros.motion.limits.stop_rate`). Each pair's bound at the
        previous command (:meth:`~audio2pose_ros.robot.body.BodyModel.pair_bounds`) less its
        levers times that travel bounds it along the path. NaN (never clear) for a joint that
        moves and cannot brake.
        """
        lower, upper = self._bounds
        outside = np.maximum(lower - pose, 0.0) + np.maximum(pose - upper, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            braking = np.abs(velocity) / (2.0 * stop_rate(velocity, accel))
        return self._pose_bound(np.abs(pose - self._previous) + outside + braking)[0]

    def _clear(self, pose: np.ndarray) -> bool:
        return bool(self.body.clearance(pose) >= self._floor_m)

    def _path(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The step from the previous command to ``pose`` and its braking path, as sweep pieces.

        The braking path is the one the guard commands when it brakes (:meth:`_braked`): every
        joint together (:func:`~audio2pose_ros.motion.limits.brake_together`), so the joints
        move on along the straight line of ``velocity`` and stop on it, within
        ``velocity / (2 r)`` of ``pose`` (r the rate of
        :func:`~audio2pose_ros.motion.limits.stop_rate`), whatever the length of the ticks
        that brake them, clipped into the position range (a corner where a joint reaches its
        limit). Braking from any command on this path follows the rest of it, so a command the
        guard braked has its braking path checked already. Each straight piece is sampled so
        that no checked pair travels more than ``SAMPLE_TRAVEL_M`` between two samples.

        Returns:
            ``(points, counts)`` for :meth:`~audio2pose_ros.robot.body.BodyModel.sweep`: the
            previous command, ``pose``, the corners and the rest, and each piece's samples.
        """
        rate = stop_rate(velocity, accel)
        lower, upper = self._bounds
        if np.isfinite(rate):
            reach = velocity / (2.0 * rate)
            with np.errstate(divide="ignore", invalid="ignore"):
                corners = np.where(reach > 0.0, upper - pose, lower - pose) / reach
            corners = np.unique(corners[(corners > 0.0) & (corners < 1.0)])
            fractions = np.append(corners, 1.0)[:, None]
            braking = np.clip(pose + fractions * reach, lower, upper)
            nodes = np.vstack([self._previous, pose, braking])
        else:
            nodes = np.vstack([self._previous, pose])
        pieces = np.diff(nodes, axis=0)
        travel = blocked_product(np.abs(pieces), self._travel.T).max(axis=1)
        return nodes, np.clip(np.ceil(travel / SAMPLE_TRAVEL_M), 1, MAX_SAMPLES)

    def _sweep(
        self,
        pose: np.ndarray,
        velocity: np.ndarray,
        accel: np.ndarray,
        floor_m: float,
        path_floor_m: float,
    ) -> PathClearance:
        """Whether the command ``pose`` keeps ``floor_m`` and its path ``path_floor_m``.

        The path is :meth:`_path`'s; recent answers are kept.
        """
        floors = np.array([floor_m, path_floor_m])
        key = (
            b"".join(
                (self._previous.tobytes(), floors.tobytes(), pose.tobytes(), velocity.tobytes())
            )
            + accel.tobytes()
        )
        found = self._paths.get(key)
        if found is None:
            distance, pair = self.body.query(pose)
            if distance < floor_m:
                found = PathClearance(False, -1, pair, distance, 0.0, 1)
            else:
                points, counts = self._path(pose, velocity, accel)
                found = self.body.sweep(points, path_floor_m, counts)
            if len(self._paths) >= RECENT_PATHS:
                self._paths.pop(next(iter(self._paths)))
            self._paths[key] = found
        return found

    def _check(self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray) -> PathClearance:
        """The admissibility check: the command keeps the floor, and so does its path.

        The path may come ``PATH_SLACK_M`` inside the margin, but no closer than the present
        clearance once inside it (so that braking along it cannot creep deeper step by step).
        Outside the margin, a path whose travel bound (:meth:`_path_bound`) keeps the floor is
        clear without a query: the exact check would find it clear too.
        """
        inside = self._floor_m < self.margin_m  # the floor is the present clearance
        path_floor = self._floor_m if inside else self._floor_m - PATH_SLACK_M
        if self._travel_bound and not inside:
            bound = self._path_bound(pose, velocity, accel)
            if bound >= self._floor_m:  # the whole path, the command too, keeps the floor
                self.status.bound_checks += 1
                self._bounded = pose.tobytes()
                return PathClearance(True, -1, -1, bound, 0.0, 0)
        return self._sweep(pose, velocity, accel, self._floor_m, path_floor)

    def _admissible(self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray) -> bool:
        return self._check(pose, velocity, accel).clear

    def _braking_short_of(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> np.ndarray | None:
        """None if a braked command keeps the guaranteed floor within ``TOLERANCE_M``.

        Else the joints of the first pair too close (of the command or of its path). Braking
        follows the previous command's checked path, but that was checked with the previous
        tick's length and acceleration.
        """
        assert self._guaranteed_m is not None
        limit = self._guaranteed_m - TOLERANCE_M
        found = self._sweep(pose, velocity, accel, limit, limit)
        return None if found.clear else self.body.pair_joints(found.pair)

    def _offending(
        self, pose: np.ndarray, velocity: np.ndarray, accel: np.ndarray
    ) -> np.ndarray | None:
        """None if (pose, velocity) is admissible, else the joints of the first pair too close."""
        found = self._check(pose, velocity, accel)
        return None if found.clear else self.body.pair_joints(found.pair)

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
                every pose the guard makes, its acceleration limit is the braking deceleration
                (or the previous one, higher, until the arms can stop at it: module text).

        Returns:
            ``(positions_rad, velocities_rad_s)``.
        """
        start_ns = time.perf_counter_ns()
        status = self.status
        want = np.asarray(positions_rad, dtype=np.float64)
        want_velocity = np.asarray(velocities_rad_s, dtype=np.float64)
        previous = np.asarray(previous_rad, dtype=np.float64)
        previous_velocity = np.asarray(previous_velocity_rad_s, dtype=np.float64)
        self._previous = previous
        # One deceleration for the limiter and the guard: the braking paths assume the joint
        # limiter's (its acceleration limit, or the previous, higher limit while a joint it let
        # move fast still needs it to stop: a live-lowered acceleration_fraction); the guard's
        # own moves speed up at the acceleration limit only.
        self._speed_up = limiter.max_acceleration_rad_s2
        accel = np.maximum(self._speed_up, limiter.braking_rad_s2)
        brake = accel if self._brake_accel is None else np.maximum(accel, self._brake_accel)
        self._bounds = limiter.allowed_range(previous)
        self._max_speed = limiter.max_velocity_rad_s
        self._bounded = b""
        previous_clearance = self._previous_clearance(previous)
        if self._guaranteed_m is None:  # from rest: what the start pose has, at most the margin
            self._guaranteed_m = min(self.margin_m, previous_clearance)
        self._guaranteed_m = min(self._guaranteed_m, self.margin_m)  # a lowered margin: at once
        # never closer than now while inside the margin; braked commands may end up to
        # TOLERANCE_M inside the guaranteed floor
        self._floor_m = min(self.margin_m, previous_clearance)
        result: tuple[np.ndarray, np.ndarray]
        if not (np.isfinite(dt_s) and dt_s > 0.0):
            result = (want, want_velocity) if self._clear(want) else (previous, previous_velocity)
        else:
            if previous_clearance < self.margin_m - TOLERANCE_M:
                want, want_velocity = self._lead_out(
                    want, want_velocity, previous, previous_velocity, dt_s, accel, brake
                )
            else:
                self._lead_out_s = 0.0
            result = self._restrain(
                want, want_velocity, previous, previous_velocity, dt_s, accel, brake
            )
        positions, velocities = result
        if self._guaranteed_m < self.margin_m or np.any(brake > accel):
            self._settle(positions, velocities, accel, brake)
        else:
            self._brake_accel = accel
        status.active = not np.array_equal(positions, np.asarray(positions_rad, dtype=np.float64))
        status.interventions += int(status.active)
        if status.active or positions.tobytes() != self._bounded:
            distance, link_a, link_b = self.body.closest_pair(positions)
            status.clearance_exact = True
        else:  # cleared by the travel bound: the command's own bound
            distance, pair = self._pose_bound(np.abs(positions - previous))
            link_a, link_b = self.body.link_pairs[pair]
            status.clearance_exact = False
        status.clearance_m, status.links = distance, (link_a, link_b)
        status.floor_m = self._guaranteed_m
        self._last = (positions.tobytes(), velocities.copy())
        status.last_cost_ns = time.perf_counter_ns() - start_ns
        return positions.copy(), velocities.copy()

    def _previous_clearance(self, previous: np.ndarray) -> float:
        """The previous command's clearance, or a lower bound of it that is at least the margin.

        With the travel bound, each pair's bound at the previous command is kept for this step
        (:meth:`_pose_bound`). While their lowest is at least the margin it stands for the
        clearance: the floor is then the margin and no lead-out is due, as with the exact
        clearance. Else, and from rest, the clearance is queried.
        """
        self._pair_bounds_m = None
        if self._travel_bound and self._guaranteed_m is not None:
            self._pair_bounds_m = self.body.pair_bounds(previous)
            bound = float(self._pair_bounds_m.min())
            if bound >= self.margin_m:
                return bound
        return float(self.body.clearance(previous))

    def _settle(
        self, positions: np.ndarray, velocities: np.ndarray, accel: np.ndarray, brake: np.ndarray
    ) -> None:
        """Raise the floor to what the returned command's path keeps, and pick its braking.

        The command relies on the limiter's deceleration if its braking path is clear at it,
        else on the higher one it was braked with (after a lowered acceleration limit).
        """
        assert self._guaranteed_m is not None
        self._previous = positions  # the returned command's own braking path, from itself
        floor = self._guaranteed_m - TOLERANCE_M
        found = self._sweep(positions, velocities, accel, floor, floor)
        self._brake_accel = accel
        if not found.clear and np.any(brake > accel):
            found = self._sweep(positions, velocities, brake, floor, floor)
            self._brake_accel = brake
        if found.clear and found.lowest_m > self._guaranteed_m:
            self._guaranteed_m = (
                self.margin_m
                if found.lowest_m >= self.margin_m - TOLERANCE_M
                else float(found.lowest_m)
            )

    def _restrain(
        self,
        want: np.ndarray,
        want_velocity: np.ndarray,
        previous: np.ndarray,
        previous_velocity: np.ndarray,
        dt_s: float,
        accel: np.ndarray,
        brake: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        offending = self._offending(want, want_velocity, accel)
        if offending is None:
            return want, want_velocity
        held = offending
        for widening in range(MAX_WIDENINGS + 1):
            braked, braked_velocity = self._braked(previous, previous_velocity, held, dt_s, brake)
            pose = np.where(held, braked, want)
            velocity = np.where(held, braked_velocity, want_velocity)
            more = self._offending(pose, velocity, accel)
            if more is not None and not np.any(more & ~held):
                # braking every offending joint is not enough: within the tolerance it is,
                # unless another pair is the one too close
                more = self._braking_short_of(pose, velocity, brake)
            if more is None:
                pose, velocity = self._slide(pose, velocity, want, want_velocity, held, accel)
                return self._detour(
                    pose, velocity, want, previous, previous_velocity, held, dt_s, accel
                )
            if held.all():
                break
            # widen to the joints of the pair too close; when that adds none, or widening is
            # done, every joint brakes: the rest of the previous command's braking path
            widened = held | more
            last = np.array_equal(widened, held) or widening == MAX_WIDENINGS - 1
            held = np.ones_like(held) if last else widened
        # Last resort (counted): within the tolerance, braking every joint did not keep the
        # floor. The previous command's own braking path was checked: follow it, within the
        # acceleration limits. A previous command that is not the guard's (a caller's state)
        # has none: its offending joints hold, failing that every joint does.
        self.status.holds += 1
        if self._own(previous, previous_velocity):
            return self._braked(previous, previous_velocity, held, dt_s, brake)
        pose = np.where(offending, previous, want)
        velocity = np.where(offending, 0.0, want_velocity)
        if self._clear(pose):
            return pose, velocity
        return previous.copy(), np.zeros_like(previous)

    def _braked(
        self,
        previous: np.ndarray,
        previous_velocity: np.ndarray,
        held: np.ndarray,
        dt_s: float,
        brake: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The previous command with the ``held`` joints braked together for ``dt_s``.

        They keep their direction, so they move on along the previous command's checked path
        (seen on their own joints); every joint held: on the path itself.
        """
        lower, upper = self._bounds
        velocity = brake_together(np.where(held, previous_velocity, 0.0), brake, dt_s)
        pose = np.clip(previous + velocity * dt_s, lower, upper)
        return pose, (pose - previous) / dt_s

    def _own(self, previous: np.ndarray, previous_velocity: np.ndarray) -> bool:
        """Whether the previous command is the guard's last one, its velocity at most scaled down.

        Its braking path is then known clear, also with the velocity braked together (a filter
        that missed ticks does so).
        """
        if self._last is None or previous.tobytes() != self._last[0]:
            return False
        velocity = self._last[1]
        squared = float(velocity @ velocity)
        scale = float(previous_velocity @ velocity) / squared if squared > 0.0 else 0.0
        tolerance = PLAN_RTOL * (1.0 + np.abs(velocity))
        return bool(
            -PLAN_RTOL <= scale <= 1.0 + PLAN_RTOL
            and np.all(np.abs(previous_velocity - scale * velocity) <= tolerance)
        )

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
        command passes the body. Then the held joints of the closest pair move along the
        margin: the wanted direction without its part towards the body (the clearance
        gradient), lifted a little away from it, at most ``LEAD_OUT_SPEED_RAD_S`` and within
        the acceleration limits; the arm follows its command again once the straight way is
        clear. Kept only if admissible.
        """
        # one arm at a time: the closest pair's (with both arms at the margin, moving both
        # along the gradient of the closest pair alone would take the other one in)
        held = held & self.body.pair_joints(self.body.query(previous)[1])
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
        change = np.clip(target - previous_velocity, -self._speed_up * dt_s, self._speed_up * dt_s)
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
        brake: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The command with the offending joints moved up the clearance gradient, slowly.

        The offending joints' velocity approaches the lead-out velocity (along the gradient,
        ramped from zero at ``LEAD_OUT_ACCEL_RAD_S2`` up to ``LEAD_OUT_SPEED_RAD_S``) no faster
        than their acceleration limit allows, so a moving arm brakes into it rather than
        jumping. The other joints follow their command unless that brings the body closer than
        the led-out pose alone; then they brake (at ``brake``). The result is the command the
        guard then checks like any other (:meth:`_restrain`): every joint's braking path.
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
        change = np.clip(target - previous_velocity, -self._speed_up * dt_s, self._speed_up * dt_s)
        led_velocity = np.where(joints, previous_velocity + change, 0.0)
        led = np.where(joints, np.clip(previous + led_velocity * dt_s, lower, upper), previous)
        pose = np.where(joints, led, want)
        if body.clearance(pose) < body.clearance(led):
            braked, _ = self._braked(previous, previous_velocity, ~joints, dt_s, brake)
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
