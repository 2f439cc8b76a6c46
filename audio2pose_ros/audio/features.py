"""Log filter-bank and MFCC audio features, offline and streaming (seed 003 section 3.2).

The computation follows seed 003 section 3.2, steps 1-8, with the settings of section 4.2.2
(alpha = 0.97, w = 25 ms, s = 10 ms, N_FFT = 512, N_filt = 26, N_Delta = 2):

1. pre-emphasis y(t) = x(t) - alpha x(t - 1/f_s) (eq. 3.1), the first sample kept as is;
2. framing into ``frame_len``-sample frames every ``frame_step`` samples, the last frame
   zero-padded;
3. windowing: rectangular (no window) by default, as python_speech_features' default ``winfunc``
   that the seed used, or the Hamming window of eq. 3.2;
4. power spectrum ``P = |FFT(y_i)|^2 / N_FFT`` (eq. 3.3);
5. triangular mel filters (eq. 3.4), logarithm -> LogFB;
6. DCT-II (orthonormal), first ``numcep`` coefficients, sinusoidal lifter, coefficient 0
   replaced by the log frame energy -> MFCC;
7. deltas (eq. 3.5) of order 1 (LogFB-52) or 1 and 2 (LogFB-78);
8. per-speaker z-normalisation (:class:`~audio2pose_ros.audio.normalize.FeatureNormalizer`).

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
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from audio2pose_ros.audio.dsp import (
    LOG_FLOOR,
    dct_matrix,
    delta,
    direct_rfft,
    hamming_window,
    lifter_weights,
    mel_filterbank,
    preemphasis,
    round_half_up,
)
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.timebase import FRAME_PERIOD_S, SAMPLE_RATE_HZ, WINDOW_S

_BLOCK_FRAMES = 4096  # frames per vectorised block in extract_features

KINDS: tuple[str, ...] = ("logfbank", "mfcc")
WINDOWS: tuple[str, ...] = ("rectangular", "hamming")


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
    def label(self) -> str:
        """Name of the feature set in a features message (``logfbank26``, ``mfcc13``)."""
        return f"{self.kind}{self.dim}"

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


class FrameKernel:
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
        self.rfft = direct_rfft(spec.nfft, spec.frame_len)
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
        energies[energies == 0.0] = LOG_FLOOR  # as python_speech_features: avoid log(0)
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
        np.copyto(energies, LOG_FLOOR, where=np.equal(energies, 0.0, out=self.zero))
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
    y = preemphasis(x, spec.preemph)
    padded_len = (n_frames - 1) * spec.frame_step + spec.frame_len
    y = np.concatenate([y, np.zeros(max(0, padded_len - y.size))])
    frames = np.lib.stride_tricks.sliding_window_view(y, spec.frame_len)[:: spec.frame_step]
    kernel = FrameKernel(spec)
    base = np.empty((n_frames, spec.base_dim))
    for i in range(0, n_frames, _BLOCK_FRAMES):  # blocks bound the FFT's temporary memory
        base[i : i + _BLOCK_FRAMES] = kernel(frames[i : min(i + _BLOCK_FRAMES, n_frames)])
    return _with_deltas(base, spec)
