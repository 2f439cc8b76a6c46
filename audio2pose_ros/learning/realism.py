"""Measures of motion realism beyond speed histograms: windows, diversity, jerk, beats, tails.

Generated motion is compared with real motion of the same held-out clips:

- **Fréchet distance on motion windows** (:func:`frechet_windows`): the field's FID / FGD
  compares Gaussian fits of motion features; here the features are the joint angles of 1 s
  windows, taken every 0.1 s (:data:`WINDOW_S`, :data:`WINDOW_STRIDE_S`), every 0.25 s inside
  a window, projected on the principal components of the real windows that hold 95 % of their
  variance (at most :data:`MAX_COMPONENTS`). It is computed half against half (the clips dealt
  alternately into two halves, generated half A against real half B and the reverse, averaged),
  so that the real-vs-real floor (real half A against real half B, :func:`split_half`) uses the
  same amount of data and is comparable.
- **L1 diversity** (EMAGE, Liu et al. 2024, and TalkSHOW: the mean over frames of the summed
  absolute deviation of every joint from the clip's mean pose) and the seed's **jerk** J (seed
  003 eq. 3.21, per frame), both as ratios generated / real (:func:`motion_ratios`).
- **Beat consistency** (EMAGE's BC, :func:`beat_consistency`): audio onsets (the onset strength
  of librosa's ``onset_detect``, McFee et al. 2015: the mean over mel bands of the rectified
  frame-to-frame rise of the log power in dB, its peaks picked with librosa's default windows,
  and each onset moved back to the preceding minimum of the frame energy) against motion beats
  (local minima of the group's angular speed over +-:data:`BEAT_ORDER_S`, EMAGE's ``order`` 7
  at 30 fps); BC is the mean over onsets of exp(-d^2 / (2 sigma^2)), d the distance to the
  nearest motion beat, sigma = 0.3 s. It is reported for the model, the real motion on the
  same clips and the model's motion paired with another clip's audio (shuffled audio).
- **Percentiles** of joint speed and acceleration (p50, p90, p99 per joint,
  :func:`speed_percentiles`): where a Hellinger distance says that two distributions differ,
  the tails say how.

All of it runs on the 100 Hz frame grid (:mod:`audio2pose_ros.timebase`) with masks: only frames
where the real angle is known count, for real and generated motion alike.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLES_PER_FRAME, WINDOW_SAMPLES

if TYPE_CHECKING:
    from audio2pose_ros.data.dataset import Clip

WINDOW_S = 1.0
WINDOW_STRIDE_S = 0.1
WINDOW_SAMPLE_S = 0.25  # angles kept every 0.25 s inside a window (5 per joint and window)
MAX_COMPONENTS = 8
VARIANCE_KEPT = 0.95
BEAT_SIGMA_S = 0.3  # EMAGE's sigma
BEAT_ORDER_S = 7 / 30  # EMAGE's argrelextrema order of 7 frames at 30 fps
PERCENTILES = (50, 90, 99)
PERCENTILE_TOLERANCE = 0.25  # |model / real - 1|: a percentile "within 25 % of real"
# librosa.onset.onset_detect's peak picking (seconds): pre_max 0.03, post_max 0 (+1 frame),
# pre_avg 0.1, post_avg 0.1 (+1 frame), wait 0.03, delta 0.07 on the envelope scaled to [0, 1]
_PEAK_PRE_MAX_S, _PEAK_PRE_AVG_S, _PEAK_POST_AVG_S, _PEAK_WAIT_S = 0.03, 0.1, 0.1, 0.03
_PEAK_DELTA = 0.07
_TOP_DB = 80.0  # librosa's power_to_db clips this far below the clip's loudest band


Motion = tuple[np.ndarray, np.ndarray]  # (N, J) angles of one clip and its (N, J) known mask


def clip_motions(clips: Sequence[Clip], joints: np.ndarray) -> list[Motion]:
    """The real motion of the ``joints`` (a boolean mask) in every clip that observes them."""
    return [
        (np.nan_to_num(c.angles_rad[:, joints]), c.mask[:, joints])
        for c in clips
        if c.mask[:, joints].any()
    ]


def _windows(motion: Motion, rate_hz: float) -> np.ndarray:
    """(W, J * k) angle windows of one clip, only windows whose every angle is known."""
    angles, known = motion
    length = round(WINDOW_S * rate_hz)
    stride = max(1, round(WINDOW_STRIDE_S * rate_hz))
    step = max(1, round(WINDOW_SAMPLE_S * rate_hz))
    picks = np.arange(0, length, step)
    rows = [
        angles[start + picks].T.ravel()
        for start in range(0, angles.shape[0] - length + 1, stride)
        if known[start + picks].all()
    ]
    return np.asarray(rows, dtype=np.float64).reshape(len(rows), angles.shape[1] * picks.size)


def frechet_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Fréchet distance between Gaussian fits of two sets of rows (the FID formula).

    ``||mu_a - mu_b||^2 + tr(S_a + S_b - 2 (S_a S_b)^(1/2))``; NaN with fewer than two rows.
    """
    if a.shape[0] < 2 or b.shape[0] < 2:
        return math.nan
    mean = a.mean(axis=0) - b.mean(axis=0)
    cov_a = np.atleast_2d(np.cov(a, rowvar=False))
    cov_b = np.atleast_2d(np.cov(b, rowvar=False))
    # tr (S_a S_b)^(1/2) is the sum of the square roots of the product's eigenvalues, which
    # are real and non-negative for covariances (also singular ones, e.g. of a still pose)
    eigenvalues = np.linalg.eigvals(cov_a @ cov_b)
    root_trace = np.sqrt(np.maximum(eigenvalues.real, 0.0)).sum()
    return float(mean @ mean + np.trace(cov_a) + np.trace(cov_b) - 2.0 * root_trace)


