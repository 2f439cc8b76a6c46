"""The online motion filter: paces raw model poses to a fixed rate, smooths them, limits them.

This is the ROS-free core of ``motion_filter_node``. Raw poses arrive in bursts (one burst per
audio chunk); :class:`MotionFilter` queues them in a short jitter buffer and, at every
:meth:`MotionFilter.tick`, takes one pose, scales each joint group around the neutral pose, smooths
it causally (seed 003 section 4.4.2) and applies the joint limits last. When no pose has arrived
for ``watchdog_timeout_s`` the target becomes the neutral pose, which the smoother and the limiter
turn into a glide without a jump.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.limits import JointLimiter, LimitSettings
from audio2pose_ros.motion.smoothing import CausalLowPass, KalmanSmoother
from audio2pose_ros.robot import JOINT_GROUPS, RobotDescription

SMOOTHING_METHODS = ("kalman", "lowpass", "none")


@dataclass(frozen=True)
class MotionFilterSettings:
    """Settings of :class:`MotionFilter` (defaults are the ones shipped in config/pepper.yaml).

    Attributes:
        rate_hz: output rate (Hz); seed 003 clocks commands at f_f = 100 Hz.
        smoothing: 'kalman' (seed 003 section 4.4.2), 'lowpass' (causal Butterworth) or 'none'.
        kalman_q: Kalman process noise (seed value 0.5).
        kalman_r: Kalman measurement noise (seed value 0.01).
        lowpass_cutoff_hz: cut-off of the causal low-pass (seed value 4 Hz).
        watchdog_timeout_s: without input for this long, glide to the neutral pose (s).
        max_buffer_s: poses queued beyond this much motion are dropped, oldest first (s).
        head_gain: scale of head motion around neutral (0 = head still, 1 = as generated).
        arms_gain: scale of arm motion around neutral.
        hip_gain: scale of hip motion around neutral.

    """

    rate_hz: float = 100.0
    smoothing: str = "kalman"
    kalman_q: float = 0.5
    kalman_r: float = 0.01
    lowpass_cutoff_hz: float = 4.0
    watchdog_timeout_s: float = 0.5
    max_buffer_s: float = 0.3
    head_gain: float = 1.0
    arms_gain: float = 1.0
    hip_gain: float = 1.0

    def __post_init__(self) -> None:
        """Reject settings that would make the filter unsafe or meaningless."""
        if self.smoothing not in SMOOTHING_METHODS:
            raise ValueError(f"smoothing {self.smoothing!r} is not one of {SMOOTHING_METHODS}")
        if self.rate_hz <= 0 or self.watchdog_timeout_s <= 0 or self.max_buffer_s <= 0:
            raise ValueError("rate_hz, watchdog_timeout_s and max_buffer_s must be positive")
        for group in JOINT_GROUPS:
            gain = getattr(self, f"{group}_gain")
            if not 0.0 <= gain <= 1.0:
                raise ValueError(f"{group}_gain must be in [0, 1], got {gain}")


@dataclass
class FilterStatus:
    """Counters and state for diagnostics."""

    received: int = 0
    rejected: int = 0
    dropped: int = 0
    underruns: int = 0
    watchdog_active: bool = True
    buffered: int = 0


class MotionFilter:
    """Jitter buffer, group gains, causal smoothing and joint limits, stepped at ``rate_hz``."""

    def __init__(
        self,
        robot: RobotDescription,
        settings: MotionFilterSettings | None = None,
        limits: LimitSettings | None = None,
    ) -> None:
        """Start at rest in the neutral pose with the watchdog active."""
        self.robot = robot
        self.settings = settings or MotionFilterSettings()
        self.limiter = JointLimiter(robot, limits)
        self.period_s = 1.0 / self.settings.rate_hz
        self._neutral = self.limiter.clamp_position(robot.neutral_rad)
        self._gains = np.ones(robot.n_joints)
        for group in JOINT_GROUPS:
            self._gains[robot.group_mask(group)] = getattr(self.settings, f"{group}_gain")
        self._queue: deque[np.ndarray] = deque(
            maxlen=max(1, round(self.settings.max_buffer_s * self.settings.rate_hz))
        )
        self._smoother = self._make_smoother()
        self.status = FilterStatus()
        self.position_rad = self._neutral.copy()
        self.velocity_rad_s = np.zeros(robot.n_joints)
        self._target = self._neutral.copy()
        self._last_input_s: float | None = None
        self._last_tick_s: float | None = None

    def _make_smoother(self) -> KalmanSmoother | CausalLowPass | None:
        n = self.robot.n_joints
        if self.settings.smoothing == "kalman":
            smoother: KalmanSmoother | CausalLowPass = KalmanSmoother(
                n, self.period_s, self.settings.kalman_q, self.settings.kalman_r
            )
        elif self.settings.smoothing == "lowpass":
            smoother = CausalLowPass(n, self.settings.rate_hz, self.settings.lowpass_cutoff_hz)
        else:
            return None
        smoother.reset(self._neutral)
        return smoother

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

    def tick(self, now_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Advance one output period and return ``(positions_rad, velocities_rad_s)``."""
        timeout = self.settings.watchdog_timeout_s
        silent = self._last_input_s is None or now_s - self._last_input_s > timeout
        if self._queue:
            self._target = self._queue.popleft()
        elif silent:
            self._target = self._neutral
        else:
            self.status.underruns += 1
        self.status.watchdog_active = silent and not self._queue
        self.status.buffered = len(self._queue)

        scaled = self._neutral + self._gains * (self._target - self._neutral)
        smoothed = scaled if self._smoother is None else self._smoother.step(scaled)
        dt_s = self.period_s if self._last_tick_s is None else now_s - self._last_tick_s
        dt_s = min(dt_s, 2.0 * self.period_s)  # a stalled timer must not allow a large jump
        self._last_tick_s = now_s
        self.position_rad, self.velocity_rad_s = self.limiter.enforce(
            smoothed, self.position_rad, self.velocity_rad_s, dt_s
        )
        return self.position_rad, self.velocity_rad_s
