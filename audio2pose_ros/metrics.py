"""Evaluation metrics of seed 003 (Ondras 2018) section 3.4, plus distribution and diversity.

Notation of the seed: Omega (N_fr, N_fe) audio features, ^t Theta and ^p Theta (N_fr, J) true and
predicted joint angles (radians), f_f the frame rate (100 Hz). Masks are (N_fr, J) booleans,
True where the true angle is known: RMSE and L average over known values only; LCCA and jerk use
the joints known in every frame of the clip (a partly known joint has no complete trajectory).

Beyond the seed, the numerical evaluation of the GENEA challenge compares the distributions of
joint speed and acceleration of generated and real motion with the Hellinger distance between
their histograms (:func:`hellinger_speed`, :func:`hellinger_acceleration`); for samplers,
:func:`diversity_deg` measures how different several samples for the same audio are.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

LCCA_WINDOW_S = 3.0  # seed 003 section 3.4.3: tau = 3 s, N_tau = tau * f_f frames
_RANK_TOLERANCE = 1e-10  # singular values below this (relative) span no direction in CCA
# Histogram bins (documented choice; GENEA does not fix units for joint angles): speed |d theta/dt|
# in 0.1 rad/s bins up to 5 rad/s, acceleration |d^2 theta/dt^2| in 5 rad/s^2 bins up to
# 200 rad/s^2; larger values fall into the last bin, so no value is dropped.
SPEED_BINS_RAD_S = np.append(np.arange(0.0, 5.0, 0.1), np.inf)
ACCELERATION_BINS_RAD_S2 = np.append(np.arange(0.0, 200.0, 5.0), np.inf)


def _mask_or_all(true: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    return np.ones(true.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)


def rmse_deg_per_joint(
    true_rad: np.ndarray, pred_rad: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """RMSE of each joint angle in degrees, seed 003 eq. 3.11.

    Args:
        true_rad: (N_fr, J) true angles (rad).
        pred_rad: (N_fr, J) predicted angles (rad).
        mask: (N_fr, J) known values; None = all known.

    Returns:
        (J,) RMSE in degrees; NaN for a joint with no known value.

    """
    known = _mask_or_all(true_rad, mask)
    squared = np.where(known, (np.asarray(true_rad) - np.asarray(pred_rad)) ** 2, 0.0)
    count = known.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.degrees(np.sqrt(squared.sum(axis=0) / count))


def rmse_deg(true_rad: np.ndarray, pred_rad: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Overall RMSE in degrees over all known values, seed 003 eq. 3.12."""
    known = _mask_or_all(true_rad, mask)
    diff = (np.asarray(true_rad) - np.asarray(pred_rad))[known]
    return float(np.degrees(np.sqrt(np.mean(diff**2))))