def split_half(n: int) -> tuple[list[int], list[int]]:
    """Clip indices dealt alternately into two halves (one clip: no split)."""
    return list(range(0, n, 2)), list(range(1, n, 2))


def _halves(motions: Sequence[Motion]) -> tuple[list[Motion], list[Motion]]:
    """Two halves of the clips; a single clip is cut in the middle."""
    if len(motions) >= 2:
        first, second = split_half(len(motions))
        return [motions[i] for i in first], [motions[i] for i in second]
    angles, known = motions[0]
    middle = angles.shape[0] // 2
    return [(angles[:middle], known[:middle])], [(angles[middle:], known[middle:])]


@dataclass(frozen=True)
class WindowDistance:
    """Fréchet distances of motion windows, half against half.

    Attributes:
        generated: mean of FD(generated half A, real half B) and FD(generated B, real A).
        floor: FD(real half A, real half B): what two stretches of real motion differ by.
        components: principal components kept.

    """

    generated: float
    floor: float
    components: int


def frechet_windows(
    real: Sequence[Motion], generated: Sequence[np.ndarray], rate_hz: float = FRAME_RATE_HZ
) -> WindowDistance:
    """Fréchet distance on motion windows with its real-vs-real floor (module docstring).

    Args:
        real: per clip, the real angles of one joint group and their known mask.
        generated: per clip, generated angles of the same group (the real mask applies).
        rate_hz: frame rate.

    """
    if not real:
        return WindowDistance(math.nan, math.nan, 0)
    gen = [(g, known) for g, (_, known) in zip(generated, real, strict=True)]
    real_a, real_b = _halves(real)
    gen_a, gen_b = _halves(gen)
    sets = [np.concatenate([_windows(m, rate_hz) for m in part]) for part in (real_a, real_b)] + [
        np.concatenate([_windows(m, rate_hz) for m in part]) for part in (gen_a, gen_b)
    ]
    pooled = np.concatenate(sets[:2])
    if pooled.shape[0] < 4:
        return WindowDistance(math.nan, math.nan, 0)
    centre = pooled.mean(axis=0)
    _, singular, axes = np.linalg.svd(pooled - centre, full_matrices=False)
    variance = singular**2
    if variance.sum() <= 0:
        return WindowDistance(math.nan, math.nan, 0)
    kept = int(np.searchsorted(np.cumsum(variance) / variance.sum(), VARIANCE_KEPT) + 1)
    kept = max(1, min(kept, MAX_COMPONENTS, axes.shape[0]))
    real_a_p, real_b_p, gen_a_p, gen_b_p = ((s - centre) @ axes[:kept].T for s in sets)
    generated_fd = 0.5 * (frechet_distance(gen_a_p, real_b_p) + frechet_distance(gen_b_p, real_a_p))
    return WindowDistance(generated_fd, frechet_distance(real_a_p, real_b_p), kept)


def l1_diversity(angles: np.ndarray, known: np.ndarray) -> tuple[float, int]:
    """EMAGE's L1 diversity of one clip as (sum over known frames, number of frames).

    Per frame: the sum over joints of ``|angle - the clip's mean angle|`` (over known frames).
    """
    frames = known.all(axis=1)
    if frames.sum() < 2:
        return 0.0, 0
    chosen = angles[frames]
    return float(np.abs(chosen - chosen.mean(axis=0)).sum()), int(frames.sum())


