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

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.data.runs import true_runs
from audio2pose_ros.timebase import SAMPLES_PER_FRAME, WINDOW_SAMPLES

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
    return np.asarray(np.asarray(mask, dtype=bool).all(axis=0))


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
    """``|LCCA(Omega, true) - LCCA(Omega, predicted)|``, seed 003 eq. 3.20."""
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
    """``Delta J = |J(true) - J(predicted)|``, seed 003 section 3.4.4."""
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


# --- Distribution measures per joint group, with confidence intervals ------------------------

SILENCE_MIN_S = 1.0  # only pauses of at least this long count as silence (short pauses do not)
VAD_FLOOR_DB = 30.0  # frames this far below the clip's loud frames (95th percentile) are silent


def energy_vad(
    signal_16k: np.ndarray,
    n_frames: int,
    hop: int = SAMPLES_PER_FRAME,
    window: int = WINDOW_SAMPLES,
) -> np.ndarray:
    """Speech activity per motion frame from frame energy (an energy VAD).

    A frame (25 ms window every 10 ms, the feature grid) is speech when its RMS energy in dB is
    within :data:`VAD_FLOOR_DB` of the clip's 95th percentile; the decision is smoothed by a
    0.2 s median filter so that stop consonants do not split speech.

    Returns:
        (n_frames,) bool, True where someone speaks.

    """
    from scipy.ndimage import median_filter

    audio = np.asarray(signal_16k, dtype=np.float64)
    starts = np.arange(n_frames) * hop
    padded = np.pad(audio, (0, max(0, starts[-1] + window - audio.size if n_frames else 0)))
    frames = np.stack([padded[s : s + window] for s in starts]) if n_frames else np.zeros((0, 1))
    level_db = 10.0 * np.log10(np.mean(frames**2, axis=1) + 1e-10)
    if level_db.size == 0:
        return np.zeros(0, dtype=bool)
    speech = level_db >= np.percentile(level_db, 95) - VAD_FLOOR_DB
    return median_filter(speech.astype(np.uint8), size=21, mode="nearest").astype(bool)


def long_silences(speech: np.ndarray, rate_hz: float, min_s: float = SILENCE_MIN_S) -> np.ndarray:
    """Frames inside runs of non-speech lasting at least ``min_s`` seconds."""
    silent = ~np.asarray(speech, dtype=bool)
    out = np.zeros_like(silent)
    for start, stop in true_runs(silent):
        if stop - start >= min_s * rate_hz:
            out[start:stop] = True
    return out


@dataclass
class MotionSegments:
    """Per-segment sufficient statistics of one motion source, for paired bootstrapping.

    Every held-out clip is cut into segments of :data:`SEGMENT_S`; a bootstrap resample draws
    segments with replacement and sums their statistics, so the measures of a resample cost a
    sum, not a recomputation.

    Attributes:
        speed_counts: (S, J, bins) histogram counts of joint speed per segment.
        accel_counts: (S, J, bins) histogram counts of joint acceleration per segment.
        moments: (S, J, 3) count, sum and sum of squares of the clip-centred angle.
        speech_speed: (S, 2) sum of the joints' mean speed over speech frames, and their count.
        silence_speed: (S, 2) the same over frames of silences of at least 1 s.

    """

    speed_counts: np.ndarray
    accel_counts: np.ndarray
    moments: np.ndarray
    speech_speed: np.ndarray
    silence_speed: np.ndarray


SEGMENT_S = 1.0


