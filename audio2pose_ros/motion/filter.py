"""The online motion filter: paces raw model poses to a fixed rate, smooths them, limits them.

This is the ROS-free core of ``motion_filter_node``. Raw poses arrive in bursts (one burst per
audio chunk); :class:`MotionFilter` queues them in a short jitter buffer and, at every
:meth:`MotionFilter.tick`, produces one command:

1. **Mode.** It *tracks* the generated motion while poses arrive, the voice is active, the filter
   is enabled and no stop is requested. Otherwise it *glides to the neutral pose* along a
   minimum-jerk path of ``neutral_glide_s`` that starts where the robot is, or, on an emergency
   stop with ``stop_behaviour: hold``, brakes to a standstill and *holds*.
2. **Tracking.** Each joint group is scaled around the neutral pose by its gain, and the pose
   is smoothed causally (seed 003 section 4.4.2: Kalman filter; or a low-pass; or none). When
   tracking resumes, the smoother restarts from the current pose, so nothing jumps.
3. **Head composition.** An external head target (a face tracker's look-at) is blended into the
   head joints with ``head_target_weight``, and an external offset is added, for
   ``external_timeout_s`` after each message, in every mode but an emergency stop.
4. **Limits last** (:class:`~audio2pose_ros.motion.limits.JointLimiter`): position, velocity,
   acceleration. Nothing after them changes the command.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.motion.smoothing import CausalLowPass, KalmanSmoother
from audio2pose_ros.robot import JOINT_GROUPS, RobotDescription

SMOOTHING_METHODS = ("kalman", "lowpass", "none")
STOP_BEHAVIOURS = ("hold", "neutral")
MODES = ("tracking", "neutral", "stopped")


def minimum_jerk(fraction: float) -> float:
    """Position fraction of a minimum-jerk move at time fraction ``fraction`` in [0, 1].

    10 s^3 - 15 s^4 + 6 s^5: zero velocity and acceleration at both ends (Flash and Hogan's
    minimum-jerk profile; seed 003 section 3.4.4 cites minimum-jerk human movement).
    """
    s = min(max(fraction, 0.0), 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


@dataclass(frozen=True)
class MotionFilterSettings:
    """Settings of :class:`MotionFilter` (defaults are the ones shipped in config/pepper.yaml).

    Attributes:
        rate_hz: output rate (Hz); seed 003 clocks commands at f_f = 100 Hz.
        smoothing: 'kalman' (seed 003 section 4.4.2), 'lowpass' (causal Butterworth) or 'none'.
        kalman_q: Kalman process noise (seed value 0.5).
        kalman_r: Kalman measurement noise (seed value 0.01).
        lowpass_cutoff_hz: cut-off of the causal low-pass (seed value 4 Hz).
        watchdog_timeout_s: without poses for this long, glide to the neutral pose (s).
        silence_timeout_s: with the voice inactive for this long, glide to neutral (s).
        neutral_glide_s: duration of the glide to the neutral pose (s).
        stop_behaviour: on an emergency stop, 'hold' (brake and stay) or 'neutral' (glide).
        max_buffer_s: poses queued beyond this much motion are dropped, oldest first (s).
        backlog_window_s: when the buffer never ran empty after a tick during this whole window,
            the poses it never went below are skipped, so a standing backlog (latency) drains (s).
        head_gain: scale of head motion around neutral (0 = head still, 1 = as generated).
        arms_gain: scale of arm motion around neutral.
        hip_gain: scale of hip motion around neutral.
        head_target_weight: weight of an external head target against generated head motion.
        external_timeout_s: an external head target or offset counts for this long (s).
    """

    rate_hz: float = 100.0
    smoothing: str = "kalman"
    kalman_q: float = 0.5
    kalman_r: float = 0.01
    lowpass_cutoff_hz: float = 4.0
    watchdog_timeout_s: float = 0.5
    silence_timeout_s: float = 1.0
    neutral_glide_s: float = 1.0
    stop_behaviour: str = "hold"
    max_buffer_s: float = 0.3
    backlog_window_s: float = 0.2
    head_gain: float = 1.0
    arms_gain: float = 1.0
    hip_gain: float = 1.0
    head_target_weight: float = 0.8
    external_timeout_s: float = 0.5

    def __post_init__(self) -> None:
        """Reject settings that would make the filter unsafe or meaningless."""
        if self.smoothing not in SMOOTHING_METHODS:
            raise ValueError(f"smoothing {self.smoothing!r} is not one of {SMOOTHING_METHODS}")
        if self.stop_behaviour not in STOP_BEHAVIOURS:
            raise ValueError(
                f"stop_behaviour {self.stop_behaviour!r} is not one of {STOP_BEHAVIOURS}"
            )
        for name in (
            "rate_hz",
            "watchdog_timeout_s",
            "silence_timeout_s",
            "neutral_glide_s",
            "max_buffer_s",
            "external_timeout_s",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in (*(f"{g}_gain" for g in JOINT_GROUPS), "head_target_weight"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")


@dataclass
class FilterStatus:
    """Counters and state for diagnostics."""

    mode: str = "neutral"
    received: int = 0
    rejected: int = 0
    dropped: int = 0  # buffer overflow, or generated while not tracking (stale)
    underruns: int = 0
    skipped: int = 0
    buffered: int = 0
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

    def set(self, values: np.ndarray, mask: np.ndarray, now_s: float) -> None:
        self.values, self.mask, self.stamp_s = values, mask, now_s

    def active(self, now_s: float, timeout_s: float) -> np.ndarray:
        """Mask of joints with a fresh value (all False when stale)."""
        return self.mask if now_s - self.stamp_s <= timeout_s else np.zeros_like(self.mask)


class MotionFilter:
    """Jitter buffer, modes, group gains, smoothing, head composition and limits at ``rate_hz``."""

    def __init__(
        self,
        robot: RobotDescription,
        settings: MotionFilterSettings | None = None,
        limits: LimitSettings | None = None,
    ) -> None:
        """Start at rest in the neutral pose."""
        self.robot = robot
        self.settings = settings or MotionFilterSettings()
        self.limiter = JointLimiter(robot, limits)
        self.period_s = 1.0 / self.settings.rate_hz
        self.neutral_rad = self.limiter.clamp_position(robot.neutral_rad)
        self._gains = np.ones(robot.n_joints)
        for group in JOINT_GROUPS:
            self._gains[robot.group_mask(group)] = getattr(self.settings, f"{group}_gain")
        self._head = robot.group_mask("head")
        self._queue: deque[np.ndarray] = deque(
            maxlen=max(1, round(self.settings.max_buffer_s * self.settings.rate_hz))
        )
        self._depths: deque[int] = deque(
            maxlen=max(1, round(self.settings.backlog_window_s * self.settings.rate_hz))
        )
        self._smoother = self._make_smoother()
        if self._smoother is not None:
            self._smoother.reset(self.neutral_rad)
        self.status = FilterStatus()
        self.position_rad = self.neutral_rad.copy()
        self.velocity_rad_s = np.zeros(robot.n_joints)
        self._target = self.neutral_rad.copy()
        self._last_input_s = -np.inf
        self._last_voice_s = -np.inf
        self._voice_reported = False
        self._last_tick_s: float | None = None
        self._glide_start: tuple[float, np.ndarray] | None = None
        self._head_target = _External(robot.n_joints)
        self._head_offset = _External(robot.n_joints)

    def _make_smoother(self) -> KalmanSmoother | CausalLowPass | None:
        n = self.robot.n_joints
        if self.settings.smoothing == "kalman":
            return KalmanSmoother(n, self.period_s, self.settings.kalman_q, self.settings.kalman_r)
        if self.settings.smoothing == "lowpass":
            return CausalLowPass(n, self.settings.rate_hz, self.settings.lowpass_cutoff_hz)
        return None

    @property
    def buffered(self) -> int:
        """Poses waiting in the jitter buffer now."""
        return len(self._queue)

    # --- inputs -------------------------------------------------------------------------------

    def push(self, poses_rad: np.ndarray, now_s: float) -> int:
        """Queue raw poses (n_frames, n_joints); frames with non-finite values are rejected.

        Returns:
            The number of frames accepted.
        """
        poses = np.asarray(poses_rad, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != self.robot.n_joints:
            self.status.rejected += 1
            return 0
        good = np.isfinite(poses).all(axis=1)
        self.status.rejected += int(np.count_nonzero(~good))
        for pose in poses[good]:
            if len(self._queue) == self._queue.maxlen:
                self.status.dropped += 1
            self._queue.append(pose)
        accepted = int(np.count_nonzero(good))
        self.status.received += accepted
        if accepted:
            self._last_input_s = now_s
        return accepted

    def set_voice_active(self, active: bool, now_s: float) -> None:
        """Report voice activity; without any report the voice counts as active."""
        self._voice_reported = True
        self.status.voice_active = active
        if active:
            self._last_voice_s = now_s

    def set_enabled(self, enabled: bool) -> None:
        """Disable (glide to neutral, ignore generated motion) or re-enable the filter."""
        self.status.enabled = enabled

    def set_stop(self, stopped: bool) -> None:
        """Request or release the emergency stop (see ``stop_behaviour``)."""
        self.status.stopped = stopped

    def _external(self, values: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        array, mask = np.zeros(self.robot.n_joints), np.zeros(self.robot.n_joints, dtype=bool)
        for name, value in values.items():
            if name not in self.robot.names or not self._head[self.robot.names.index(name)]:
                raise ValueError(f"{name!r} is not a head joint of {self.robot.name}")
            if not np.isfinite(value):
                raise ValueError(f"{name}: value {value} is not finite")
            index = self.robot.names.index(name)
            array[index], mask[index] = value, True
        return array, mask

    def set_head_target(self, values: Mapping[str, float], now_s: float) -> None:
        """Absolute head joint targets (rad), blended with ``head_target_weight``.

        Raises:
            ValueError: a name is not a head joint, or a value is not finite.
        """
        self._head_target.set(*self._external(values), now_s)

    def set_head_offset(self, values: Mapping[str, float], now_s: float) -> None:
        """Head joint offsets (rad) added to the head motion.

        Raises:
            ValueError: a name is not a head joint, or a value is not finite.
        """
        self._head_offset.set(*self._external(values), now_s)

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

    def _track(self) -> np.ndarray:
        if self._glide_start is not None:  # resuming: start smoothing from where the robot is
            self._glide_start = None
            if self._smoother is not None:
                self._smoother.reset(self.position_rad)
            self._target = self.position_rad.copy()
        if self._queue:
            self._target = self._queue.popleft()
        else:
            self.status.underruns += 1
        self._depths.append(len(self._queue))
        standing = min(self._depths) if len(self._depths) == self._depths.maxlen else 0
        if standing > 0:  # a standing backlog only adds latency: skip it (the smoother and the
            for _ in range(standing):  # limits turn the jump in the target into motion)
                self._queue.popleft()
            self.status.skipped += standing
            self._depths.clear()
        scaled = self.neutral_rad + self._gains * (self._target - self.neutral_rad)
        return scaled if self._smoother is None else self._smoother.step(scaled)

    def _compose_head(self, desired: np.ndarray, now_s: float) -> np.ndarray:
        timeout = self.settings.external_timeout_s
        target_mask = self._head_target.active(now_s, timeout)
        self.status.head_target_active = bool(target_mask.any())
        weight = self.settings.head_target_weight
        blended = np.where(
            target_mask, (1.0 - weight) * desired + weight * self._head_target.values, desired
        )
        offset_mask = self._head_offset.active(now_s, timeout)
        return np.where(offset_mask, blended + self._head_offset.values, blended)

    def tick(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance one output period and return ``(positions_rad, velocities_rad_s)``."""
        status = self.status
        stop_and_hold = status.stopped and self.settings.stop_behaviour == "hold"
        if stop_and_hold:
            self._queue.clear()
            self._glide_start = None
            desired = self.position_rad  # the limiter brakes to a standstill and holds there
            status.mode = "stopped"
        elif self._tracking_allowed(now_s):
            desired = self._compose_head(self._track(), now_s)
            status.mode = "tracking"
        else:
            # Poses generated meanwhile (of silence, or while disabled or stopped) are stale:
            # replaying them when tracking resumes would only add latency and wrong motion.
            status.dropped += len(self._queue)
            self._queue.clear()
            desired = self._compose_head(self._glide(now_s), now_s)
            status.mode = "neutral"
        status.buffered = len(self._queue)

        dt_s = self.period_s if self._last_tick_s is None else now_s - self._last_tick_s
        dt_s = min(dt_s, 2.0 * self.period_s)  # a stalled timer must not allow a large jump
        if self._last_tick_s is None or now_s > self._last_tick_s:
            self._last_tick_s = now_s
        self.position_rad, self.velocity_rad_s = self.limiter.enforce(
            desired, self.position_rad, self.velocity_rad_s, dt_s
        )
        return self.position_rad, self.velocity_rad_s
