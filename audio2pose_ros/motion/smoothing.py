"""Trajectory smoothing: offline zero-phase Butterworth, online Kalman filter and causal low-pass.

Seed 003 section 4.2.3 smooths joint-angle trajectories with a 5th-order low-pass Butterworth
filter at f_c = 4 Hz (offline synthesis, section 4.4.1) and, online (section 4.4.2), with a
per-joint Kalman filter. Trajectories are (n_frames, n_joints) arrays sampled at ``rate_hz``.

scipy is imported by the offline zero-phase filter only: the online filters (the causal
low-pass, :func:`butterworth_sos` in numpy, and the Kalman filter) need numpy alone, so
``motion_filter_node`` starts without scipy's import time and memory (about 0.8 s and 75 MB).
"""

from __future__ import annotations

import numpy as np

SEED_CUTOFF_HZ = 4.0  # seed 003 section 4.2.3: "f_c = 4 Hz resulted in most natural movements"
SEED_ORDER = 5  # seed 003 section 4.2.3: 5th-order low-pass Butterworth filter


def butterworth_sos(
    rate_hz: float, cutoff_hz: float = SEED_CUTOFF_HZ, order: int = SEED_ORDER
) -> np.ndarray:
    """Second-order sections of a digital Butterworth low-pass, each of unit gain at 0 Hz.

    The analog prototype's poles w_a exp(i pi (2k + n + 1) / 2n), k = 0 .. n - 1, at the
    pre-warped cut-off w_a = 2 f_s tan(pi f_c / f_s), mapped by the bilinear transform
    z = (1 + s / 2f_s) / (1 - s / 2f_s); the zeros are at z = -1. A conjugate pair makes one
    section, the real pole of an odd order a first-order one (last). numpy only, so the online
    filter starts without scipy (about 0.8 s and 75 MB); the cascade equals
    ``scipy.signal.butter(order, cutoff_hz, fs=rate_hz, output="sos")`` (tested).

    Returns:
        (n_sections, 6) rows [b0, b1, b2, 1, a1, a2].

    Raises:
        ValueError: the cut-off is not inside (0, rate_hz / 2), or the order is below 1.
    """
    if not 0.0 < cutoff_hz < rate_hz / 2.0:
        raise ValueError(f"cutoff_hz {cutoff_hz} must lie in (0, {rate_hz / 2.0}) Hz")
    if order < 1:
        raise ValueError(f"order {order} must be at least 1")
    warped = 2.0 * rate_hz * np.tan(np.pi * cutoff_hz / rate_hz)
    k = np.arange(order)
    analog = warped * np.exp(1j * np.pi * (2 * k + order + 1) / (2 * order))
    poles = (1.0 + analog / (2.0 * rate_hz)) / (1.0 - analog / (2.0 * rate_hz))
    sections = []
    for pole in poles[poles.imag > 1e-9 * np.abs(poles)]:
        a = np.array([1.0, -2.0 * pole.real, abs(pole) ** 2])
        sections.append(np.concatenate([np.array([1.0, 2.0, 1.0]) * a.sum() / 4.0, a]))
    if order % 2:
        real = float(poles[np.argmin(np.abs(poles.imag))].real)
        sections.append(np.array([(1.0 - real) / 2.0, (1.0 - real) / 2.0, 0.0, 1.0, -real, 0.0]))
    return np.array(sections)


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

    sos = butterworth_sos(rate_hz, cutoff_hz, order)
    padlen = min(3 * (2 * len(sos) + 1), data.shape[0] - 1)
    return signal.sosfiltfilt(sos, data, axis=0, padlen=padlen)


class CausalLowPass:
    """Streaming Butterworth low-pass, one frame at a time (causal, so it delays the motion).

    The seed's offline smoother (5th order, 4 Hz; section 4.2.3) run forwards only: its
    :func:`butterworth_sos` sections in transposed direct form II, in numpy. The default
    smoother of the motion filter: it passes the model's motion below the cut-off as the offline
    synthesis does, without the Kalman filter's rise of about 1.3 at 1 to 2 Hz.
    """

    def __init__(
        self,
        n_joints: int,
        rate_hz: float = 100.0,
        cutoff_hz: float = SEED_CUTOFF_HZ,
        order: int = SEED_ORDER,
    ) -> None:
        """Design the filter; call :meth:`reset` with the starting pose before use."""
        self._sos = butterworth_sos(rate_hz, cutoff_hz, order)
        self.reset(np.zeros(n_joints))

    def reset(self, pose: np.ndarray) -> None:
        """Start in steady state at ``pose`` (no transient).

        Every section has unit gain at 0 Hz, so each one's output is ``pose`` too; its state
        is then s1 = (b1 + b2 - a1 - a2) x and s2 = (b2 - a2) x.
        """
        x = np.asarray(pose, dtype=np.float64)
        b1, b2, a1, a2 = (self._sos[:, i, None] for i in (1, 2, 4, 5))
        self._state = np.stack(((b1 + b2 - a1 - a2) * x, (b2 - a2) * x), axis=1)

    def is_finite(self) -> bool:
        """Whether the whole filter state is finite (a NaN/inf state would never recover)."""
        return bool(np.isfinite(self._state).all())

    def step(self, pose: np.ndarray) -> np.ndarray:
        """Filter one (n_joints,) frame and return the smoothed frame."""
        x = np.asarray(pose, dtype=np.float64)
        for (b0, b1, b2, _, a1, a2), state in zip(self._sos, self._state, strict=True):
            y = b0 * x + state[0]
            state[0] = b1 * x - a1 * y + state[1]
            state[1] = b2 * x - a2 * y
            x = y
        return x.copy()


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