def segment_statistics(
    theta_rad: np.ndarray,
    mask: np.ndarray,
    speech: np.ndarray,
    rate_hz: float,
    segment_s: float = SEGMENT_S,
) -> MotionSegments:
    """Cut one clip's motion (N, J) into segments and histogram speed and acceleration.

    Args:
        theta_rad: (N, J) angles of the joints of one group.
        mask: (N, J) True where the angle is known.
        speech: (N,) speech activity (:func:`energy_vad`).
        rate_hz: frame rate.
        segment_s: segment length.

    """
    theta = np.asarray(theta_rad, dtype=np.float64)
    known = np.asarray(mask, dtype=bool)
    n, joints = theta.shape
    speed = np.zeros_like(theta)
    speed[1:] = np.abs(np.diff(theta, axis=0)) * rate_hz
    speed_ok = np.zeros_like(known)
    speed_ok[1:] = known[1:] & known[:-1]
    accel = np.zeros_like(theta)
    accel[2:] = np.abs(np.diff(theta, 2, axis=0)) * rate_hz**2
    accel_ok = np.zeros_like(known)
    accel_ok[2:] = known[2:] & known[1:-1] & known[:-2]
    centre = np.array(
        [np.mean(theta[known[:, j], j]) if known[:, j].any() else 0.0 for j in range(joints)]
    )
    centred = theta - centre
    silence = long_silences(speech, rate_hz)
    mean_speed = np.where(speed_ok, speed, 0.0).sum(axis=1) / np.maximum(speed_ok.sum(axis=1), 1)
    any_speed = np.asarray(speed_ok.any(axis=1))
    length = max(1, round(segment_s * rate_hz))
    bounds = [(s, min(n, s + length)) for s in range(0, n, length) if min(n, s + length) - s > 2]
    out = MotionSegments(
        np.zeros((len(bounds), joints, SPEED_BINS_RAD_S.size - 1)),
        np.zeros((len(bounds), joints, ACCELERATION_BINS_RAD_S2.size - 1)),
        np.zeros((len(bounds), joints, 3)),
        np.zeros((len(bounds), 2)),
        np.zeros((len(bounds), 2)),
    )
    for k, (a, b) in enumerate(bounds):
        for j in range(joints):
            out.speed_counts[k, j] = np.histogram(
                speed[a:b, j][speed_ok[a:b, j]], SPEED_BINS_RAD_S
            )[0]
            out.accel_counts[k, j] = np.histogram(
                accel[a:b, j][accel_ok[a:b, j]], ACCELERATION_BINS_RAD_S2
            )[0]
            values = centred[a:b, j][known[a:b, j]]
            out.moments[k, j] = (values.size, values.sum(), (values**2).sum())
        for target, frames in ((out.speech_speed, speech), (out.silence_speed, silence)):
            chosen = frames[a:b] & any_speed[a:b]
            target[k] = (mean_speed[a:b][chosen].sum(), chosen.sum())
    return out


def concat_segments(parts: Sequence[MotionSegments]) -> MotionSegments:
    """Stack the segments of several clips."""
    return MotionSegments(
        *(
            np.concatenate([getattr(p, f) for p in parts])
            for f in MotionSegments.__dataclass_fields__
        )
    )


def sum_segments(parts: Sequence[MotionSegments]) -> MotionSegments:
    """Add the statistics of several motions of the same segments (e.g. samples with other seeds).

    Every statistic is a sum (histogram counts, moments, speed sums), so the result describes
    the motions pooled, segment by segment: a paired bootstrap over segments stays paired.
    """
    return MotionSegments(
        *(sum(getattr(p, f) for p in parts) for f in MotionSegments.__dataclass_fields__)
    )


def _joint_hellinger(true_counts: np.ndarray, pred_counts: np.ndarray) -> float:
    """Hellinger distance per joint between (J, bins) histograms, averaged over joints."""
    values = [hellinger(t, p) for t, p in zip(true_counts, pred_counts, strict=True)]
    values = [v for v in values if not np.isnan(v)]
    return float(np.mean(values)) if values else float("nan")