def loss_l(true_01: np.ndarray, pred_01: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Loss L: the MSE of range-normalised angles (eq. 3.14) over known values, eq. 3.15."""
    known = _mask_or_all(true_01, mask)
    return float(np.mean(((np.asarray(true_01) - np.asarray(pred_01))[known]) ** 2))


def _orthonormal_basis(x: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the column space of centred ``x`` (rank-deficient columns dropped)."""
    centred = x - x.mean(axis=0)
    u, s, _ = np.linalg.svd(centred, full_matrices=False)
    if s.size == 0 or s[0] == 0.0:
        return u[:, :0]
    return u[:, s > _RANK_TOLERANCE * s[0]]


def cca(x: np.ndarray, y: np.ndarray) -> float:
    """First canonical correlation of two data sets, seed 003 eqs. 3.16-3.17.

    rho = max over a, b of corr(X a, Y b), computed as the largest singular value of
    Q_x^T Q_y, where Q_x and Q_y are orthonormal bases of the centred column spaces.

    Args:
        x: (d, n) data, one row per frame.
        y: (d, m) data.

    Returns:
        rho in [0, 1]; 0 when either set is constant over the frames (no direction to correlate).

    """
    qx = _orthonormal_basis(np.asarray(x, dtype=np.float64))
    qy = _orthonormal_basis(np.asarray(y, dtype=np.float64))
    if qx.shape[1] == 0 or qy.shape[1] == 0:
        return 0.0
    return float(min(1.0, np.linalg.svd(qx.T @ qy, compute_uv=False)[0]))


def lcca(x: np.ndarray, y: np.ndarray, window_frames: int) -> float:
    """Local CCA: mean CCA over sliding windows of N_tau frames, stride 1, seed 003 eq. 3.18.

    Sequences shorter than the window give the CCA of the whole sequence (one window).
    """
    d = x.shape[0]
    if d <= window_frames:
        return cca(x, y)
    return float(
        np.mean(
            [
                cca(x[i : i + window_frames], y[i : i + window_frames])
                for i in range(d - window_frames + 1)
            ]
        )
    )


def _complete_joints(mask: np.ndarray | None, n_joints: int) -> np.ndarray:
    if mask is None:
        return np.ones(n_joints, dtype=bool)
    return np.asarray(mask, dtype=bool).all(axis=0)


def window_frames_for(rate_hz: float, window_s: float = LCCA_WINDOW_S) -> int:
    """N_tau = tau f_f (300 frames at 100 Hz)."""
    return round(window_s * rate_hz)


def lcca_theta(
    true_rad: np.ndarray, pred_rad: np.ndarray, rate_hz: float, mask: np.ndarray | None = None
) -> float:
    """LCCA between true and predicted movements, seed 003 eq. 3.19 (3 s windows)."""
    joints = _complete_joints(mask, true_rad.shape[1])
    return lcca(true_rad[:, joints], pred_rad[:, joints], window_frames_for(rate_hz))


def delta_lcca(
    features: np.ndarray,
    true_rad: np.ndarray,
    pred_rad: np.ndarray,
    rate_hz: float,
    mask: np.ndarray | None = None,
) -> float:
    """|LCCA(Omega, true) - LCCA(Omega, predicted)|, seed 003 eq. 3.20."""
    joints = _complete_joints(mask, true_rad.shape[1])
    window = window_frames_for(rate_hz)
    return abs(
        lcca(features, true_rad[:, joints], window) - lcca(features, pred_rad[:, joints], window)
    )


def jerk(theta_rad: np.ndarray, rate_hz: float, mask: np.ndarray | None = None) -> float:
    """Angular jerkiness J in rad^2 s^-5, seed 003 eq. 3.21.

    J = 1 / (2 f_f (N_fr - 3)) sum_i sum_j (Delta^3 Theta_ij)^2, with the third-order forward
    difference Delta^3 Theta_ij = (Theta_{i+3,j} - 3 Theta_{i+2,j} + 3 Theta_{i+1,j} - Theta_ij)
    f_f^3, summed over the joints known in every frame.

    Raises:
        ValueError: fewer than 4 frames.

    """
    theta = np.asarray(theta_rad, dtype=np.float64)[:, _complete_joints(mask, theta_rad.shape[1])]
    n_frames = theta.shape[0]
    if n_frames < 4:
        raise ValueError(f"jerk needs at least 4 frames, got {n_frames}")
    third = (theta[3:] - 3.0 * theta[2:-1] + 3.0 * theta[1:-2] - theta[:-3]) * rate_hz**3
    return float((third**2).sum() / (2.0 * rate_hz * (n_frames - 3)))


def delta_jerk(
    true_rad: np.ndarray, pred_rad: np.ndarray, rate_hz: float, mask: np.ndarray | None = None
) -> float:
    """Delta J = |J(true) - J(predicted)|, seed 003 section 3.4.4."""
    return abs(jerk(true_rad, rate_hz, mask) - jerk(pred_rad, rate_hz, mask))


def jerk_means(
    trues_rad: Sequence[np.ndarray], preds_rad: Sequence[np.ndarray], rate_hz: float
) -> tuple[float, float]:
    """(J~, Delta J~): means of J(predicted) and of Delta J over n sequences, seed 003 eq. 3.22."""
    jerks = [jerk(p, rate_hz) for p in preds_rad]
    deltas = [delta_jerk(t, p, rate_hz) for t, p in zip(trues_rad, preds_rad, strict=True)]
    return float(np.mean(jerks)), float(np.mean(deltas))


def _derivative_magnitudes(
    theta_rad: np.ndarray, rate_hz: float, order: int, mask: np.ndarray | None
) -> np.ndarray:
    """|d^order theta / dt^order| by finite differences, over frames whose stencil is known."""
    theta = np.asarray(theta_rad, dtype=np.float64)
    known = _mask_or_all(theta, mask)
    values, valid = theta, known
    for _ in range(order):
        values = np.diff(values, axis=0) * rate_hz
        valid = valid[1:] & valid[:-1]
    return np.abs(values[valid])


def hellinger(p_counts: np.ndarray, q_counts: np.ndarray) -> float:
    """Hellinger distance sqrt(1 - sum sqrt(p_i q_i)) of two histograms (normalised here)."""
    p = np.asarray(p_counts, dtype=np.float64)
    q = np.asarray(q_counts, dtype=np.float64)
    if p.sum() == 0 or q.sum() == 0:
        return float("nan")
    coefficient = np.sqrt(p / p.sum() * q / q.sum()).sum()
    return float(np.sqrt(max(0.0, 1.0 - coefficient)))


def _hellinger_of_derivative(
    true_rad: np.ndarray,
    pred_rad: np.ndarray,
    rate_hz: float,
    order: int,
    bins: np.ndarray,
    mask: np.ndarray | None,
) -> float:
    true_hist, _ = np.histogram(_derivative_magnitudes(true_rad, rate_hz, order, mask), bins)
    pred_hist, _ = np.histogram(_derivative_magnitudes(pred_rad, rate_hz, order, mask), bins)
    return hellinger(true_hist, pred_hist)


def hellinger_speed(
    true_rad: np.ndarray, pred_rad: np.ndarray, rate_hz: float, mask: np.ndarray | None = None
) -> float:
    """Hellinger distance between histograms of joint speed (rad/s), all joints pooled."""
    return _hellinger_of_derivative(true_rad, pred_rad, rate_hz, 1, SPEED_BINS_RAD_S, mask)


def hellinger_acceleration(
    true_rad: np.ndarray, pred_rad: np.ndarray, rate_hz: float, mask: np.ndarray | None = None
) -> float:
    """Hellinger distance between histograms of joint acceleration (rad/s^2), joints pooled."""
    return _hellinger_of_derivative(true_rad, pred_rad, rate_hz, 2, ACCELERATION_BINS_RAD_S2, mask)


def diversity_deg(samples_rad: np.ndarray) -> float:
    """Mean pairwise RMS distance in degrees between S >= 2 samples (S, N_fr, J) for one audio.

    Raises:
        ValueError: fewer than two samples.

    """
    samples = np.asarray(samples_rad, dtype=np.float64)
    n = samples.shape[0]
    if n < 2:
        raise ValueError(f"diversity needs at least 2 samples, got {n}")
    distances = [
        np.sqrt(np.mean((samples[a] - samples[b]) ** 2)) for a in range(n) for b in range(a + 1, n)
    ]
    return float(np.degrees(np.mean(distances)))
