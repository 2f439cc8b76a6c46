"""Trajectory smoothing: offline zero-phase Butterworth, online Kalman filter and causal low-pass.

Seed 003 section 4.2.3 smooths joint-angle trajectories with a 5th-order low-pass Butterworth
filter at f_c = 4 Hz (offline synthesis, section 4.4.1) and, online (section 4.4.2), with a
per-joint Kalman filter. Trajectories are (n_frames, n_joints) arrays sampled at ``rate_hz``.

scipy is imported by the Butterworth filters only, when one is built: the online default (the
Kalman filter) needs numpy alone, so ``motion_filter_node`` starts without scipy's import time
and memory (about 0.6 s and 70 MB of start-up).
"""

from __future__ import annotations

import numpy as np

SEED_CUTOFF_HZ = 4.0  # seed 003 section 4.2.3: "f_c = 4 Hz resulted in most natural movements"
SEED_ORDER = 5  # seed 003 section 4.2.3: 5th-order low-pass Butterworth filter


def _butterworth_sos(rate_hz: float, cutoff_hz: float, order: int) -> np.ndarray:
    if not 0.0 < cutoff_hz < rate_hz / 2.0:
        raise ValueError(f"cutoff_hz {cutoff_hz} must lie in (0, {rate_hz / 2.0}) Hz")
    from scipy import signal

    return signal.butter(order, cutoff_hz, btype="low", fs=rate_hz, output="sos")


def butterworth_zero_phase(
    trajectory: np.ndarray,
    rate_hz: float = 100.0,
    cutoff_hz: float = SEED_CUTOFF_HZ,
    order: int = SEED_ORDER,
) -> np.ndarray:
    """Zero-phase low-pass of a whole trajectory (offline; seed 003 section 4.2.3).

    Args:
        trajectory: (n_frames, n_joints) angles.
        rate_hz: frame rate (default 100 Hz, the seed's f_f).
        cutoff_hz: cut-off frequency (default 4 Hz).
        order: Butterworth order (default 5).

    Returns:
        (n_frames, n_joints) smoothed angles. Sequences too short for forward-backward filtering
        (fewer than about 3 * 2 * order frames) use odd padding as long as the sequence allows.

    """
    data = np.asarray(trajectory, dtype=np.float64)
    if data.shape[0] < 2:
        return data.copy()
    from scipy import signal

    sos = _butterworth_sos(rate_hz, cutoff_hz, order)
    padlen = min(3 * (2 * len(sos) + 1), data.shape[0] - 1)
    return signal.sosfiltfilt(sos, data, axis=0, padlen=padlen)


class CausalLowPass:
    """Streaming Butterworth low-pass, one frame at a time (causal, so it delays the motion)."""

    def __init__(
        self,
        n_joints: int,
        rate_hz: float = 100.0,
        cutoff_hz: float = SEED_CUTOFF_HZ,
        order: int = SEED_ORDER,
    ) -> None:
        """Design the filter; call :meth:`reset` with the starting pose before use."""
        from scipy import signal

        self._sos = _butterworth_sos(rate_hz, cutoff_hz, order)
        self._sosfilt = signal.sosfilt
        self._zi_unit = signal.sosfilt_zi(self._sos)  # (n_sections, 2) for a unit step
        self._state = np.zeros((len(self._sos), 2, n_joints))
        self.reset(np.zeros(n_joints))

    def reset(self, pose: np.ndarray) -> None:
        """Start in steady state at ``pose`` (no transient)."""
        self._state = self._zi_unit[:, :, None] * np.asarray(pose, dtype=np.float64)[None, None, :]

    def is_finite(self) -> bool:
        """Whether the whole filter state is finite (a NaN/inf state would never recover)."""
        return bool(np.isfinite(self._state).all())

    def step(self, pose: np.ndarray) -> np.ndarray:
        """Filter one (n_joints,) frame and return the smoothed frame."""
        out, self._state = self._sosfilt(
            self._sos, np.asarray(pose, dtype=np.float64)[None, :], axis=0, zi=self._state
        )
        return out[0]


class KalmanSmoother:
    """Per-joint constant-acceleration Kalman filter (seed 003 section 4.4.2; q=0.5, r=0.01).

    The state of each joint is [angle, velocity, acceleration]; only the angle is measured. The
    process noise is the discrete piecewise-white-noise model Q = q * G G^T with
    G = [dt^2/2, dt, 1]. Every joint is measured at the same fixed rate with the same F, Q and
    R, so all joints share one covariance, which converges to the solution of the discrete
    Riccati equation within a fraction of a second. The filter uses that steady-state gain from
    the start (a steady-state Kalman filter): a step is one 3x3 product and one correction.
    """

    RICCATI_ITERATIONS = 2000  # ample: the gain settles to machine precision in a few hundred

    def __init__(self, n_joints: int, dt_s: float = 0.01, q: float = 0.5, r: float = 0.01) -> None:
        """Build the model and its steady-state gain; call :meth:`reset` before use."""
        if dt_s <= 0 or q <= 0 or r <= 0:
            raise ValueError(f"dt_s, q and r must be positive, got {dt_s}, {q}, {r}")
        self._f = np.array([[1.0, dt_s, 0.5 * dt_s * dt_s], [0.0, 1.0, dt_s], [0.0, 0.0, 1.0]])
        g = np.array([[0.5 * dt_s * dt_s], [dt_s], [1.0]])
        process = q * (g @ g.T)
        covariance = np.eye(3)
        for _ in range(self.RICCATI_ITERATIONS):
            predicted = self._f @ covariance @ self._f.T + process
            gain = predicted[:, 0:1] / (predicted[0, 0] + r)
            covariance = predicted - gain @ predicted[0:1, :]
        self.gain = gain[:, 0].copy()  # (3,): angle, velocity, acceleration
        self._x = np.zeros((3, n_joints))

    def reset(self, pose: np.ndarray) -> None:
        """Start at rest at ``pose``."""
        self._x = np.zeros_like(self._x)
        self._x[0] = np.asarray(pose, dtype=np.float64)

    def is_finite(self) -> bool:
        """Whether the whole state (angle, velocity, acceleration) is finite."""
        return bool(np.isfinite(self._x).all())

    def step(self, measurement: np.ndarray) -> np.ndarray:
        """Predict one frame ahead and correct with ``measurement`` (n_joints,).

        Joints whose measurement is NaN/inf are predicted only (no correction).
        """
        with np.errstate(invalid="ignore", over="ignore"):  # callers check is_finite()
            x = self._f @ self._x
            residual = np.asarray(measurement, dtype=np.float64) - x[0]
            if not np.isfinite(residual).all():
                residual = np.where(np.isfinite(residual), residual, 0.0)
            x += self.gain[:, None] * residual
        self._x = x
        return x[0].copy()
