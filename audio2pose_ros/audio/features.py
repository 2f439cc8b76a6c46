"""Log filter-bank and MFCC audio features, offline and streaming (seed 003 section 3.2).

The computation follows seed 003 section 3.2, steps 1-8, with the settings of section 4.2.2
(alpha = 0.97, w = 25 ms, s = 10 ms, N_FFT = 512, N_filt = 26, N_Delta = 2):

1. pre-emphasis y(t) = x(t) - alpha x(t - 1/f_s) (eq. 3.1), the first sample kept as is;
2. framing into ``frame_len``-sample frames every ``frame_step`` samples, the last frame
   zero-padded;
3. windowing: rectangular (no window) by default, as python_speech_features' default ``winfunc``
   that the seed used, or the Hamming window of eq. 3.2;
4. power spectrum P = |FFT(y_i)|^2 / N_FFT (eq. 3.3);
5. triangular mel filters (eq. 3.4), logarithm -> LogFB;
6. DCT-II (orthonormal), first ``numcep`` coefficients, sinusoidal lifter, coefficient 0
   replaced by the log frame energy -> MFCC;
7. deltas (eq. 3.5) of order 1 (LogFB-52) or 1 and 2 (LogFB-78);
8. per-speaker z-normalisation (:class:`FeatureNormalizer`).

The numbers are those of python_speech_features 0.6 (``logfbank``, ``mfcc``, ``delta``), which
the seed used, including its quirks: FFT bin edges ``floor((N_FFT + 1) f / f_s)``, zero band
energies replaced by float64 eps before the log, the number of frames
``1 + ceil((n - frame_len) / frame_step)`` (at least 1) with a zero-padded last frame, and deltas
that repeat the first/last frame at the edges. That library is not used here; the tests
compare against it.

All computations are in float64; features are float64 arrays of shape (n_frames, dim).
"""

from __future__ import annotations

import dataclasses
import decimal
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.timebase import FRAME_PERIOD_S, SAMPLE_RATE_HZ, WINDOW_S

_EPS = float(np.finfo(np.float64).eps)  # replaces zero energies before the log (as the seed's)

_BLOCK_FRAMES = 4096  # frames per vectorised block in extract_features

KINDS: tuple[str, ...] = ("logfbank", "mfcc")
WINDOWS: tuple[str, ...] = ("rectangular", "hamming")


def round_half_up(value: float) -> int:
    """Round to the nearest integer, halves away from zero (python_speech_features' framing).

    The exact binary value of ``value`` is rounded (``0.025 * 16000`` -> 400).

    Args:
        value: a non-negative number of samples.

    Returns:
        The rounded integer.

    """
    exact = decimal.Decimal(value).quantize(decimal.Decimal(1), rounding=decimal.ROUND_HALF_UP)
    return int(exact)


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


def _delta_rows(seq: np.ndarray, seq_start: int, rows: np.ndarray, last: int, n: int) -> np.ndarray:
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
    return _delta_rows(feats, 0, rows, feats.shape[0] - 1, n)


