"""Decoding raw PCM audio (audio_common_msgs AudioData as AudioInfo describes it) to 16 kHz mono.

Seed 003 section 4.2.2: "The stereo audio signal was first averaged to a single channel and
downsampled to f_s = 16 kHz". :class:`PcmDecoder` does exactly that on a byte stream that
arrives in arbitrary pieces (ROS messages, odd byte counts, single bytes): it keeps the bytes of
an incomplete frame, averages the channels and resamples any input rate to the target rate with
a streaming polyphase FIR whose state is carried across calls, so that feeding a signal in
chunks gives the same samples as feeding it whole.

Samples are float32 in the nominal range [-1, 1): integer formats are scaled by their full
scale (S16LE by 2**15, S32LE by 2**31, U8 by 2**7 around 128); the decoder's output is clipped
to [-1, 1) so float input and filter overshoot cannot leave it.

The module is ROS-free: callers pass AudioInfo's fields to :meth:`PcmFormat.from_audio_info`
and AudioData's ``data`` (anything bytes-like) to :meth:`PcmDecoder.feed`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike

import numpy as np

TARGET_RATE_HZ = 16000  # seed 003 section 4.2.2: audio is downsampled to f_s = 16 kHz

SUPPORTED_SAMPLE_FORMATS: tuple[str, ...] = ("S16LE", "S32LE", "F32LE", "U8")
SUPPORTED_CODING_FORMATS: tuple[str, ...] = ("wave", "")
SUPPORTED_CHANNELS: tuple[int, ...] = (1, 2)
MAX_SAMPLE_RATE_HZ = 384000

# numpy dtype and bytes per sample of each supported sample format (all little-endian).
_DTYPES: dict[str, np.dtype] = {
    "S16LE": np.dtype("<i2"),
    "S32LE": np.dtype("<i4"),
    "F32LE": np.dtype("<f4"),
    "U8": np.dtype("u1"),
}

# Largest float32 below 1.0: the decoder's output is clipped to [-1, _MAX_SAMPLE].
_MAX_SAMPLE = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


class UnsupportedAudioFormat(ValueError):  # noqa: N818 (name fixed by the node API)
    """An AudioInfo field names a format this decoder cannot handle."""


class InvalidAudio(ValueError):  # noqa: N818 (name fixed by the node API)
    """Audio data that cannot be decoded as samples (for example NaN or inf in F32LE)."""


@dataclass(frozen=True)
class PcmFormat:
    """Layout of interleaved little-endian PCM bytes (the fields of audio_common_msgs AudioInfo).

    Attributes:
        sample_format: one of :data:`SUPPORTED_SAMPLE_FORMATS` (case-insensitive, stored upper
            case; default ``"S16LE"``).
        channels: number of interleaved channels, 1 or 2 (default 1).
        sample_rate_hz: frames per second (Hz, default 16000).
        coding_format: ``"wave"`` or ``""`` (raw PCM; case-insensitive, stored lower case;
            default ``"wave"``). Compressed codings such as ``"mp3"`` are rejected.

    Raises:
        UnsupportedAudioFormat: a field has a value outside the supported ones; the message
            names the field, its value and the supported values.

    """

    sample_format: str = "S16LE"
    channels: int = 1
    sample_rate_hz: int = TARGET_RATE_HZ
    coding_format: str = "wave"

    def __post_init__(self) -> None:
        """Normalise the case of the string fields and reject unsupported values."""
        sample_format = str(self.sample_format).strip().upper()
        coding_format = str(self.coding_format).strip().lower()
        if sample_format not in SUPPORTED_SAMPLE_FORMATS:
            raise UnsupportedAudioFormat(
                f"unsupported sample_format {self.sample_format!r}; "
                f"supported: {', '.join(SUPPORTED_SAMPLE_FORMATS)}"
            )
        if coding_format not in SUPPORTED_CODING_FORMATS:
            raise UnsupportedAudioFormat(
                f"unsupported coding_format {self.coding_format!r}; supported: 'wave' "
                "(uncompressed PCM) or '' (raw PCM)"
            )
        if isinstance(self.channels, bool) or self.channels not in SUPPORTED_CHANNELS:
            raise UnsupportedAudioFormat(
                f"unsupported channels {self.channels!r}; supported: 1 (mono) or 2 (stereo)"
            )
        rate = self.sample_rate_hz
        if (
            isinstance(rate, bool)
            or not isinstance(rate, (int, np.integer))
            or not 0 < rate <= MAX_SAMPLE_RATE_HZ
        ):
            raise UnsupportedAudioFormat(
                f"unsupported sample_rate {rate!r}; supported: integer Hz in "
                f"1..{MAX_SAMPLE_RATE_HZ}"
            )
        object.__setattr__(self, "sample_format", sample_format)
        object.__setattr__(self, "coding_format", coding_format)
        object.__setattr__(self, "channels", int(self.channels))
        object.__setattr__(self, "sample_rate_hz", int(rate))

    @classmethod
    def from_audio_info(
        cls,
        channels: int,
        sample_rate: int,
        sample_format: str,
        coding_format: str = "wave",
    ) -> PcmFormat:
        """Build a format from the fields of an audio_common_msgs/AudioInfo message.

        Args:
            channels: ``AudioInfo.channels`` (1 or 2).
            sample_rate: ``AudioInfo.sample_rate`` (Hz).
            sample_format: ``AudioInfo.sample_format`` (e.g. ``"S16LE"``).
            coding_format: ``AudioInfo.coding_format`` (``"wave"``/``"WAVE"`` or ``""``).

        Returns:
            The validated format.

        Raises:
            UnsupportedAudioFormat: a field is not supported (the message says which).

        """
        return cls(
            sample_format=sample_format,
            channels=channels,
            sample_rate_hz=sample_rate,
            coding_format=coding_format,
        )

    def audio_info_fields(self) -> dict[str, int | str]:
        """The fields of an audio_common_msgs/AudioInfo describing this format.

        The inverse of :meth:`from_audio_info`; ``bitrate`` is that of uncompressed PCM.
        """
        return {
            "channels": self.channels,
            "sample_rate": self.sample_rate_hz,
            "sample_format": self.sample_format,
            "bitrate": self.sample_rate_hz * self.frame_bytes * 8,
            "coding_format": self.coding_format,
        }

    @property
    def dtype(self) -> np.dtype:
        """Numpy dtype of one sample of one channel."""
        return _DTYPES[self.sample_format]

    @property
    def bytes_per_sample(self) -> int:
        """Bytes of one sample of one channel."""
        return self.dtype.itemsize

    @property
    def frame_bytes(self) -> int:
        """Bytes of one frame (one sample of every channel)."""
        return self.bytes_per_sample * self.channels


S16LE_MONO_16K = PcmFormat()  # audio_capture's default: S16LE, mono, 16 kHz, wave


def _as_bytes(data: object) -> bytes:
    """Bytes of a bytes-like object (bytes, bytearray, memoryview, array.array, list of ints)."""
    if isinstance(data, bytes):
        return data
    try:
        return memoryview(data).tobytes()  # type: ignore[arg-type]
    except TypeError:
        return bytes(data)  # type: ignore[call-overload]


def _to_float(raw: np.ndarray, sample_format: str) -> np.ndarray:
    """Scale integer or float samples to float64 in the nominal range [-1, 1)."""
    if sample_format == "S16LE":
        return raw.astype(np.float64) * (1.0 / 32768.0)
    if sample_format == "S32LE":
        return raw.astype(np.float64) * (1.0 / 2147483648.0)
    if sample_format == "U8":
        return (raw.astype(np.float64) - 128.0) * (1.0 / 128.0)
    return raw.astype(np.float64)


class PolyphaseResampler:
    """Streaming rational-ratio resampler (polyphase Kaiser-windowed-sinc FIR, delay-compensated).

    The ratio ``out_rate_hz / in_rate_hz`` is reduced to ``up / down``. A linear-phase low-pass
    of ``2 * delay_samples * down + 1`` taps at the rate ``in_rate_hz * up`` (cut-off 0.96 of the
    lower Nyquist frequency, Kaiser beta 8, about 80 dB stop-band) is applied in polyphase form.
    The output is delay-compensated: output sample ``m`` is the signal at time
    ``m / out_rate_hz``. Because of that an output sample is only produced once the input
    ``delay_samples`` output periods later has arrived; :meth:`flush` produces the tail (input
    beyond the end taken as zeros). Input before the start is taken as zeros.

    A whole signal of ``n`` input samples gives ``ceil(n * up / down)`` output samples from
    :meth:`process` plus :meth:`flush`, independent of how it was chunked (to rounding error).

    Args:
        in_rate_hz: input sample rate (Hz).
        out_rate_hz: output sample rate (Hz).

    """

    ZERO_CROSSINGS = 32  # sinc zero crossings per side: sets the filter length and transition
    ROLLOFF = 0.96  # cut-off as a fraction of the lower of the two Nyquist frequencies
    KAISER_BETA = 8.0  # about 80 dB stop-band attenuation
    BLOCK = 4096  # outputs computed per vectorised block (bounds temporary memory)

    def __init__(self, in_rate_hz: int, out_rate_hz: int) -> None:
        if in_rate_hz <= 0 or out_rate_hz <= 0:
            raise ValueError(f"rates must be positive, got {in_rate_hz} -> {out_rate_hz} Hz")
        g = math.gcd(int(in_rate_hz), int(out_rate_hz))
        self.in_rate_hz = int(in_rate_hz)
        self.out_rate_hz = int(out_rate_hz)
        self.up = self.out_rate_hz // g
        self.down = self.in_rate_hz // g
        if self.up == self.down == 1:
            self.delay_samples = 0
            self._poly = np.ones((1, 1))
        else:
            max_rate = max(self.up, self.down)
            self.delay_samples = math.ceil(self.ZERO_CROSSINGS * max_rate / self.down)
            half_len = self.delay_samples * self.down  # group delay in up-rate samples
            taps = np.arange(-half_len, half_len + 1, dtype=np.float64)
            cutoff = self.ROLLOFF * 0.5 / max_rate  # cycles per up-rate sample
            h = 2.0 * cutoff * np.sinc(2.0 * cutoff * taps) * np.kaiser(taps.size, self.KAISER_BETA)
            h *= self.up / h.sum()  # unit DC gain after zero-stuffing by `up`
            n_taps = -(-h.size // self.up)
            h = np.concatenate([h, np.zeros(n_taps * self.up - h.size)])
            # _poly[p, j] = h[j * up + p], reversed along j so it pairs with ascending input.
            self._poly = h.reshape(n_taps, self.up).T[:, ::-1].copy()
        self.reset()

    @property
    def passthrough(self) -> bool:
        """True when the rates are equal and samples pass unchanged."""
        return self.up == self.down == 1

    @property
    def taps_per_phase(self) -> int:
        """Input samples that each output sample depends on."""
        return int(self._poly.shape[1])

    def reset(self) -> None:
        """Forget all input: the next sample is the start of a new signal."""
        history = self.taps_per_phase - 1
        self._buf = np.zeros(history)  # input samples, zeros before the signal start
        self._offset = -history  # global input index of _buf[0]
        self._n_in = 0  # input samples received
        self._n_out = 0  # output samples produced

    def _n_available(self, n_in: int) -> int:
        """Count the outputs whose newest input is among the first ``n_in`` input samples."""
        return -(-n_in * self.up // self.down) - self.delay_samples

    def _compute(self, m0: int, m1: int) -> np.ndarray:
        """Output samples ``m0 .. m1 - 1`` from the buffered input."""
        out = np.empty(m1 - m0)
        taps = self.taps_per_phase
        lane = np.arange(taps)
        for b0 in range(m0, m1, self.BLOCK):
            b1 = min(b0 + self.BLOCK, m1)
            k = (np.arange(b0, b1, dtype=np.int64) + self.delay_samples) * self.down
            newest = k // self.up
            phase = k - newest * self.up
            first = newest - (taps - 1) - self._offset
            values = self._buf[first[:, None] + lane[None, :]]
            out[b0 - m0 : b1 - m0] = np.einsum("ij,ij->i", values, self._poly[phase])
        return out

    def _drop_consumed(self) -> None:
        """Discard input no longer needed by the next output sample."""
        k = (self._n_out + self.delay_samples) * self.down
        keep_from = k // self.up - (self.taps_per_phase - 1)
        cut = keep_from - self._offset
        if cut > 0:
            self._buf = self._buf[cut:]
            self._offset += cut

    def process(self, samples: np.ndarray) -> np.ndarray:
        """Resample the next piece of the input.

        Args:
            samples: (n,) input samples at ``in_rate_hz``.

        Returns:
            (k,) float64 output samples at ``out_rate_hz`` that became computable.

        """
        x = np.asarray(samples, dtype=np.float64).reshape(-1)
        if self.passthrough:
            return x.copy()
        if x.size == 0:
            return np.empty(0)
        self._buf = np.concatenate([self._buf, x])
        self._n_in += x.size
        m1 = self._n_available(self._n_in)
        if m1 <= self._n_out:
            return np.empty(0)
        out = self._compute(self._n_out, m1)
        self._n_out = m1
        self._drop_consumed()
        return out

    def flush(self) -> np.ndarray:
        """Produce the remaining output (input after the end taken as zeros) and reset.

        Returns:
            (k,) float64 output samples, so that the total output of the signal is
            ``ceil(n_in * up / down)`` samples.

        """
        if self.passthrough:
            return np.empty(0)
        total = -(-self._n_in * self.up // self.down)
        out = np.empty(0)
        if total > self._n_out:
            newest = ((total - 1 + self.delay_samples) * self.down) // self.up
            missing = newest + 1 - (self._offset + self._buf.size)
            if missing > 0:
                self._buf = np.concatenate([self._buf, np.zeros(missing)])
            out = self._compute(self._n_out, total)
        self.reset()
        return out


class PcmDecoder:
    """Streaming decoder: interleaved PCM bytes -> float32 mono samples at the target rate.

    Implements seed 003 section 4.2.2 (channel averaging, resampling to 16 kHz) for audio that
    arrives in pieces. Bytes of an incomplete frame are kept for the next :meth:`feed`. At the
    target rate the samples pass through unchanged; otherwise a :class:`PolyphaseResampler`
    introduces :attr:`latency_samples` output samples of latency (the output itself is
    delay-compensated, :meth:`flush` emits the last samples).

    Non-finite float samples: a :meth:`feed` whose complete frames contain NaN or inf raises
    :class:`InvalidAudio` and drops all of that call's frames. The sample state (the resampler
    history and everything already output) is unchanged, as if those frames never arrived; the
    bytes are consumed, so the bytes of a trailing incomplete frame are kept and the frame
    alignment of later data is preserved. The caller can log the error and go on feeding.

    Args:
        fmt: the format of the incoming bytes.
        target_rate_hz: output sample rate (Hz, default 16000, seed 003 section 4.2.2).

    """

    def __init__(self, fmt: PcmFormat, target_rate_hz: int = TARGET_RATE_HZ) -> None:
        self._fmt = fmt
        self._target_rate_hz = int(target_rate_hz)
        self._resampler = PolyphaseResampler(fmt.sample_rate_hz, self._target_rate_hz)
        self._pending = b""

    @property
    def fmt(self) -> PcmFormat:
        """Format of the incoming bytes."""
        return self._fmt

    @property
    def target_rate_hz(self) -> int:
        """Output sample rate (Hz)."""
        return self._target_rate_hz

    @property
    def pending_bytes(self) -> int:
        """Bytes of an incomplete frame held back for the next :meth:`feed` (0..frame_bytes-1)."""
        return len(self._pending)

    @property
    def latency_samples(self) -> int:
        """Output samples the resampler holds back (0 when the input is at the target rate)."""
        return self._resampler.delay_samples

    def feed(self, data: bytes | bytearray | memoryview | Sequence[int]) -> np.ndarray:
        """Decode the next piece of the byte stream.

        Args:
            data: bytes-like (bytes, bytearray, memoryview, ``array.array``, list of ints) with
                any number of bytes, including 0 and counts that split a frame.

        Returns:
            (n,) float32 mono samples at :attr:`target_rate_hz`, in [-1, 1); empty when no
            output became available.

        Raises:
            InvalidAudio: the complete frames of this call contain NaN or inf (F32LE). All of
                this call's frames are dropped; see the class docstring for the state kept.

        """
        buf = self._pending + _as_bytes(data)
        frame_bytes = self._fmt.frame_bytes
        usable = len(buf) - len(buf) % frame_bytes
        self._pending = buf[usable:]
        if usable == 0:
            return np.empty(0, dtype=np.float32)
        raw = np.frombuffer(buf, dtype=self._fmt.dtype, count=usable // self._fmt.bytes_per_sample)
        if self._fmt.sample_format == "F32LE" and not np.isfinite(raw).all():
            bad = int(np.count_nonzero(~np.isfinite(raw)))
            raise InvalidAudio(
                f"{bad} non-finite F32LE sample(s) in {usable} bytes; "
                f"dropped {usable // frame_bytes} frame(s), decoder state unchanged"
            )
        samples = _to_float(raw, self._fmt.sample_format)
        if self._fmt.channels > 1:
            samples = samples.reshape(-1, self._fmt.channels).mean(axis=1)
        return self._finish(self._resampler.process(samples))

    def flush(self) -> np.ndarray:
        """End the stream: emit the resampler's held-back samples and reset the decoder.

        The bytes of an incomplete last frame are discarded.

        Returns:
            (n,) float32 samples (empty when the input is at the target rate).

        """
        out = self._finish(self._resampler.flush())
        self.reset()
        return out

    def reset(self) -> None:
        """Clear all state (pending bytes and resampler history)."""
        self._pending = b""
        self._resampler.reset()

    @staticmethod
    def _finish(samples: np.ndarray) -> np.ndarray:
        """Clip to [-1, 1) and convert to float32."""
        return np.clip(samples, -1.0, _MAX_SAMPLE).astype(np.float32)


def encode_pcm(samples: np.ndarray, fmt: PcmFormat) -> bytes:
    """Encode float samples as interleaved PCM bytes (inverse of :class:`PcmDecoder` at one rate).

    No resampling is done: ``samples`` must already be at ``fmt.sample_rate_hz``. Values are
    scaled by the format's full scale, rounded to nearest and saturated (integer formats).

    Args:
        samples: (n,) mono samples, written to every channel, or (n, fmt.channels) samples;
            nominal range [-1, 1).
        fmt: output format.

    Returns:
        ``n * fmt.frame_bytes`` bytes.

    Raises:
        InvalidAudio: ``samples`` contains NaN or inf.
        ValueError: ``samples`` has the wrong shape.

    """
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim == 1:
        x = np.repeat(x[:, None], fmt.channels, axis=1)
    if x.ndim != 2 or x.shape[1] != fmt.channels:
        raise ValueError(
            f"samples must have shape (n,) or (n, {fmt.channels}), got {np.shape(samples)}"
        )
    if not np.isfinite(x).all():
        raise InvalidAudio("cannot encode non-finite samples")
    if fmt.sample_format == "S16LE":
        out = np.clip(np.rint(x * 32768.0), -32768, 32767)
    elif fmt.sample_format == "S32LE":
        out = np.clip(np.rint(x * 2147483648.0), -2147483648, 2147483647)
    elif fmt.sample_format == "U8":
        out = np.clip(np.rint(x * 128.0) + 128.0, 0, 255)
    else:
        out = x
    return out.astype(fmt.dtype).tobytes()


def read_wav(
    path: str | PathLike[str], target_rate_hz: int = TARGET_RATE_HZ
) -> tuple[np.ndarray, int]:
    """Read a WAV file as float32 mono at the target rate (seed 003 section 4.2.2).

    The file is decoded by :class:`PcmDecoder` (same scaling, channel averaging and resampler
    as the streaming path) and flushed, so the result is delay-compensated and has
    ``ceil(n * target_rate_hz / original_rate)`` samples. 8-, 16-, 24- and 32-bit integer and
    32/64-bit float WAVs are read; more than two channels are averaged first.

    Args:
        path: WAV file.
        target_rate_hz: output sample rate (Hz, default 16000).

    Returns:
        ``(samples, original_rate)``: (n,) float32 samples in [-1, 1) and the file's rate (Hz).

    Raises:
        UnsupportedAudioFormat: the WAV sample type is not supported.
        InvalidAudio: the file holds NaN or inf samples.

    """
    from scipy.io import wavfile  # local import: only needed for files

    rate, data = wavfile.read(path)
    data = np.asarray(data)
    if data.ndim == 1:
        data = data[:, None]
    if data.dtype == np.float64:
        data = data.astype(np.float32)
    kinds = {
        np.dtype(np.uint8): "U8",
        np.dtype(np.int16): "S16LE",
        np.dtype(np.int32): "S32LE",  # scipy left-aligns 24-bit samples in int32
        np.dtype(np.float32): "F32LE",
    }
    sample_format = kinds.get(np.dtype(data.dtype).newbyteorder("="))
    if sample_format is None:
        raise UnsupportedAudioFormat(
            f"unsupported WAV sample type {data.dtype} in {path}; supported: 8/16/24/32-bit "
            "integer, 32/64-bit float"
        )
    if data.shape[1] > 2:
        mono = _to_float(data, sample_format).mean(axis=1).astype(np.float32)
        data, sample_format = mono[:, None], "F32LE"
    fmt = PcmFormat(sample_format, data.shape[1], int(rate), "wave")
    decoder = PcmDecoder(fmt, target_rate_hz)
    payload = np.ascontiguousarray(data, dtype=fmt.dtype).tobytes()
    samples = np.concatenate([decoder.feed(payload), decoder.flush()])
    return samples, int(rate)