def jerk_sum(angles: np.ndarray, known: np.ndarray, rate_hz: float) -> tuple[float, int]:
    """The seed's jerk (eq. 3.21) of one clip as (sum of squared third differences, frames).

    Summed over joints and over the frames whose four-frame stencil is known.
    """
    if angles.shape[0] < 4:
        return 0.0, 0
    third = (angles[3:] - 3.0 * angles[2:-1] + 3.0 * angles[1:-2] - angles[:-3]) * rate_hz**3
    valid = known[3:] & known[2:-1] & known[1:-2] & known[:-3]
    frames = valid.all(axis=1)
    return float((third[frames] ** 2).sum() / (2.0 * rate_hz)), int(frames.sum())


def motion_ratios(
    real: Sequence[Motion], generated: Sequence[Motion], rate_hz: float = FRAME_RATE_HZ
) -> dict[str, float]:
    """L1 diversity and jerk of generated motion relative to real (pooled over the clips).

    Both over the frames known in both (a baseline made of other clips' motion has its own
    unknown frames).
    """
    totals = np.zeros((2, 2, 2))  # measure, real / generated, (sum, frames)
    for (angles, known), (gen, gen_known) in zip(real, generated, strict=True):
        both = known & gen_known
        for k, motion in enumerate((angles, gen)):
            totals[0, k] += l1_diversity(motion, both)
            totals[1, k] += jerk_sum(motion, both, rate_hz)
    out = {}
    for m, name in enumerate(("L1div ratio", "jerk ratio")):
        real_mean = totals[m, 0, 0] / max(totals[m, 0, 1], 1.0)
        gen_mean = totals[m, 1, 0] / max(totals[m, 1, 1], 1.0)
        out[name] = gen_mean / real_mean if real_mean > 0 else math.nan
    return out


def speed_percentiles(
    motions: Sequence[Motion], rate_hz: float = FRAME_RATE_HZ
) -> tuple[np.ndarray, np.ndarray]:
    """(J, 3) speed and (J, 3) acceleration percentiles :data:`PERCENTILES` per joint.

    Over all clips' frames whose stencil is known (rad/s and rad/s^2).
    """
    n_joints = motions[0][0].shape[1]
    out = np.full((2, n_joints, len(PERCENTILES)), np.nan)
    for order in (1, 2):
        for j in range(n_joints):
            values = []
            for angles, known in motions:
                diff = np.abs(np.diff(angles[:, j], order)) * rate_hz**order
                valid = known[order:, j].copy()
                for k in range(1, order + 1):
                    valid &= known[order - k : angles.shape[0] - k, j]
                values.append(diff[valid])
            pooled = np.concatenate(values)
            if pooled.size:
                out[order - 1, j] = np.percentile(pooled, PERCENTILES)
    return out[0], out[1]


@dataclass(frozen=True)
class PercentileAgreement:
    """How a motion's speed and acceleration percentiles compare with real ones.

    Attributes:
        inside: how many lie within :data:`PERCENTILE_TOLERANCE` of real (``|model / real - 1|``).
        total: how many were compared, those of a still real joint included (never inside).
        lowest: the smallest model / real (NaN when no real percentile is above 0).
        highest: the largest.

    """

    inside: int
    total: int
    lowest: float
    highest: float


def percentile_agreement(
    model: tuple[np.ndarray, np.ndarray], real: tuple[np.ndarray, np.ndarray]
) -> PercentileAgreement:
    """Compare (speed, acceleration) percentiles of :func:`speed_percentiles` with real ones.

    A real percentile of 0 (a still joint) has no scale: its ratio is undefined and never
    inside.
    """
    model_flat = np.concatenate([np.ravel(p) for p in model])
    real_flat = np.concatenate([np.ravel(p) for p in real])
    ratios = model_flat / np.where(real_flat > 0, real_flat, np.nan)
    inside = np.abs(ratios - 1.0) <= PERCENTILE_TOLERANCE
    known = ratios[np.isfinite(ratios)]
    lowest, highest = (float(known.min()), float(known.max())) if known.size else (math.nan,) * 2
    return PercentileAgreement(int(inside.sum()), int(inside.size), lowest, highest)


# --- beat consistency --------------------------------------------------------------------------


def _peak_pick(envelope: np.ndarray, rate_hz: float) -> np.ndarray:
    """Indices of onset peaks (librosa.util.peak_pick with onset_detect's defaults)."""
    pre_max = round(_PEAK_PRE_MAX_S * rate_hz)
    pre_avg = round(_PEAK_PRE_AVG_S * rate_hz)
    post_avg = round(_PEAK_POST_AVG_S * rate_hz) + 1
    wait = round(_PEAK_WAIT_S * rate_hz)
    peaks: list[int] = []
    last = -math.inf
    for n in range(envelope.size):
        window = envelope[max(0, n - pre_max) : n + 1]
        if envelope[n] < window.max():
            continue
        average = envelope[max(0, n - pre_avg) : n + post_avg].mean()
        if envelope[n] >= average + _PEAK_DELTA and n - last > wait:
            peaks.append(n)
            last = n
    return np.asarray(peaks, dtype=int)


