"""The online motion filter: paces raw model poses to a fixed rate, smooths them, limits them.

This is the ROS-free core of ``motion_filter_node``, the last stage before the robot. Raw poses
arrive in bursts (one burst per audio chunk); :class:`MotionFilter` checks them, queues them in
a short jitter buffer and, at every :meth:`MotionFilter.tick`, produces one command. A message's
poses fall due one period apart from its arrival; a tick takes the newest pose that is due and
skips those it overtook (two messages that came together, a late tick), and a backlog that
never empties for ``backlog_window_s`` is skipped too: the buffer smooths bursts, never adds
standing latency.

0. **Gate** (:class:`~audio2pose_ros.motion.gate.TrackGate`). At most
   ``max_points_per_message`` poses of a message are looked at (the rest are dropped and
   counted). Non-finite poses, poses outside a joint's range (beyond ``outlier_tolerance_rad``)
   and poses no joint could reach from the recent track in the time that passed are rejected
   before the buffer or the smoother sees them; the rest are clamped into the joint ranges. Head
   targets are checked against the head's range, head offsets against ``max_head_offset_rad``.
1. **Mode.** It *tracks* the generated motion while poses arrive, the voice is active, the filter
   is enabled and no stop is requested. After :meth:`MotionFilter.start_from` it is *waiting*:
   it holds the start pose until the first pose is admitted (a restarted filter does not move the
   robot before input says it may). Otherwise it *glides to the neutral pose* along a
   minimum-jerk path of ``neutral_glide_s`` that starts where the robot is. An emergency stop
   either brakes to a standstill and *holds* (``stop_behaviour: hold``) or glides to neutral
   (``neutral``); while stopped nothing else (generated motion, head target or offset) moves it.
2. **Tracking.** The style (:mod:`~audio2pose_ros.motion.style`: per joint group a tempo and a
   size about the neutral pose, the arms' rest and height) is applied, and the pose
   is smoothed causally (a Butterworth low-pass, by default 3 Hz and 2nd order; or the Kalman
   filter of seed 003 section 4.4.2; or none). When
   tracking resumes, the smoother restarts from the commanded pose, so nothing jumps, and when
   it resumes or the gate re-acquires a new track, the tracked pose is blended in along a
   minimum-jerk path timed for the distance (:class:`~audio2pose_ros.motion.approach.Approach`:
   at most a quarter of the velocity limit), never at the limits.
3. **Head composition.** An external head target (a face tracker's look-at) is blended into the
   head joints with ``head_target_weight``, and an external offset is added, for
   ``external_timeout_s`` after each message, while not stopped.
4. **Limits last** (:class:`~audio2pose_ros.motion.limits.JointLimiter`): position, velocity,
   acceleration, from the first command on (the start pose counts as commanded, at rest).
   Then the **body** (:class:`~audio2pose_ros.motion.body_guard.BodyGuard`): no command brings
   an arm closer than ``body_margin_m`` to the robot's body or the other arm; only the joints
   that must stop brake, and a robot that starts inside the margin is led out slowly.
5. **Health**. A non-finite wanted pose or smoother state is reset from the
   last commanded pose; a command that is not finite, leaves the limits or steps further than
   the velocity limit allows is replaced by the last commanded pose. Either counts as a fault
   (``FilterStatus.faults``, ``last_fault``) that the node reports as ERROR.
6. **Gaps**. When ticks stop for more than ``GAP_PERIODS`` periods (a blocked
   process), the commanded velocity is braked at the acceleration limit over the time that
   passed and the smoother restarts from the commanded pose at rest: the robot resumes from the
   pose it was last sent, with no velocity jump.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.approach import Approach, minimum_jerk
from audio2pose_ros.motion.body_guard import BodyGuard
from audio2pose_ros.motion.filter_settings import (
    LIMIT_SETTINGS,
    READ_ONLY_SETTINGS,
    MotionFilterSettings,
)
from audio2pose_ros.motion.gate import TrackGate
from audio2pose_ros.motion.limits import (
    JointLimiter,
    LimitSettings,
    brake_together,
    check_limit_settings,
)
from audio2pose_ros.motion.smoothing import CausalLowPass, KalmanSmoother
from audio2pose_ros.motion.style import StyleSettings, StyleTransform
from audio2pose_ros.parameters import settings_with
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription

MODES = ("waiting", "tracking", "neutral", "stopped")
GAP_PERIODS = 3.0  # ticks further apart than this many periods are a gap (the process stalled)
STEP_SLACK_RAD = 1e-9  # rounding allowance of the step check of the health guard


@dataclass
class FilterStatus:
    """Counters and state for diagnostics (counters count since start)."""

    mode: str = "neutral"
    received: int = 0  # poses accepted into the buffer
    rejected: int = 0  # malformed messages (shape) and poses with NaN/inf
    out_of_range: int = 0  # poses with a joint outside its range (beyond the tolerance)
    implausible: int = 0  # poses too far from the recent track for the time that passed
    truncated: int = 0  # poses beyond max_points_per_message
    dropped: int = 0  # buffer overflow, or generated while not tracking (stale)
    underruns: int = 0
    skipped: int = 0  # overdue poses (overtaken by the next due one) and standing backlogs
    buffered: int = 0
    external_rejected: int = 0  # head targets / offsets refused
    gaps: int = 0  # ticks more than GAP_PERIODS apart
    faults: int = 0  # non-finite state or unsafe command replaced by the last commanded pose
    last_fault: str = ""
    last_fault_s: float = -np.inf
    enabled: bool = True
    stopped: bool = False
    voice_active: bool = True
    head_target_active: bool = False


class _External:
    """An externally commanded value for some joints, valid for a while after it arrived."""

    def __init__(self, n_joints: int) -> None:
        self.values = np.zeros(n_joints)
        self.mask = np.zeros(n_joints, dtype=bool)
        self.stamp_s = -np.inf
        self._none = np.zeros(n_joints, dtype=bool)
        self._none.flags.writeable = False

    def set(self, values: np.ndarray, mask: np.ndarray, now_s: float) -> None:
        self.values, self.mask, self.stamp_s = values, mask, now_s

    def active(self, now_s: float, timeout_s: float) -> np.ndarray:
        """Mask of joints with a fresh value (all False, read-only, when stale)."""
        return self.mask if now_s - self.stamp_s <= timeout_s else self._none


def _with_legacy_gains(
    settings: MotionFilterSettings, style: StyleSettings | None
) -> StyleSettings:
    """``style`` with the deprecated gains of ``settings`` (if any) as its sizes."""
    return dataclasses.replace(style or StyleSettings(), **settings.legacy_gains())


class MotionFilter:
    """Gate, jitter buffer, modes, style, smoothing, head composition, limits and health guard."""

    def __init__(
        self,
        robot: RobotDescription,
        settings: MotionFilterSettings | None = None,
        limits: LimitSettings | None = None,
        start_pose_rad: np.ndarray | None = None,
        style: StyleSettings | None = None,
    ) -> None:
        """Start at rest in ``start_pose_rad`` (the robot's pose), or in the neutral pose.

        ``style`` is applied to the generated motion before smoothing (default: the identity).

        Raises:
            ConfigurationError: the limit settings leave no range for some joint.
            InputError: the start pose has the wrong size or is not finite.
        """
        self.robot = robot
        self.settings = settings or MotionFilterSettings()
        self.limiter = JointLimiter(robot, limits)
        self.body_guard = BodyGuard(BodyModel.load(robot), self.settings.body_margin_m)
        self.period_s = 1.0 / self.settings.rate_hz
        self.neutral_rad = self.limiter.clamp_position(robot.neutral_rad)
        self.style = StyleTransform(
            robot, _with_legacy_gains(self.settings, style), self.settings.rate_hz
        )
        self._head = robot.group_mask("head")
        self.gate = TrackGate(
            robot.lower_rad,
            robot.upper_rad,
            robot.max_velocity_rad_s,
            self.period_s,
            self.settings.outlier_tolerance_rad,
        )
        self.approach = Approach()
        # settings validated by request_settings, for take_requested_settings
        self._requested: tuple[MotionFilterSettings, LimitSettings, StyleSettings] | None = None
        self._apply_live_settings()
        # the jitter buffer: (due time, pose); a message's poses fall due one period apart from
        # its arrival
        self._queue: deque[tuple[float, np.ndarray]] = deque(
            maxlen=max(1, round(self.settings.max_buffer_s * self.settings.rate_hz))
        )
        self._depths: deque[int] = deque(
            maxlen=max(1, round(self.settings.backlog_window_s * self.settings.rate_hz))
        )
        self._smoother = self._make_smoother()
        self.status = FilterStatus()
        self._last_input_s = -np.inf
        self._last_voice_s = -np.inf
        self._voice_reported = False
        # After start_from, hold the start pose until the first pose is admitted: a restarted
        # filter must not move the robot (not even towards neutral) before input says it may.
        self._holding = False
        self._head_target = _External(robot.n_joints)
        self._head_offset = _External(robot.n_joints)
        self.start_from(self.neutral_rad if start_pose_rad is None else start_pose_rad)

    def _make_smoother(self) -> KalmanSmoother | CausalLowPass | None:
        n = self.robot.n_joints
        settings = self.settings
        if settings.smoothing == "kalman":
            return KalmanSmoother(n, self.period_s, settings.kalman_q, settings.kalman_r)
        if settings.smoothing == "lowpass":
            return CausalLowPass(
                n, settings.rate_hz, settings.lowpass_cutoff_hz, settings.lowpass_order
            )
        return None

    def _apply_live_settings(self) -> None:
        self.gate.tolerance_rad = self.settings.outlier_tolerance_rad
        self.body_guard.margin_m = self.settings.body_margin_m

    def start_from(self, pose_rad: np.ndarray) -> None:
        """Take ``pose_rad`` as the commanded pose, at rest: the next command starts there.

        Used at start-up with the robot's measured (or last commanded) pose. The pose is clamped
        into the robot's limits, not into the margin: a joint between its limit and the margin
        is brought inside at the velocity and acceleration limits, not in one step. The buffer,
        the smoother and the gate's track start from it.

        Raises:
            InputError: the pose has the wrong size or is not finite.
        """
        pose = np.asarray(pose_rad, dtype=np.float64)
        if pose.shape != (self.robot.n_joints,) or not np.isfinite(pose).all():
            raise InputError(f"start pose must be {self.robot.n_joints} finite angles, got {pose}")
        self.position_rad = self.limiter.clamp_to_robot(pose)
        self.velocity_rad_s = np.zeros(self.robot.n_joints)
        self.body_guard.reset()  # a start pose inside the body's margin is led out from rest
        self._target = self.position_rad.copy()
        if self._smoother is not None:
            self._smoother.reset(self.position_rad)
        self._queue.clear()
        self._depths.clear()
        self.gate.reset()
        self.style.reset()
        self._last_tick_s: float | None = None
        self._glide_start: tuple[float, np.ndarray] | None = None
        self._holding = True

    def check_settings(self, settings: MotionFilterSettings, limits: LimitSettings) -> None:
        """Refuse settings :meth:`update_settings` would refuse, changing nothing (cheap).

        A node validates a run-time change with this when it is requested and applies it at its
        next tick, so a storm of requests costs one application per tick, not one per request.

        Raises:
            ConfigurationError: a read-only setting differs from the running one, or the limit
                settings leave no range for some joint.
        """
        for name in READ_ONLY_SETTINGS:
            new, running = (
                (limits, self.limiter.settings)
                if name in LIMIT_SETTINGS
                else (settings, self.settings)
            )
            if getattr(new, name) != getattr(running, name):
                raise ConfigurationError(f"parameter {name} cannot change while the node runs")
        check_limit_settings(self.robot, limits)

    def update_settings(
        self,
        settings: MotionFilterSettings,
        limits: LimitSettings | None = None,
        style: StyleSettings | None = None,
    ) -> None:
        """Take new settings from the next tick on (``ros2 param set`` at run time).

        A new ``style`` blends in over ``STYLE_BLEND_S`` (no jump); None keeps the style.

        Raises:
            ConfigurationError: refused by :meth:`check_settings` (nothing changes then).
        """
        limits = limits or self.limiter.settings
        self.check_settings(settings, limits)
        self.settings = settings
        if limits != self.limiter.settings:
            counts = self.limiter.counts
            # a lowered acceleration limit: joints brake at the old one until they can stop
            self.limiter = JointLimiter(self.robot, limits, self.limiter.braking_rad_s2)
            self.limiter.counts = counts
        if style is not None or settings.legacy_gains():
            self.style.update(_with_legacy_gains(settings, style or self.style.settings))
        self._apply_live_settings()

    def request_settings(self, changes: Mapping[str, object]) -> None:
        """Validate a run-time change now, as a whole; :meth:`take_requested_settings` applies it.

        ``changes`` maps setting names to new values (names of other settings are ignored); it
        adds to a request not taken yet (the newest value of each wins), and a request that
        leaves every setting as it runs cancels the pending one. A request costs a validation
        only (no limiter or body model is built), so a node applies requests once per tick,
        however many came.

        Raises:
            ConfigurationError: the new combination is refused (nothing changes then).
        """
        running = (self.settings, self.limiter.settings, self.style.settings)
        settings, limits, style = self._requested or running
        wanted = (
            settings_with(settings, changes),
            settings_with(limits, changes),
            settings_with(style, changes),
        )
        self.check_settings(wanted[0], wanted[1])
        self._requested = wanted if wanted != running else None

    def take_requested_settings(self) -> None:
        """Apply the settings requested since the last call (:meth:`update_settings`), if any."""
        if self._requested is not None:
            requested, self._requested = self._requested, None
            self.update_settings(*requested)

    @property
    def buffered(self) -> int:
        """Poses waiting in the jitter buffer now."""
        return len(self._queue)

    # --- inputs -------------------------------------------------------------------------------

    def points_to_take(self, n_points: int) -> int:
        """How many of a message's ``n_points`` poses to look at; the rest count as truncated."""
        cap = self.settings.max_points_per_message
        if n_points > cap:
            self.status.truncated += n_points - cap
            return cap
        return n_points

    def push(self, poses_rad: np.ndarray, now_s: float) -> int:
        """Check raw poses (n_frames, n_joints) and queue those the gate admits.

        Poses beyond ``max_points_per_message`` are dropped first; the gate rejects non-finite,
        out-of-range and unreachable poses and clamps the rest into the joint ranges.

        Returns:
            The number of poses accepted.
        """
        poses = np.asarray(poses_rad, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != self.robot.n_joints:
            self.status.rejected += 1
            return 0
        poses = poses[: self.points_to_take(len(poses))]
        counts = self.gate.counts
        before = (counts.non_finite, counts.out_of_range, counts.implausible)
        admitted = self.gate.admit(poses, now_s)
        if self.gate.new_track_at is not None and self.status.mode == "tracking":
            # A new track: the old track's queued poses are dropped, the smoother starts on the
            # new one (none of the old momentum, no transient of its own) and the approach
            # blends it in gently from the robot's pose.
            old = len(self._queue) + self.gate.new_track_at
            self.status.dropped += old
            self._queue.clear()
            admitted = admitted[self.gate.new_track_at :]
            self.style.reset()
            scaled = self.style.static(admitted[-1])
            if self._smoother is not None:
                self._smoother.reset(scaled)
            self.approach.begin(now_s, self.position_rad, scaled, self.limiter.max_velocity_rad_s)
        self.status.rejected += counts.non_finite - before[0]
        self.status.out_of_range += counts.out_of_range - before[1]
        self.status.implausible += counts.implausible - before[2]
        for i, pose in enumerate(admitted):
            if len(self._queue) == self._queue.maxlen:
                self.status.dropped += 1
            self._queue.append((now_s + i * self.period_s, pose))
        self.status.received += len(admitted)
        if len(admitted):
            self._last_input_s = now_s
            self._holding = False
        return len(admitted)

    def set_voice_active(self, active: bool, now_s: float) -> None:
        """Report voice activity; without any report the voice counts as active.

        A report holds until the next one, so a sender may report changes only
        (``audio_features_node`` does, with a refresh every 0.5 s): a report of silence after
        one of voice means the voice was active until now, and ``silence_timeout_s`` counts
        from here.
        """
        if active or (self._voice_reported and self.status.voice_active):
            self._last_voice_s = now_s
        self._voice_reported = True
        self.status.voice_active = active

    def set_enabled(self, enabled: bool) -> None:
        """Disable (glide to neutral, ignore generated motion) or re-enable the filter."""
        self.status.enabled = enabled

    def set_stop(self, stopped: bool) -> None:
        """Request or release the emergency stop (see ``stop_behaviour``)."""
        self.status.stopped = stopped

    def _external(
        self, values: Mapping[str, float], lower: np.ndarray, upper: np.ndarray, tolerance: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Head values and their mask; within ``tolerance`` outside [lower, upper] is clamped."""
        array, mask = np.zeros(self.robot.n_joints), np.zeros(self.robot.n_joints, dtype=bool)
        for name, value in values.items():
            if name not in self.robot.names or not self._head[self.robot.names.index(name)]:
                raise InputError(f"{name!r} is not a head joint of {self.robot.name}")
            index = self.robot.names.index(name)
            if not (lower[index] - tolerance <= value <= upper[index] + tolerance):
                raise InputError(
                    f"{name}: {value} rad is outside [{lower[index]:g}, {upper[index]:g}] rad"
                )
            array[index] = min(max(value, lower[index]), upper[index])
            mask[index] = True
        return array, mask

    def set_head_target(self, values: Mapping[str, float], now_s: float) -> None:
        """Absolute head joint targets (rad), blended with ``head_target_weight``.

        A value up to ``outlier_tolerance_rad`` outside the joint's range is clamped into it.

        Raises:
            InputError: a name is not a head joint, or a value is not finite or outside the
                joint's range (the previous target stays in force until it times out).
        """
        try:
            external = self._external(
                values,
                self.robot.lower_rad,
                self.robot.upper_rad,
                self.settings.outlier_tolerance_rad,
            )
        except InputError:
            self.status.external_rejected += 1
            raise
        self._head_target.set(*external, now_s)

    def set_head_offset(self, values: Mapping[str, float], now_s: float) -> None:
        """Head joint offsets (rad), each at most ``max_head_offset_rad``, added to head motion.

        Raises:
            InputError: a name is not a head joint, or a value is not finite or larger than
                ``max_head_offset_rad``.
        """
        limit = np.full(self.robot.n_joints, self.settings.max_head_offset_rad)
        try:
            external = self._external(values, -limit, limit, 0.0)
        except InputError:
            self.status.external_rejected += 1
            raise
        self._head_offset.set(*external, now_s)

    # --- output -------------------------------------------------------------------------------

    def _tracking_allowed(self, now_s: float) -> bool:
        settings, status = self.settings, self.status
        poses_recent = now_s - self._last_input_s <= settings.watchdog_timeout_s
        voice_recent = not self._voice_reported or (
            status.voice_active or now_s - self._last_voice_s <= settings.silence_timeout_s
        )
        return status.enabled and not status.stopped and poses_recent and voice_recent

    def _glide(self, now_s: float) -> np.ndarray:
        if self._glide_start is None:
            self._glide_start = (now_s, self.position_rad.copy())
        start_s, start_pose = self._glide_start
        fraction = minimum_jerk((now_s - start_s) / self.settings.neutral_glide_s)
        return start_pose + fraction * (self.neutral_rad - start_pose)

    def _track(self, now_s: float) -> np.ndarray:
        if self._glide_start is not None:  # resuming: start smoothing from where the robot is
            self._glide_start = None
            if self._smoother is not None:
                self._smoother.reset(self.position_rad)
            self._target = self.position_rad.copy()
            self.style.reset()
        # A pose whose successor is due too is overdue: the ticks fell behind the stream (poses
        # of two messages came together, a tick was late). It is skipped, so the newest due pose
        # is commanded now and no backlog stands behind it.
        while len(self._queue) > 1 and self._queue[1][0] <= now_s:
            self._queue.popleft()
            self.status.skipped += 1
        if self._queue:
            self._target = self._queue.popleft()[1]
        else:
            self.status.underruns += 1
        self._depths.append(len(self._queue))
        standing = min(self._depths) if len(self._depths) == self._depths.maxlen else 0
        if standing > 0:  # a standing backlog only adds latency: skip it (the smoother and the
            for _ in range(standing):  # limits turn the jump in the target into motion)
                self._queue.popleft()
            self.status.skipped += standing
            self._depths.clear()
        scaled = self.style.step(self._target)
        return scaled if self._smoother is None else self._smoother.step(scaled)

    def _compose_head(self, desired: np.ndarray, now_s: float) -> np.ndarray:
        timeout = self.settings.external_timeout_s
        target_mask = self._head_target.active(now_s, timeout)
        self.status.head_target_active = targeted = bool(target_mask.any())
        blended = desired
        if targeted:
            weight = self.settings.head_target_weight
            mixed = (1.0 - weight) * desired + weight * self._head_target.values
            blended = np.where(target_mask, mixed, desired)
        offset_mask = self._head_offset.active(now_s, timeout)
        if not offset_mask.any():  # no head offset in force (the usual case): nothing to add
            return blended
        return np.where(offset_mask, blended + self._head_offset.values, blended)

    def _fault(self, message: str, now_s: float) -> None:
        """Record a fault and restart the filter state from the last commanded pose."""
        self.status.faults += 1
        self.status.last_fault, self.status.last_fault_s = message, now_s
        if self._smoother is not None:
            self._smoother.reset(self.position_rad)
        if not np.isfinite(self._target).all():
            self._target = self.position_rad.copy()

    def _resume_after_gap(self, elapsed_s: float) -> None:
        """No tick for ``elapsed_s``: brake the velocity over that time, restart the smoother."""
        self.status.gaps += 1
        # every joint together, direction kept: the self-collision guard's checked braking path
        # (a straight line) still holds the joints' way to rest
        self.velocity_rad_s = brake_together(
            self.velocity_rad_s, self.limiter.max_acceleration_rad_s2, elapsed_s
        )
        if self._smoother is not None:
            self._smoother.reset(self.position_rad)

    def _safe(self, positions: np.ndarray, velocities: np.ndarray, dt_s: float) -> bool:
        limiter = self.limiter
        # After a live decrease of velocity_fraction the limiter brakes from the old velocity at
        # the acceleration limit, so a step may use the previous speed for a few ticks.
        speed = np.maximum(limiter.max_velocity_rad_s, np.abs(self.velocity_rad_s))
        lower, upper = limiter.allowed_range(self.position_rad)
        return bool(
            np.isfinite(positions).all()
            and np.isfinite(velocities).all()
            and (positions >= lower).all()
            and (positions <= upper).all()
            and (np.abs(positions - self.position_rad) <= speed * dt_s + STEP_SLACK_RAD).all()
        )

    def tick(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance one output period and return ``(positions_rad, velocities_rad_s)``."""
        status = self.status
        elapsed_s = self.period_s if self._last_tick_s is None else now_s - self._last_tick_s
        if elapsed_s > GAP_PERIODS * self.period_s:
            self._resume_after_gap(elapsed_s)
        if status.stopped:
            status.dropped += len(self._queue)  # nothing generated meanwhile is replayed later
            self._queue.clear()
            if self.settings.stop_behaviour == "hold":
                self._glide_start = None
                desired = self.position_rad  # the limiter brakes to a standstill and holds there
            else:
                desired = self._glide(now_s)
            status.mode = "stopped"
            status.head_target_active = False
        elif self._tracking_allowed(now_s):
            if status.mode != "tracking":  # resuming: approach the track gently
                ahead = self._queue[0][1] if self._queue else self._target
                self.approach.begin(
                    now_s, self.position_rad, ahead, self.limiter.max_velocity_rad_s
                )
            desired = self._compose_head(self.approach.blend(self._track(now_s), now_s), now_s)
            status.mode = "tracking"
        elif self._holding and status.enabled:
            self._glide_start = None
            desired = self.position_rad  # started: wait where the robot is for the first pose
            status.mode = "waiting"
        else:
            # Poses generated meanwhile (of silence, or while disabled) are stale: replaying
            # them when tracking resumes would only add latency and wrong motion.
            status.dropped += len(self._queue)
            self._queue.clear()
            desired = self._compose_head(self._glide(now_s), now_s)
            status.mode = "neutral"
        status.buffered = len(self._queue)
        if not np.isfinite(desired).all() or (
            self._smoother is not None and not self._smoother.is_finite()
        ):
            self._fault("non-finite filter state reset from the last commanded pose", now_s)
            desired = self.position_rad

        dt_s = min(elapsed_s, 2.0 * self.period_s)  # a stalled timer must not allow a large jump
        if self._last_tick_s is None or now_s > self._last_tick_s:
            self._last_tick_s = now_s
        positions, velocities = self.limiter.enforce(
            desired, self.position_rad, self.velocity_rad_s, dt_s
        )
        positions, velocities = self.body_guard.enforce(
            positions,
            velocities,
            self.position_rad,
            self.velocity_rad_s,
            dt_s,
            self.limiter,
        )
        if not self._safe(positions, velocities, max(dt_s, 0.0)):
            self._fault("unsafe command replaced by the last commanded pose", now_s)
            positions, velocities = self.position_rad.copy(), np.zeros(self.robot.n_joints)
        self.position_rad, self.velocity_rad_s = positions, velocities
        return self.position_rad, self.velocity_rad_s


def online_filter(filt: MotionFilter, raw_rad: np.ndarray, tail_s: float = 2.0) -> np.ndarray:
    """What ``filt`` commands for a steady stream: one raw pose per tick, then ``tail_s`` more.

    The node's own loop without ROS (``push`` then ``tick`` every period), for plots and for
    scoring the motion the robot is commanded (:mod:`audio2pose_ros.learning.command_path`).

    Returns:
        (n_frames + tail frames, n_joints) commanded positions.
    """
    out, t = [], 0.0
    for pose in raw_rad:
        t += filt.period_s
        filt.push(pose[None, :], t)
        out.append(filt.tick(t)[0].copy())
    for _ in range(round(tail_s / filt.period_s)):
        t += filt.period_s
        out.append(filt.tick(t)[0].copy())
    return np.array(out)


def delay_s(
    references: Sequence[np.ndarray], delayed: Sequence[np.ndarray], rate_hz: float = 100.0
) -> float:
    """How far trajectories trail their references (s): median cross-correlation lag.

    Args:
        references: (T, J) trajectories, e.g. the offline synthesis.
        delayed: the same trajectories as a filter commands them, at least T frames each.
        rate_hz: frame rate of both.

    Returns:
        The median over every pair and joint that moves (std above 1e-6 in both) of the lag
        at which the delayed joint best correlates with its reference; NaN when none moves.
    """
    lags = []
    for reference, late in zip(references, delayed, strict=True):
        n = len(reference)
        for j in range(reference.shape[1]):
            a = reference[:, j] - reference[:, j].mean()
            b = late[:n, j] - late[:n, j].mean()
            if a.std() > 1e-6 and b.std() > 1e-6:
                lags.append((np.argmax(np.correlate(b, a, mode="full")) - (n - 1)) / rate_hz)
    return float(np.median(lags)) if lags else float("nan")