@dataclass(frozen=True)
class FeatureSpec:
    """Audio feature settings (seed 003 sections 3.2 and 4.2.2); the defaults give LogFB-26.

    Attributes:
        kind: ``"logfbank"`` (LogFB) or ``"mfcc"``.
        sample_rate_hz: sample rate of the signal (Hz, default 16000).
        window_s: frame length w (s, default 0.025).
        step_s: frame step s (s, default 0.010).
        nfft: N_FFT (default 512; must be >= frame_len).
        nfilt: N_filt, number of mel filters (default 26).
        numcep: MFCCs kept (default 13; mfcc only).
        lowfreq_hz: lowest mel band edge (Hz, default 0).
        highfreq_hz: highest mel band edge (Hz, default None = sample_rate_hz / 2).
        preemph: pre-emphasis alpha of eq. 3.1 (default 0.97; 0 disables).
        ceplifter: cepstral lifter L (default 22; <= 0 disables; mfcc only).
        append_energy: replace MFCC 0 by the log frame energy (default True; mfcc only).
        window: ``"rectangular"`` (python_speech_features' default, used by the seed) or
            ``"hamming"`` (eq. 3.2).
        delta_order: 0, 1 (append deltas) or 2 (append deltas and delta-deltas), eq. 3.5.
        delta_n: N_Delta (default 2).

    """

    kind: str = "logfbank"
    sample_rate_hz: int = SAMPLE_RATE_HZ
    window_s: float = WINDOW_S
    step_s: float = FRAME_PERIOD_S
    nfft: int = 512
    nfilt: int = 26
    numcep: int = 13
    lowfreq_hz: float = 0.0
    highfreq_hz: float | None = None
    preemph: float = 0.97
    ceplifter: float = 22
    append_energy: bool = True
    window: str = "rectangular"
    delta_order: int = 0
    delta_n: int = 2

    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "logfb26": {},
        "logfb52": {"delta_order": 1},
        "logfb78": {"delta_order": 2},
        "mfcc13": {"kind": "mfcc"},
    }

    # Bounds on what a checkpoint's feature section may ask for: the seed's settings sit well
    # inside them, and they keep the filter bank and per-frame buffers small (nfft 65536 x
    # nfilt 512 float64 is 128 MiB at most).
    MAX_SAMPLE_RATE_HZ: ClassVar[int] = 48000
    MAX_WINDOW_S: ClassVar[float] = 1.0
    MAX_NFFT: ClassVar[int] = 1 << 16
    MAX_NFILT: ClassVar[int] = 512
    MAX_DELTA_N: ClassVar[int] = 100

    def __post_init__(self) -> None:
        """Reject inconsistent or out-of-bounds settings with one line naming the field.

        Raises:
            ConfigurationError: the first field refused.
        """
        if self.kind not in KINDS:
            raise ConfigurationError(f"FeatureSpec kind must be one of {KINDS}, got {self.kind!r}")
        if self.window not in WINDOWS:
            raise ConfigurationError(
                f"FeatureSpec window must be one of {WINDOWS}, got {self.window!r}"
            )
        bounds = {
            "sample_rate_hz": (8000, self.MAX_SAMPLE_RATE_HZ),
            "nfft": (1, self.MAX_NFFT),
            "nfilt": (1, self.MAX_NFILT),
            "numcep": (1, self.MAX_NFILT),
            "delta_order": (0, 2),
            "delta_n": (1, self.MAX_DELTA_N),
        }
        for name, (low, high) in bounds.items():
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, int | np.integer)
                or not low <= value <= high
            ):
                raise ConfigurationError(
                    f"FeatureSpec {name} must be an integer in [{low}, {high}], got {value!r}"
                )
        reals = {
            "window_s": self.window_s,
            "step_s": self.step_s,
            "lowfreq_hz": self.lowfreq_hz,
            "highfreq_hz": 0.0 if self.highfreq_hz is None else self.highfreq_hz,
            "preemph": self.preemph,
            "ceplifter": self.ceplifter,
        }
        for name, value in reals.items():
            if (
                isinstance(value, bool)
                or not isinstance(value, int | float | np.integer | np.floating)
                or not math.isfinite(value)
            ):
                raise ConfigurationError(
                    f"FeatureSpec {name} must be a finite number, got {value!r}"
                )
        if not isinstance(self.append_energy, bool | np.bool_):
            raise ConfigurationError(
                f"FeatureSpec append_energy must be true or false, got {self.append_energy!r}"
            )
        if not (0 < self.window_s <= self.MAX_WINDOW_S and 0 < self.step_s <= self.MAX_WINDOW_S):
            raise ConfigurationError(
                f"FeatureSpec window_s and step_s must be in (0, {self.MAX_WINDOW_S}] s, got "
                f"{self.window_s}, {self.step_s}"
            )
        if self.frame_len < 1 or self.frame_step < 1:
            raise ConfigurationError(
                "FeatureSpec window_s and step_s must each cover at least one sample"
            )
        if self.nfft < self.frame_len:
            raise ConfigurationError(
                f"FeatureSpec nfft ({self.nfft}) must be >= frame_len ({self.frame_len} samples)"
            )
        if self.kind == "mfcc" and self.numcep > self.nfilt:
            raise ConfigurationError(
                f"FeatureSpec numcep ({self.numcep}) must be <= nfilt ({self.nfilt})"
            )
        if not 0.0 <= self.preemph < 1.0:
            raise ConfigurationError(f"FeatureSpec preemph must be in [0, 1), got {self.preemph}")
        nyquist = self.sample_rate_hz / 2.0
        if not 0.0 <= self.lowfreq_hz < self.highfreq <= nyquist:
            raise ConfigurationError(
                f"FeatureSpec needs 0 <= lowfreq_hz < highfreq_hz <= {nyquist} Hz, got "
                f"{self.lowfreq_hz}, {self.highfreq_hz}"
            )

    @property
    def highfreq(self) -> float:
        """Highest mel band edge actually used (Hz)."""
        return self.sample_rate_hz / 2.0 if self.highfreq_hz is None else float(self.highfreq_hz)

    @property
    def base_dim(self) -> int:
        """Features per frame before deltas: nfilt (LogFB) or numcep (MFCC)."""
        return self.nfilt if self.kind == "logfbank" else self.numcep

    @property
    def dim(self) -> int:
        """Features per frame including deltas (26, 52, 78 for LogFB; 13 for MFCC-13)."""
        return self.base_dim * (1 + self.delta_order)

    @property
    def frame_len(self) -> int:
        """Frame length in samples, round-half-up of window_s * sample_rate_hz (400)."""
        return round_half_up(self.window_s * self.sample_rate_hz)

    @property
    def frame_step(self) -> int:
        """Frame step in samples, round-half-up of step_s * sample_rate_hz (160)."""
        return round_half_up(self.step_s * self.sample_rate_hz)

    @property
    def lookahead_frames(self) -> int:
        """Future frames a delta frame needs: delta_n * delta_order (0, 2 or 4 by default)."""
        return self.delta_n * self.delta_order

    @property
    def frames_per_second(self) -> float:
        """Feature frame rate f_f (Hz, 100 by default)."""
        return self.sample_rate_hz / self.frame_step

    def n_frames(self, n_samples: int) -> int:
        """Count frames of a signal: 0 if empty, else max(1, 1 + ceil((n - frame_len) / step)).

        Args:
            n_samples: signal length (samples).

        Returns:
            Number of feature frames :func:`extract_features` returns.

        """
        if n_samples <= 0:
            return 0
        if n_samples <= self.frame_len:
            return 1
        return 1 + -(-(n_samples - self.frame_len) // self.frame_step)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dictionary of all fields."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.generic):
                value = value.item()
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FeatureSpec:
        """Build a spec from :meth:`to_dict` output; missing keys take the defaults.

        Args:
            data: field name -> value.

        Returns:
            The spec.

        Raises:
            ConfigurationError: an unknown key (the message lists the known ones) or a bad
                value.

        """
        known = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(known))
        if unknown:
            raise ConfigurationError(f"unknown FeatureSpec key(s) {unknown}; known keys: {known}")
        return cls(**dict(data))

    @classmethod
    def preset(cls, name: str) -> FeatureSpec:
        """One of the seed's feature sets (seed 003 section 4.2.2).

        Args:
            name: ``"logfb26"``, ``"logfb52"``, ``"logfb78"`` or ``"mfcc13"`` (case, ``-`` and
                ``_`` ignored, so ``"LogFB-26"`` works).

        Returns:
            The spec.

        Raises:
            ConfigurationError: an unknown preset (the message lists the known ones).

        """
        key = name.lower().replace("-", "").replace("_", "")
        if key not in cls.PRESETS:
            raise ConfigurationError(
                f"unknown feature preset {name!r}; known: {sorted(cls.PRESETS)}"
            )
        return cls(**cls.PRESETS[key])