def _frame_rms(audio: np.ndarray, n_frames: int) -> np.ndarray:
    """RMS of each 25 ms window of the frame grid."""
    padded = np.pad(np.asarray(audio, np.float64), (0, WINDOW_SAMPLES))
    starts = np.arange(n_frames) * SAMPLES_PER_FRAME
    frames = np.stack([padded[s : s + WINDOW_SAMPLES] for s in starts])
    return np.sqrt(np.mean(frames**2, axis=1))


def _backtrack(onsets: np.ndarray, energy: np.ndarray) -> np.ndarray:
    """Move each onset back to the latest local minimum of ``energy`` at or before it."""
    minima = np.flatnonzero(
        np.concatenate(
            [[True], (energy[1:-1] <= energy[:-2]) & (energy[1:-1] < energy[2:]), [False]]
        )
    )
    if onsets.size == 0:
        return onsets
    return minima[np.maximum(np.searchsorted(minima, onsets, side="right") - 1, 0)]


def audio_onsets(audio: np.ndarray, rate_hz: float = FRAME_RATE_HZ) -> np.ndarray:
    """Onset times (s) of a 16 kHz utterance (librosa's recipe on the 26 mel bands, see above)."""
    logs = extract_features(audio, FeatureSpec())  # natural log of mel band energies
    if logs.shape[0] < 3:
        return np.zeros(0)
    decibels = logs * (10.0 / math.log(10.0))
    decibels = np.maximum(decibels, decibels.max() - _TOP_DB)
    rise = np.maximum(0.0, np.diff(decibels, axis=0)).mean(axis=1)
    envelope = np.concatenate([[0.0], rise])
    span = envelope.max() - envelope.min()
    if span <= 0:
        return np.zeros(0)
    envelope = (envelope - envelope.min()) / span
    peaks = _peak_pick(envelope, rate_hz)
    onsets = _backtrack(peaks, _frame_rms(audio, envelope.size))
    return onsets / rate_hz


def motion_beats(angles: np.ndarray, rate_hz: float = FRAME_RATE_HZ) -> np.ndarray:
    """Beat times (s): strict local minima of the angular speed over +-:data:`BEAT_ORDER_S`."""
    from scipy.signal import argrelextrema

    if angles.shape[0] < 3:
        return np.zeros(0)
    speed = np.linalg.norm(np.diff(angles, axis=0), axis=1) * rate_hz
    order = max(1, round(BEAT_ORDER_S * rate_hz))
    (minima,) = argrelextrema(speed, np.less, order=order)
    return (minima + 1) / rate_hz  # speed[i] lies between frames i and i + 1


def beat_consistency(onsets_s: np.ndarray, beats_s: np.ndarray) -> tuple[float, int]:
    """EMAGE's BC of one clip as (sum over onsets, number of onsets); no beat counts as 0."""
    if onsets_s.size == 0:
        return 0.0, 0
    if beats_s.size == 0:
        return 0.0, int(onsets_s.size)
    nearest = np.abs(onsets_s[:, None] - beats_s[None, :]).min(axis=1)
    return float(np.exp(-(nearest**2) / (2.0 * BEAT_SIGMA_S**2)).sum()), int(onsets_s.size)


def pooled_beat_consistency(
    onsets: Sequence[np.ndarray], motions: Sequence[Motion], pairing: Sequence[int]
) -> float:
    """BC pooled over clips: clip i's onsets against the beats of ``motions[pairing[i]]``.

    Only beats inside known motion count, and only onsets within both clip i's motion and the
    paired motion: an onset past the paired motion's end has no beat near it for want of
    motion, not of timing. A pairing other than the identity gives the "shuffled audio" BC:
    how much of BC any motion gets from onsets being frequent. NaN when no clip has an onset.
    """
    total = np.zeros(2)
    for i, clip_onsets in enumerate(onsets):
        angles, known = motions[pairing[i]]
        beats = motion_beats(angles)
        frames = np.minimum(np.round(beats * FRAME_RATE_HZ).astype(int), known.shape[0] - 1)
        beats = beats[known[frames].all(axis=1)]  # only beats inside observed motion
        duration = min(motions[i][0].shape[0], angles.shape[0]) / FRAME_RATE_HZ
        total += beat_consistency(clip_onsets[clip_onsets < duration], beats)
    return float(total[0] / total[1]) if total[1] else math.nan
