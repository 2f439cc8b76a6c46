"""Lags between two stamped signals, by cross-correlation; chunk-to-pose pairing by event order.

Two measurements the voice's synchronisation is built from (:mod:`audio2pose_ros.voice.sync`)
and the offset at the robot is judged with (:mod:`audio2pose_ros.voice.offset`):

- :func:`motion_lag`: how long after one joint trajectory another follows it (commanded against
  measured joint states, raw poses against commands): the lag that best lines up their joint
  velocities, on a common grid, within ``[0, max_lag_s]``;
- :func:`sound_lag`: how long after one sound another one hears it (the voice sent against what
  the robot's microphones recorded): the lag that best lines up their loudness envelopes;
- :class:`ChunkPairing`: how long after an audio chunk arrives the pose computed from it
  arrives, pairing each pose message with the newest chunk before it that has none yet (the
  graph answers every chunk of 10 ms or more with one ``raw_trajectory`` message).

Each lag comes with its score, the normalised correlation at that lag (1: the signals are the
same up to scale): a lag whose score is under the caller's threshold is no measurement (too
little motion or sound in the window, or unrelated signals). Times are seconds on one clock.
This module does not import rclpy.
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np

__all__ = [
    "ENVELOPE_RATE_HZ",
    "ChunkPairing",
    "Lag",
    "envelope",
    "loudness",
    "motion_lag",
    "sound_lag",
]

MOTION_GRID_S = 0.005  # joint trajectories are compared on this grid (s)
ENVELOPE_S = 0.005  # loudness envelope bin (s)
ENVELOPE_RATE_HZ = 200  # = 1 / ENVELOPE_S: the rate of a piece made by loudness()
# Both signals are smoothed over this many grid steps before they are lined up (30 ms of
# loudness, 50 ms of joint velocity): the model's frame-to-frame jitter and a voice's pitch
# periods are not what the lag is about; the same smoothing on both shifts neither.
SMOOTH_BINS = 6
MIN_MOTION_RAD = 1e-3  # total joint travel in a window below this: too little motion to tell
MIN_SOUND_RMS = 1e-4  # envelope deviation below this: silence, nothing to line up


class Lag(NamedTuple):
    """A measured lag (s) and its score (normalised correlation, -1..1)."""

    lag_s: float
    score: float


NO_LAG = Lag(math.nan, 0.0)


def _smooth(x: np.ndarray, bins: int = SMOOTH_BINS) -> np.ndarray:
    """A moving average over ``bins`` rows (the same on both signals: no lag between them)."""
    if len(x) < bins:
        return x
    kernel = np.ones(bins) / bins
    return np.stack([np.convolve(col, kernel, mode="same") for col in np.asarray(x).T], axis=1)


def _best_lag(a: np.ndarray, b: np.ndarray, max_lag: int, step_s: float) -> Lag:
    """Lag (in ``step_s``) of the columns of ``b`` behind ``a``, refined to a parabola's peak.

    ``a`` is the leading signal over a window of ``n`` rows; ``b`` is the following one over the
    same start and ``max_lag`` rows more, so at every lag ``k`` in ``[0, max_lag]`` the whole of
    ``a`` is compared with ``b[k : k + n]``: the same ``n`` rows, never a shrinking overlap (a
    few rows at a long lag correlate by chance). The score at ``k`` is the correlation
    coefficient of the two (each column centred on its mean over the rows compared, summed over
    the columns), from one FFT product per column and running sums.
    """
    n = len(a)
    max_lag = min(max_lag, len(b) - n)
    if n < 4 or max_lag < 0:
        return NO_LAG
    a = a - a.mean(axis=0)
    size = 1 << (n + len(b) - 1).bit_length()
    products = np.fft.rfft(b, size, axis=0) * np.conj(np.fft.rfft(a, size, axis=0))
    dots = np.fft.irfft(products.sum(axis=1), size)[: max_lag + 1]  # a is centred: b's mean adds 0
    sums = np.concatenate([np.zeros((1, b.shape[1])), np.cumsum(b, axis=0)])
    squares = np.concatenate([np.zeros((1, b.shape[1])), np.cumsum(b * b, axis=0)])
    k = np.arange(max_lag + 1)
    window_sum = sums[k + n] - sums[k]
    energy_b = np.maximum((squares[k + n] - squares[k]) - window_sum**2 / n, 0.0).sum(axis=1)
    norms = np.sqrt(float(np.sum(a * a)) * energy_b)
    floor = 1e-12 * max(float(norms.max()), 1e-300)
    scores = np.where(norms > floor, dots / np.where(norms > floor, norms, 1.0), -np.inf)
    best = int(np.argmax(scores))
    if not math.isfinite(scores[best]):
        return NO_LAG
    shift = 0.0
    if 0 < best < max_lag:
        left, mid, right = scores[best - 1], scores[best], scores[best + 1]
        curve = left - 2.0 * mid + right
        if curve < 0.0 and math.isfinite(left + right):
            shift = 0.5 * (left - right) / curve
    return Lag((best + shift) * step_s, float(scores[best]))


def motion_lag(
    times_a: np.ndarray,
    poses_a: np.ndarray,
    times_b: np.ndarray,
    poses_b: np.ndarray,
    max_lag_s: float,
) -> Lag:
    """How long after trajectory ``a`` trajectory ``b`` follows it (joint velocities lined up).

    Args:
        times_a: increasing stamps (s) of ``poses_a``.
        poses_a: (n, n_joints) positions (rad) of the leading trajectory.
        times_b: increasing stamps (s) of ``poses_b``.
        poses_b: (m, n_joints) positions (rad) of the following one, same joints, same order.
        max_lag_s: longest lag considered (s).

    Returns:
        The lag in ``[0, max_lag_s]``, or a NaN lag with score 0 when the trajectories overlap
        too little or hardly move. ``a`` is compared where ``b`` also covers the ``max_lag_s``
        after it (:func:`_best_lag`).
    """
    times_a, times_b = np.asarray(times_a, float), np.asarray(times_b, float)
    if len(times_a) < 3 or len(times_b) < 3:
        return NO_LAG
    max_lag = round(max_lag_s / MOTION_GRID_S)
    start = max(times_a[0], times_b[0])
    end = min(times_a[-1], times_b[-1] - max_lag * MOTION_GRID_S)
    n = int(np.floor((end - start) / MOTION_GRID_S)) + 1
    if n < 5:
        return NO_LAG
    grid = start + np.arange(n + max_lag) * MOTION_GRID_S
    a = np.stack([np.interp(grid, times_a, col) for col in np.asarray(poses_a, float).T], axis=1)
    b = np.stack([np.interp(grid, times_b, col) for col in np.asarray(poses_b, float).T], axis=1)
    # both smoothed over the whole grid (the same edges), then a cut to its window
    va, vb = _smooth(np.diff(a, axis=0))[: n - 1], _smooth(np.diff(b, axis=0))
    if np.abs(va).sum() < MIN_MOTION_RAD or np.abs(vb).sum() < MIN_MOTION_RAD:
        return NO_LAG
    return _best_lag(va, vb, max_lag, MOTION_GRID_S)


def envelope(
    pieces: list[tuple[float, np.ndarray]], rate_hz: int, start_s: float, end_s: float
) -> np.ndarray:
    """RMS loudness in bins of ``ENVELOPE_S`` over ``[start_s, end_s)``.

    Args:
        pieces: ``(time of the first sample (s), mono samples)``.
        rate_hz: sample rate of the pieces (Hz).
        start_s: start of the first bin (s).
        end_s: end of the envelope (s).
    """
    n_bins = max(0, int((end_s - start_s) / ENVELOPE_S))
    if not pieces or not n_bins:
        return np.zeros(n_bins)
    index = np.concatenate(
        [np.floor((t + np.arange(len(x)) / rate_hz - start_s) / ENVELOPE_S) for t, x in pieces]
    )
    values = np.concatenate([np.asarray(x, float) for _, x in pieces])
    inside = (index >= 0) & (index < n_bins)
    bins = index[inside].astype(np.int64)
    energy = np.bincount(bins, values[inside] ** 2, minlength=n_bins)
    counts = np.bincount(bins, minlength=n_bins)
    return np.sqrt(energy / np.maximum(counts, 1))


def loudness(first_s: float, mono: np.ndarray, rate_hz: int) -> tuple[float, np.ndarray]:
    """A piece of sound as its RMS per ``ENVELOPE_S`` (a piece at 1 / ENVELOPE_S Hz).

    What :func:`sound_lag` needs of a long recording, kept at a few hundred values a second
    instead of tens of thousands of samples.
    """
    per_bin = max(1, round(rate_hz * ENVELOPE_S))
    n = len(mono) // per_bin * per_bin
    square = np.square(np.asarray(mono[:n], dtype=np.float64)).reshape(-1, per_bin)
    return first_s, np.sqrt(square.mean(axis=1))


def sound_lag(
    sent: list[tuple[float, np.ndarray]],
    sent_rate_hz: int,
    heard: list[tuple[float, np.ndarray]],
    heard_rate_hz: int,
    max_lag_s: float,
) -> Lag:
    """How long after the ``sent`` sound the ``heard`` one carries it (envelopes lined up).

    Args:
        sent: ``(time of the first sample (s), mono samples)`` pieces of the sound sent.
        sent_rate_hz: their sample rate (Hz).
        heard: the same for the sound heard.
        heard_rate_hz: its sample rate (Hz).
        max_lag_s: longest lag considered (s).

    The sound sent is compared where the sound heard covers it and the ``max_lag_s`` after it
    (:func:`_best_lag`): at every lag, the same stretch of the voice against as much of the
    microphones.
    """
    if not sent or not heard:
        return NO_LAG
    max_lag = round(max_lag_s / ENVELOPE_S)
    start = max(sent[0][0], heard[0][0])
    end = min(
        sent[-1][0] + len(sent[-1][1]) / sent_rate_hz,
        heard[-1][0] + len(heard[-1][1]) / heard_rate_hz - max_lag * ENVELOPE_S,
    )
    if end <= start:
        return NO_LAG
    longest = end + max_lag * ENVELOPE_S
    a = _smooth(envelope(sent, sent_rate_hz, start, longest)[:, None])
    b = _smooth(envelope(heard, heard_rate_hz, start, longest)[:, None])
    a = a[: len(a) - max_lag]  # both smoothed over the same span (the same edges), a then cut
    if a.std() < MIN_SOUND_RMS or b.std() < MIN_SOUND_RMS:
        return NO_LAG
    return _best_lag(a, b, max_lag, ENVELOPE_S)


class ChunkPairing:
    """Pair audio chunk arrivals with the pose messages they caused, by event order.

    Every audio chunk the graph decodes ends in one ``raw_trajectory`` message (the features
    node publishes one features message per chunk of 10 ms or more, the inference node one
    pose message per features message). A pose message belongs to the newest chunk that arrived
    before it and has none yet; older unanswered chunks (shorter than a feature window, at the
    start of a stream) are dropped. This holds while the graph answers a chunk within a chunk
    period (20 ms from the console; ``audio2pose bench --graph`` measures 2-5 ms).

    Args:
        window: latencies kept.
        max_pairing_s: a chunk unanswered for this long is dropped.
    """

    def __init__(self, window: int = 500, max_pairing_s: float = 1.0) -> None:
        self.max_pairing_s = max_pairing_s
        self._chunks: deque[float] = deque(maxlen=64)
        self.latencies_s: deque[float] = deque(maxlen=window)

    def chunk(self, arrival_s: float) -> None:
        """An audio chunk arrived."""
        self._chunks.append(arrival_s)

    def poses(self, arrival_s: float) -> None:
        """A pose message arrived: pair it with the newest chunk before it."""
        while self._chunks and arrival_s - self._chunks[0] > self.max_pairing_s:
            self._chunks.popleft()
        newest = None
        while self._chunks and self._chunks[0] <= arrival_s:
            newest = self._chunks.popleft()
        if newest is not None:
            self.latencies_s.append(arrival_s - newest)

    def median_s(self) -> float:
        """Median latency (s) of the pairs kept, NaN with none."""
        return float(np.median(self.latencies_s)) if self.latencies_s else math.nan