def _direct_rfft(nfft: int, frame_len: int) -> Callable[..., np.ndarray] | None:
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


class _Kernel:
    """Precomputed matrices turning pre-emphasised frames into base features (steps 3-6)."""

    def __init__(self, spec: FeatureSpec) -> None:
        self.spec = spec
        self.nfft = spec.nfft
        self.logfbank = spec.kind == "logfbank"
        self.append_energy = spec.append_energy
        self.window = None if spec.window == "rectangular" else hamming_window(spec.frame_len)
        fb = mel_filterbank(
            spec.nfilt, spec.nfft, spec.sample_rate_hz, spec.lowfreq_hz, spec.highfreq
        )
        weights = fb.T / spec.nfft  # (bins, nfilt), P = |X|^2 / N_FFT folded in (eq. 3.3)
        if not self.logfbank:
            energy = np.full((weights.shape[0], 1), 1.0 / spec.nfft)
            weights = np.hstack([weights, energy])  # last column: frame energy sum(P)
            lift = lifter_weights(spec.numcep, spec.ceplifter)
            self.cepstral = dct_matrix(spec.nfilt, spec.numcep) * lift[None, :]
        # Rows 2i and 2i+1 weight Re(X_i)^2 and Im(X_i)^2 of the rfft viewed as float pairs.
        self.weights = np.ascontiguousarray(np.repeat(weights, 2, axis=0))
        self.weights_t = np.ascontiguousarray(self.weights.T)
        # Scratch buffers of the one-frame path; their contents never leave it.
        self.rfft = _direct_rfft(spec.nfft, spec.frame_len)
        self.spectrum = np.empty(spec.nfft // 2 + 1, dtype=np.complex128)
        self.squares = np.empty(2 * (spec.nfft // 2 + 1))
        self.zero = np.empty(self.weights.shape[1], dtype=bool)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """Compute base features (k, base_dim) of (k, frame_len) pre-emphasised frames."""
        if self.window is not None:
            frames = frames * self.window
        spectrum = np.fft.rfft(frames, self.nfft)
        parts = spectrum.view(np.float64)
        energies = (parts * parts) @ self.weights
        energies[energies == 0.0] = _EPS  # as python_speech_features: avoid log(0)
        return self._cepstra(np.log(energies))

    def single(self, frame: np.ndarray) -> np.ndarray:
        """Compute base features (1, base_dim) of one (frame_len,) frame, with little overhead."""
        if self.window is not None:
            frame = frame * self.window
        if self.rfft is not None:
            spectrum = self.rfft(frame, 1.0, out=self.spectrum)
        else:
            spectrum = np.fft.rfft(frame, self.nfft)
        parts = spectrum.view(np.float64)
        np.multiply(parts, parts, out=self.squares)
        energies = self.weights_t.dot(self.squares)
        # as python_speech_features: exact zeros become eps to avoid log(0)
        np.copyto(energies, _EPS, where=np.equal(energies, 0.0, out=self.zero))
        logs = np.log(energies, out=energies)[None, :]
        return logs if self.logfbank else self._cepstra(logs)

    def _cepstra(self, logs: np.ndarray) -> np.ndarray:
        """Log filter-bank energies -> LogFB or liftered MFCCs with log energy (step 6)."""
        if self.logfbank:
            return logs
        ceps = logs[:, :-1] @ self.cepstral
        if self.append_energy:
            ceps[:, 0] = logs[:, -1]
        return ceps


def _preemphasis(x: np.ndarray, alpha: float, previous: float = 0.0) -> np.ndarray:
    """Eq. 3.1, y[n] = x[n] - alpha x[n - 1], with x[-1] = ``previous``."""
    y = np.empty_like(x)
    if x.size:
        y[0] = x[0] - alpha * previous
        np.subtract(x[1:], alpha * x[:-1], out=y[1:])
    return y


def _with_deltas(base: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """Append delta (and delta-delta) columns, eq. 3.5, edges repeated."""
    parts = [base]
    for _ in range(spec.delta_order):
        parts.append(delta(parts[-1], spec.delta_n))
    return np.hstack(parts) if len(parts) > 1 else base


def extract_features(signal: np.ndarray, spec: FeatureSpec | None = None) -> np.ndarray:
    """Features of a whole signal (offline; seed 003 section 3.2 steps 1-7).

    Equal (to float64 rounding) to python_speech_features' ``logfbank``/``mfcc`` followed by
    ``delta`` run on the same signal, including its frame count and zero-padded last frame.

    Args:
        signal: (n,) mono samples at ``spec.sample_rate_hz`` (any float dtype; computed in
            float64).
        spec: settings (default LogFB-26).

    Returns:
        (spec.n_frames(n), spec.dim) float64 features; (0, dim) for an empty signal (where
        python_speech_features raises IndexError).

    """
    spec = FeatureSpec() if spec is None else spec
    x = np.asarray(signal, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"signal must be 1-D (mono), got shape {x.shape}")
    n_frames = spec.n_frames(x.size)
    if n_frames == 0:
        return np.empty((0, spec.dim))
    y = _preemphasis(x, spec.preemph)
    padded_len = (n_frames - 1) * spec.frame_step + spec.frame_len
    y = np.concatenate([y, np.zeros(max(0, padded_len - y.size))])
    frames = np.lib.stride_tricks.sliding_window_view(y, spec.frame_len)[:: spec.frame_step]
    kernel = _Kernel(spec)
    base = np.empty((n_frames, spec.base_dim))
    for i in range(0, n_frames, _BLOCK_FRAMES):  # blocks bound the FFT's temporary memory
        base[i : i + _BLOCK_FRAMES] = kernel(frames[i : min(i + _BLOCK_FRAMES, n_frames)])
    return _with_deltas(base, spec)


class StreamingFeatureExtractor:
    """Incremental :func:`extract_features`: push samples, get the frames that became complete.

    The concatenation of all :meth:`push` outputs and the final :meth:`flush` equals
    :func:`extract_features` of the concatenated samples (to float64 rounding), whatever the
    chunking. A frame is computed as soon as its last sample arrives; with deltas it is emitted
    ``spec.lookahead_frames`` frames later, once the future frames eq. 3.5 needs exist (the
    first frames use repeated copies of frame 0, as python_speech_features does). :meth:`flush`
    adds the zero-padded last partial frame and the delta tail, then starts a new stream.

    Pushing one frame step (160 samples) at a time costs one FFT and a few small matrix
    products: the filter bank, window, DCT, lifter and delta weights are precomputed, raw
    samples go into a reused buffer and pre-emphasis (eq. 3.1) is applied per frame. An
    instance keeps scratch buffers and is not thread-safe: use one per stream and thread.

    Args:
        spec: settings (default LogFB-26).

    """

    _BUFFER_STEPS = 64  # initial sample buffer: frame_len + 64 steps (grows for big pushes)
    _HISTORY_ROWS = 256  # initial base-frame history for deltas (grows for big pushes)

    def __init__(self, spec: FeatureSpec | None = None) -> None:
        self.spec = FeatureSpec() if spec is None else spec
        self._kernel = _Kernel(self.spec)
        self._flen = self.spec.frame_len
        self._step = self.spec.frame_step
        self._alpha = float(self.spec.preemph)
        self._lookahead = self.spec.lookahead_frames
        self._empty = np.empty((0, self.spec.dim))
        self._frame = np.empty(self._flen)  # scratch: one pre-emphasised frame
        # Steady-state delta weights: row o applied to base frames t-L..t+L gives order o at t
        # (eq. 3.5; order 2 is eq. 3.5 applied to order 1, i.e. the kernel convolved with
        # itself). Valid only where no edge padding is involved.
        n = self.spec.delta_n
        kernel = np.arange(-n, n + 1, dtype=np.float64) / (
            2.0 * sum(i * i for i in range(1, n + 1))
        )
        width = 2 * self._lookahead + 1
        rows = [np.zeros(width)]
        rows[0][self._lookahead] = 1.0
        level = np.array([1.0])
        for _ in range(self.spec.delta_order):
            level = np.convolve(level, kernel)
            pad = (width - level.size) // 2
            rows.append(np.pad(level, (pad, pad)))
        self._delta_weights = np.vstack(rows)
        self.reset()

    @property
    def frames_per_second(self) -> float:
        """Feature frame rate (Hz, 100 by default)."""
        return self.spec.frames_per_second

    @property
    def frames_emitted(self) -> int:
        """Frames returned since the stream started (the index of the next frame)."""
        return self._emitted

    @property
    def samples_pushed(self) -> int:
        """Samples pushed since the stream started."""
        return self._total

    def reset(self) -> None:
        """Drop all state and start a new stream."""
        self._raw = np.zeros(1 + self._flen + self._BUFFER_STEPS * self._step)  # raw samples
        self._fill = 1  # valid samples in _raw; _raw[0] = 0 is x[-1] of eq. 3.1
        self._start = 1  # _raw index where the next frame starts
        self._total = 0  # samples pushed
        self._n_base = 0  # base frames computed
        self._emitted = 0  # frames returned
        self._hist = np.empty((self._HISTORY_ROWS, self.spec.base_dim))  # base frames (deltas)
        self._hist_len = 0  # valid rows of _hist
        self._hist_start = 0  # global frame index of _hist[0]

    def _make_room(self, n: int) -> int:
        """Move the samples still needed to the buffer front, growing it if needed.

        Returns:
            The new fill level.

        """
        keep = self._raw[self._start - 1 : self._fill]  # x[-1] of the next frame onwards
        size = self._raw.size
        if keep.size + n > size:
            size = 2 * (keep.size + n)
        raw = np.empty(size) if size > self._raw.size else self._raw
        raw[: keep.size] = keep  # overlapping copy is safe: numpy buffers the move
        self._raw = raw
        self._start = 1
        self._fill = keep.size
        return self._fill

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Add samples; return the frames that became complete.

        Args:
            samples: (n,) mono samples at ``spec.sample_rate_hz`` (any float dtype).

        Returns:
            (k, spec.dim) float64 features, k >= 0.

        """
        x = samples
        if not (isinstance(x, np.ndarray) and x.ndim == 1 and x.dtype.kind == "f"):
            x = np.asarray(samples, dtype=np.float64).reshape(-1)
        n = x.size
        if n == 0:
            return self._empty
        fill = self._fill
        if fill + n > self._raw.size:
            fill = self._make_room(n)
        raw = self._raw
        raw[fill : fill + n] = x  # float32 input is widened exactly to float64
        fill += n
        self._fill = fill
        self._total += n
        start = self._start
        flen = self._flen
        available = fill - start - flen
        if available < 0:
            return self._empty
        if available < self._step:  # exactly one new frame: the real-time case
            k = 1
            frame = self._frame
            np.multiply(raw[start - 1 : start - 1 + flen], self._alpha, out=frame)  # eq. 3.1
            np.subtract(raw[start : start + flen], frame, out=frame)
            base = self._kernel.single(frame)
        else:
            k = available // self._step + 1
            stop = start + (k - 1) * self._step + flen
            emphasised = raw[start:stop] - self._alpha * raw[start - 1 : stop - 1]  # eq. 3.1
            view = np.lib.stride_tricks.sliding_window_view(emphasised, flen)
            base = self._kernel(view[:: self._step])
        self._start = start + k * self._step
        self._n_base += k
        if self._lookahead == 0:
            self._emitted += k
            return base
        return self._deltas(base, last=None)

    def flush(self) -> np.ndarray:
        """End the stream: emit the zero-padded last partial frame and the delta tail, then reset.

        Returns:
            (k, spec.dim) float64 features; empty if nothing was pushed.

        """
        base = np.empty((0, self.spec.base_dim))
        if self.spec.n_frames(self._total) > self._n_base:  # at most one partial frame remains
            start, fill = self._start, self._fill
            frame = np.zeros((1, self._flen))
            frame[0, : fill - start] = (
                self._raw[start:fill] - self._alpha * self._raw[start - 1 : fill - 1]
            )
            base = self._kernel(frame)
            self._n_base += 1
        if self._lookahead == 0:
            out = base
        elif self._n_base > 0:
            out = self._deltas(base, last=self._n_base - 1)
        else:
            out = self._empty
        self.reset()
        return out

    def _store(self, base: np.ndarray) -> None:
        """Append base frames to the history, dropping rows no later frame needs."""
        k = base.shape[0]
        if self._hist_len + k > self._hist.shape[0]:
            keep_from = max(0, self._emitted - self._lookahead)  # oldest row still needed
            keep = self._hist[keep_from - self._hist_start : self._hist_len]
            rows = max(self._hist.shape[0], 2 * (keep.shape[0] + k))
            hist = (
                np.empty((rows, self._hist.shape[1])) if rows > self._hist.shape[0] else self._hist
            )
            hist[: keep.shape[0]] = keep
            self._hist = hist
            self._hist_len = keep.shape[0]
            self._hist_start = keep_from
        self._hist[self._hist_len : self._hist_len + k] = base
        self._hist_len += k

    def _deltas(self, base: np.ndarray, last: int | None) -> np.ndarray:
        """Store new base frames and return the frames whose deltas are now computable.

        Args:
            base: the newest base frames (global indices up to ``n_base - 1``).
            last: global index of the stream's last frame at the end of the stream, else None.

        Returns:
            (k, spec.dim) frames: base features followed by the delta orders.

        """
        if base.shape[0]:
            self._store(base)
        lookahead = self._lookahead
        t = self._emitted
        end = self._n_base if last is not None else self._n_base - lookahead
        if end <= t:
            return self._empty
        if last is None and end == t + 1 and t >= lookahead:
            # steady state: one frame, no edge padding -> one small matrix product
            window = self._hist[self._hist_len - 2 * lookahead - 1 : self._hist_len]
            self._emitted = end
            return (self._delta_weights @ window).reshape(1, -1)
        top = self._n_base - 1 if last is None else last
        n = self.spec.delta_n
        rows = np.arange(t, end)
        level, level_start = self._hist[: self._hist_len], self._hist_start
        parts = [level[rows - level_start]]
        for order in range(1, self.spec.delta_order + 1):
            # rows of this order that the higher orders still need (eq. 3.5 applied again)
            reach = n * (self.spec.delta_order - order)
            need = np.arange(max(0, t - reach), min(top, end - 1 + reach) + 1)
            level = _delta_rows(level, level_start, need, top, n)
            level_start = int(need[0])
            parts.append(level[rows - level_start])
        self._emitted = end
        return np.hstack(parts)


@dataclass
class FeatureNormalizer:
    """Per-speaker z-normalisation of features (seed 003 section 3.2 step 8).

    Attributes:
        mean: (dim,) feature means.
        std: (dim,) feature standard deviations (population, ddof 0), at least
            :attr:`STD_FLOOR`.

    """

    mean: np.ndarray
    std: np.ndarray

    # A feature that is (nearly) constant for a speaker, e.g. a band that is digital silence
    # throughout (log(eps) everywhere), has std ~ 0; dividing by it would blow noise up to huge
    # values or inf. Standard deviations are therefore floored at this value.
    STD_FLOOR: ClassVar[float] = 1e-6

    def __post_init__(self) -> None:
        """Coerce to float64 vectors and check shapes and values."""
        self.mean = np.asarray(self.mean, dtype=np.float64).reshape(-1)
        self.std = np.asarray(self.std, dtype=np.float64).reshape(-1)
        if self.mean.shape != self.std.shape:
            raise ConfigurationError(
                f"normalizer mean {self.mean.shape} and std {self.std.shape} differ in shape"
            )
        if not (np.isfinite(self.mean).all() and np.isfinite(self.std).all()):
            raise ConfigurationError("normalizer mean and std must be finite")
        if (self.std <= 0).any():
            raise ConfigurationError("normalizer std must be > 0")

    @property
    def dim(self) -> int:
        """Number of features."""
        return int(self.mean.size)

    @classmethod
    def fit(cls, frames: np.ndarray) -> FeatureNormalizer:
        """Estimate mean and std over all frames of one speaker.

        Args:
            frames: (n_frames, dim) features, n_frames >= 1.

        Returns:
            The normaliser.

        """
        x = np.asarray(frames, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] == 0:
            raise ValueError(f"frames must be (n_frames >= 1, dim), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise InputError("cannot fit a normalizer to non-finite feature frames")
        return cls(mean=x.mean(axis=0), std=np.maximum(x.std(axis=0), cls.STD_FLOOR))

    def apply(self, frames: np.ndarray) -> np.ndarray:
        """Normalise: (frames - mean) / std.

        Args:
            frames: (..., dim) features.

        Returns:
            (..., dim) float64 normalised features.

        """
        x = np.asarray(frames, dtype=np.float64)
        if x.shape[-1:] != (self.dim,):
            raise ValueError(f"frames must end in dimension {self.dim}, got shape {x.shape}")
        return (x - self.mean) / self.std

    def to_dict(self) -> dict[str, list[float]]:
        """JSON-safe dictionary ``{"mean": [...], "std": [...]}``."""
        return {"mean": self.mean.tolist(), "std": self.std.tolist()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FeatureNormalizer:
        """Rebuild from :meth:`to_dict` output.

        Args:
            data: ``{"mean": [...], "std": [...]}``.

        Returns:
            The normaliser.

        Raises:
            ConfigurationError: missing or unknown keys, or bad values.

        """
        keys = set(data)
        if keys != {"mean", "std"}:
            raise ConfigurationError(
                f"FeatureNormalizer dict needs exactly the keys ['mean', 'std'], got {sorted(keys)}"
            )
        return cls(mean=np.asarray(data["mean"]), std=np.asarray(data["std"]))