def _std(moments: np.ndarray) -> np.ndarray:
    count, total, squares = moments[..., 0], moments[..., 1], moments[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(np.maximum(squares / count - (total / count) ** 2, 0.0))


def distribution_measures(real: MotionSegments, generated: MotionSegments) -> dict[str, float]:
    """H speed, H accel (per joint, averaged), std ratio, and speech / silence speed ratio.

    ``real`` and ``generated`` hold the same segments (same clips, same order).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        std_ratio = _std(generated.moments.sum(axis=0)) / _std(real.moments.sum(axis=0))
        speech = generated.speech_speed.sum(axis=0)
        silence = generated.silence_speed.sum(axis=0)
        ratio = (speech[0] / speech[1]) / (silence[0] / silence[1]) if silence[1] else np.nan
    finite = std_ratio[np.isfinite(std_ratio)]
    return {
        "H speed": _joint_hellinger(
            real.speed_counts.sum(axis=0), generated.speed_counts.sum(axis=0)
        ),
        "H accel": _joint_hellinger(
            real.accel_counts.sum(axis=0), generated.accel_counts.sum(axis=0)
        ),
        "std ratio": float(np.mean(finite)) if finite.size else float("nan"),
        "speech/silence speed": float(ratio),
    }


def bias_corrected(
    point: float, draws: Sequence[float], non_negative: bool = True
) -> tuple[float, float, float]:
    """A bootstrap-bias-corrected estimate and its 95 % interval (Efron and Tibshirani 1993).

    A distance between histograms is biased upwards by sampling noise, and a resample, which
    duplicates segments, has fewer distinct ones: its distances are larger still, so the
    percentile interval of such a measure can lie wholly above the value on all the data. The
    bias is estimated as b = mean(draws) - point (section 10.2); the estimate is point - b
    (eq. 10.17) and the interval the 2.5th and 97.5th percentiles of the draws shifted by
    -2 b, the percentile interval of the bias-corrected estimator. It contains its estimate
    unless the draws' mean lies outside their own central 95 %. Non-negative measures
    (distances, ratios) are clamped at 0.

    Returns:
        (estimate, low, high); the point and NaN bounds when no draw is finite.

    """
    finite = np.asarray([v for v in draws if np.isfinite(v)])
    if not np.isfinite(point) or finite.size == 0:
        return point, math.nan, math.nan
    bias = float(finite.mean()) - point
    low, high = np.percentile(finite, [2.5, 97.5]) - 2.0 * bias
    values = (point - bias, float(low), float(high))
    if non_negative:
        values = tuple(max(0.0, v) for v in values)  # type: ignore[assignment]
    return values


def bootstrap_measures(
    real: MotionSegments, generated: MotionSegments, n_resamples: int = 200, seed: int = 0
) -> dict[str, tuple[float, float, float]]:
    """:func:`distribution_measures`, bias-corrected, with 95 % bootstrap intervals.

    Segments are resampled with replacement, the same indices for real and generated motion
    (a paired bootstrap); estimate and interval are :func:`bias_corrected`.

    Returns:
        measure -> (bias-corrected estimate, 2.5 % bound, 97.5 % bound).

    """
    point = distribution_measures(real, generated)
    rng = np.random.default_rng(seed)
    n = int(real.speed_counts.shape[0])
    draws: dict[str, list[float]] = {k: [] for k in point}
    for _ in range(n_resamples if n > 1 else 0):
        pick = rng.integers(0, n, n)
        values = distribution_measures(_take(real, pick), _take(generated, pick))
        for key, value in values.items():
            draws[key].append(value)
    return {key: bias_corrected(value, draws[key]) for key, value in point.items()}


def split_half_floor(
    real: MotionSegments, n_resamples: int = 200, seed: int = 0
) -> dict[str, tuple[float, float, float]]:
    """H speed and H accel between two halves of the real segments: what real differs from real.

    Segments are dealt alternately into two halves (neighbouring seconds of the same clips go
    to different halves, so the halves share speakers and style); each half is resampled on its
    own and the distances are :func:`bias_corrected` like the generated motion's
    (:func:`bootstrap_measures`), so the two can be compared.
    """
    n = int(real.speed_counts.shape[0])
    first, second = np.arange(0, n, 2), np.arange(1, n, 2)
    if second.size == 0:
        nan = (math.nan, math.nan, math.nan)
        return {"H speed": nan, "H accel": nan}

    def distances(a: np.ndarray, b: np.ndarray) -> dict[str, float]:
        measures = distribution_measures(_take(real, a), _take(real, b))
        return {k: measures[k] for k in ("H speed", "H accel")}

    point = distances(first, second)
    rng = np.random.default_rng(seed)
    draws: dict[str, list[float]] = {k: [] for k in point}
    for _ in range(n_resamples):
        a = first[rng.integers(0, first.size, first.size)]
        b = second[rng.integers(0, second.size, second.size)]
        for key, value in distances(a, b).items():
            draws[key].append(value)
    return {key: bias_corrected(value, draws[key]) for key, value in point.items()}


def _take(segments: MotionSegments, pick: np.ndarray) -> MotionSegments:
    return MotionSegments(
        *(getattr(segments, f)[pick] for f in MotionSegments.__dataclass_fields__)
    )
