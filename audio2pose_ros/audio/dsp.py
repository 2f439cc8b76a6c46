"""Signal-processing steps of the feature pipeline (seed 003 section 3.2).

Mel scale and triangular filter bank (eq. 3.4), orthonormal DCT-II and sinusoidal lifter (step
6), Hamming window (eq. 3.2), pre-emphasis (eq. 3.1), deltas (eq. 3.5) and the rFFT kernel, with
the numbers python_speech_features 0.6 gives; :mod:`~audio2pose_ros.audio.features` assembles
them into feature sets.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from audio2pose_ros.timebase import SAMPLE_RATE_HZ

LOG_FLOOR = float(np.finfo(np.float64).eps)  # replaces zero energies before the log (as the seed's)


def round_half_up(value: float) -> int:
    """Round to the nearest integer, halves away from zero (python_speech_features' framing).

    The exact binary value of ``value`` is rounded (``0.025 * 16000`` -> 400): a float minus
    its floor is exact, so no decimal arithmetic is needed (``decimal`` would cost the node
    processes its C library).

    Args:
        value: a non-negative number of samples.

    Returns:
        The rounded integer.

    Raises:
        OverflowError: ``value`` is infinite.
        ValueError: ``value`` is NaN.

    """
    magnitude = abs(value)
    whole = math.floor(magnitude)
    rounded = whole + (magnitude - whole >= 0.5)
    return rounded if value >= 0 else -rounded


def hz_to_mel(hz: np.ndarray | float) -> np.ndarray:
    """Convert frequency to mel, m = 1125 ln(1 + f / 700) (seed 003 eq. 3.4).

    python_speech_features uses m = 2595 log10(1 + f / 700) = 1127.01 ln(1 + f / 700): the same
    curve up to a constant factor (1125 vs 2595 / ln 10 = 1127.01), not the same function: mel
    values differ by 0.18 %. The filter bank places its edges evenly on the mel axis and maps
    them back with the inverse of the same formula, so the factor cancels and both give the
    same edges in Hz (up to rounding; :func:`mel_filterbank` uses the 2595 log10 form to match
    the reference bit for bit).

    Args:
        hz: frequency (Hz), scalar or array.

    Returns:
        Mel value(s), same shape.

    """
    return 1125.0 * np.log1p(np.asarray(hz, dtype=np.float64) / 700.0)


def mel_to_hz(mel: np.ndarray | float) -> np.ndarray:
    """Convert mel to frequency, f = 700 (exp(m / 1125) - 1) (seed 003 eq. 3.4).

    Args:
        mel: mel value(s), scalar or array.

    Returns:
        Frequency (Hz), same shape.

    """
    return 700.0 * np.expm1(np.asarray(mel, dtype=np.float64) / 1125.0)


def mel_filterbank(
    nfilt: int = 26,
    nfft: int = 512,
    sample_rate_hz: float = SAMPLE_RATE_HZ,
    lowfreq_hz: float = 0.0,
    highfreq_hz: float | None = None,
) -> np.ndarray:
    """Triangular mel filter bank (seed 003 section 3.2 step 5, eq. 3.4).

    ``nfilt + 2`` edges are spaced evenly in mel between ``lowfreq_hz`` and ``highfreq_hz`` and
    mapped to FFT bins ``b = floor((nfft + 1) f / sample_rate_hz)`` (python_speech_features'
    ``nfft + 1``). Filter j rises linearly from 0 at bin b_j to 1 at b_{j+1} and falls to 0 at
    b_{j+2} (that bin excluded); filters whose edges share a bin lose the empty side.

    The edges are computed in python_speech_features' form m = 2595 log10(1 + f / 700) rather
    than eq. 3.4's 1125 ln(1 + f / 700): the constant cancels (see :func:`hz_to_mel`), but an
    edge can land exactly on a bin boundary (e.g. the top edge 8 kHz with odd ``nfft``:
    402 * 8000 / 16000 = 201) and then ``floor`` depends on the last bit of the round trip
    mel -> Hz. Doing the same operations as the reference keeps the filter bank identical.

    Args:
        nfilt: number of filters (default 26).
        nfft: FFT size (default 512).
        sample_rate_hz: sample rate (Hz, default 16000).
        lowfreq_hz: lowest band edge (Hz, default 0).
        highfreq_hz: highest band edge (Hz, default None = sample_rate_hz / 2).

    Returns:
        (nfilt, nfft // 2 + 1) filter weights, one filter per row.

    """
    highfreq = sample_rate_hz / 2.0 if highfreq_hz is None else float(highfreq_hz)
    if not 0.0 <= lowfreq_hz < highfreq <= sample_rate_hz / 2.0:
        raise ValueError(
            f"need 0 <= lowfreq_hz < highfreq_hz <= sample_rate_hz / 2, got {lowfreq_hz}, "
            f"{highfreq}, {sample_rate_hz / 2.0}"
        )
    low_mel = 2595.0 * np.log10(1.0 + lowfreq_hz / 700.0)
    high_mel = 2595.0 * np.log10(1.0 + highfreq / 700.0)
    mels = np.linspace(low_mel, high_mel, nfilt + 2)
    edges_hz = 700.0 * (10.0 ** (mels / 2595.0) - 1.0)
    edges = np.floor((nfft + 1) * edges_hz / sample_rate_hz)
    lo, mid, hi = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    bins = np.arange(nfft // 2 + 1, dtype=np.float64)[None, :]
    rise = (bins >= lo) & (bins < mid)
    fall = (bins >= mid) & (bins < hi)
    rising = np.divide(bins - lo, mid - lo, out=np.zeros_like(rise, float), where=rise)
    falling = np.divide(hi - bins, hi - mid, out=np.zeros_like(fall, float), where=fall)
    return rising + falling


def dct_matrix(n_in: int, n_out: int) -> np.ndarray:
    """Orthonormal DCT-II as a matrix (seed 003 section 3.2 step 6).

    ``x @ dct_matrix(n, k)`` equals ``scipy.fftpack.dct(x, type=2, norm='ortho')[..., :k]``.

    Args:
        n_in: input length (number of filters).
        n_out: number of coefficients kept (<= n_in).

    Returns:
        (n_in, n_out) matrix.

    """
    n = np.arange(n_in, dtype=np.float64)[:, None]
    k = np.arange(n_out, dtype=np.float64)[None, :]
    basis = np.cos(np.pi * k * (2.0 * n + 1.0) / (2.0 * n_in))
    scale = np.full(n_out, math.sqrt(2.0 / n_in))
    scale[0] = math.sqrt(1.0 / n_in)
    return basis * scale[None, :]


def lifter_weights(numcep: int, ceplifter: float) -> np.ndarray:
    """Sinusoidal cepstral lifter 1 + (L / 2) sin(pi n / L) (python_speech_features ``lifter``).

    Args:
        numcep: number of cepstral coefficients.
        ceplifter: L; L <= 0 disables liftering (all weights 1).

    Returns:
        (numcep,) weights.

    """
    if ceplifter <= 0:
        return np.ones(numcep)
    n = np.arange(numcep, dtype=np.float64)
    return 1.0 + (ceplifter / 2.0) * np.sin(np.pi * n / ceplifter)


def hamming_window(length: int) -> np.ndarray:
    """Symmetric Hamming window h[n] = 0.54 - 0.46 cos(2 pi n / (N_w - 1)) (seed 003 eq. 3.2).

    Args:
        length: N_w, window length (samples).

    Returns:
        (length,) window.

    """
    if length == 1:
        return np.ones(1)
    n = np.arange(length, dtype=np.float64)
    return 0.54 - 0.46 * np.cos(2.0 * np.pi * n / (length - 1))


def delta_rows(seq: np.ndarray, seq_start: int, rows: np.ndarray, last: int, n: int) -> np.ndarray:
    """Eq. 3.5 at global frame indices ``rows``, edge frames repeated beyond [0, last].

    Args:
        seq: (m, d) frames; ``seq[i]`` is global frame ``seq_start + i``.
        seq_start: global index of ``seq[0]``.
        rows: (r,) global frame indices to differentiate.
        last: global index of the last frame of the whole sequence (the upper edge).
        n: N_Delta.

    Returns:
        (r, d) delta frames.

    """
    acc = np.zeros((rows.size, seq.shape[1]))
    for i in range(1, n + 1):
        ahead = np.minimum(rows + i, last) - seq_start
        behind = np.maximum(rows - i, 0) - seq_start
        acc += i * (seq[ahead] - seq[behind])
    return acc / (2.0 * sum(i * i for i in range(1, n + 1)))


def delta(features: np.ndarray, n: int = 2) -> np.ndarray:
    """Delta (differential) features, seed 003 eq. 3.5, edges padded by repetition.

    Args:
        features: (n_frames, d) features.
        n: N_Delta, frames on each side (default 2).

    Returns:
        (n_frames, d) first-order deltas; apply twice for the second order.

    """
    feats = np.asarray(features, dtype=np.float64)
    if n < 1:
        raise ValueError(f"delta n must be >= 1, got {n}")
    if feats.shape[0] == 0:
        return feats.copy()
    rows = np.arange(feats.shape[0])
    return delta_rows(feats, 0, rows, feats.shape[0] - 1, n)


def direct_rfft(nfft: int, frame_len: int) -> Callable[..., np.ndarray] | None:
    """Return numpy's rfft ufunc for ``nfft`` points, or None where numpy has none.

    numpy >= 2 implements ``np.fft.rfft`` as a ufunc (``rfft_n_even(x, fct, out=...)``, zero
    padding ``x`` to the FFT size that ``out`` implies); calling it directly skips about 2 us
    of argument handling per frame. It is private API, so it is only used after it reproduced
    ``np.fft.rfft`` exactly on a test frame here; otherwise the caller uses ``np.fft.rfft``.
    """
    try:
        from numpy.fft import _pocketfft_umath  # type: ignore[attr-defined]  # private, optional

        ufunc = _pocketfft_umath.rfft_n_even if nfft % 2 == 0 else _pocketfft_umath.rfft_n_odd
        probe = np.sin(0.37 * np.arange(frame_len)) + 0.25 * np.cos(1.91 * np.arange(frame_len))
        got = ufunc(probe, 1.0, out=np.empty(nfft // 2 + 1, dtype=np.complex128))
        if np.array_equal(got, np.fft.rfft(probe, nfft)):
            return ufunc
    except (ImportError, AttributeError, TypeError, ValueError):
        pass
    return None


def preemphasis(x: np.ndarray, alpha: float, previous: float = 0.0) -> np.ndarray:
    """Eq. 3.1, y[n] = x[n] - alpha x[n - 1], with x[-1] = ``previous``."""
    y = np.empty_like(x)
    if x.size:
        y[0] = x[0] - alpha * previous
        np.subtract(x[1:], alpha * x[:-1], out=y[1:])
    return y
