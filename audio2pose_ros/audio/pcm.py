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

Limits (what an AudioInfo, a WAV header or an AudioBuffer may claim):

- sample rates :data:`MIN_SAMPLE_RATE_HZ` .. :data:`MAX_SAMPLE_RATE_HZ` (8 kHz, the lowest
  telephony rate, to 192 kHz, the highest rate of USB Audio Class 2 interfaces and of ALSA's
  common hardware). Above 16 kHz the features only see the band below 8 kHz anyway; below
  8 kHz the upper mel bands would be empty. At the target rate of 16 kHz one input sample gives
  at most two output samples, so the output of a message is bounded by its size;
- the resampling filter has at most :data:`MAX_FILTER_TAPS` coefficients (4 MiB). Every
  standard rate (8000, 11025, 12000, 16000, 22050, 24000, 32000, 44056, 44100, 48000, 64000,
  88200, 96000, 176400, 192000 Hz) fits; a rate such as 47999 Hz, whose ratio to 16 kHz does
  not reduce, would need three million taps and is refused;
- 1 .. :data:`MAX_CHANNELS` interleaved channels (Pepper's head has 4 microphones, common
  microphone arrays 4 to 8);
- uncompressed PCM only: ``coding_format`` ``"wave"`` or ``""`` (audio_capture's default,
  mp3, is refused: start it with ``format:=wave``).

The module is ROS-free: callers pass AudioInfo's fields to :meth:`PcmFormat.from_audio_info`
and AudioData's ``data`` (anything bytes-like) to :meth:`PcmDecoder.feed`.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

SUPPORTED_SAMPLE_FORMATS: tuple[str, ...] = ("S16LE", "S32LE", "F32LE", "U8")
SUPPORTED_CODING_FORMATS: tuple[str, ...] = ("wave", "")
MIN_SAMPLE_RATE_HZ = 8000  # lowest accepted input rate (telephony)
MAX_SAMPLE_RATE_HZ = 192000  # highest accepted input rate (USB Audio Class 2, ALSA hardware)
MAX_CHANNELS = 16  # interleaved channels accepted (Pepper: 4, microphone arrays: 4 to 8)
MAX_FILTER_TAPS = 1 << 19  # resampling filter coefficients (float64: 4 MiB)
_BLOCK_VALUES = 1 << 20  # input values gathered per vectorised resampler block (8 MiB)

# numpy dtype and bytes per sample of each supported sample format (all little-endian).
_DTYPES: dict[str, np.dtype] = {
    "S16LE": np.dtype("<i2"),
    "S32LE": np.dtype("<i4"),
    "F32LE": np.dtype("<f4"),
    "U8": np.dtype("u1"),
}

# Largest float32 below 1.0: the decoder's output is clipped to [-1, _MAX_SAMPLE].
_MAX_SAMPLE = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


class UnsupportedAudioFormat(InputError):  # noqa: N818 (name fixed by the node API)
    """An AudioInfo field or a WAV header names a format this decoder cannot handle."""


class InvalidAudio(InputError):  # noqa: N818 (name fixed by the node API)
    """Audio data that cannot be decoded as samples (NaN or inf in F32LE, a broken WAV file)."""


def short_repr(value: object, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters: a message field may be megabytes long."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


@dataclass(frozen=True)
class PcmFormat:
    """Layout of interleaved little-endian PCM bytes (the fields of audio_common_msgs AudioInfo).

    Attributes:
        sample_format: one of :data:`SUPPORTED_SAMPLE_FORMATS` (case-insensitive, stored upper
            case; default ``"S16LE"``).
        channels: number of interleaved channels, 1 .. :data:`MAX_CHANNELS` (default 1).
        sample_rate_hz: frames per second, integer Hz in :data:`MIN_SAMPLE_RATE_HZ` ..
            :data:`MAX_SAMPLE_RATE_HZ` (default 16000).
        coding_format: ``"wave"`` or ``""`` (raw PCM; case-insensitive, stored lower case;
            default ``"wave"``). Compressed codings such as ``"mp3"`` are rejected.

    Raises:
        UnsupportedAudioFormat: a field has a value outside the supported ones; the message
            names the field, its value and the supported values.

    """

    sample_format: str = "S16LE"
    channels: int = 1
    sample_rate_hz: int = SAMPLE_RATE_HZ
    coding_format: str = "wave"

    def __post_init__(self) -> None:
        """Normalise the case of the string fields and reject unsupported values."""
        sample_format = str(self.sample_format).strip().upper()
        coding_format = str(self.coding_format).strip().lower()
        if sample_format not in SUPPORTED_SAMPLE_FORMATS:
            raise UnsupportedAudioFormat(
                f"unsupported sample_format {short_repr(self.sample_format)}; "
                f"supported: {', '.join(SUPPORTED_SAMPLE_FORMATS)}"
            )
        if coding_format not in SUPPORTED_CODING_FORMATS:
            raise UnsupportedAudioFormat(
                f"unsupported coding_format {short_repr(self.coding_format)}; supported: 'wave' "
                "(uncompressed PCM) or '' (raw PCM)"
            )
        channels = self.channels
        if (
            isinstance(channels, bool)
            or not isinstance(channels, int | np.integer)
            or not 1 <= channels <= MAX_CHANNELS
        ):
            raise UnsupportedAudioFormat(
                f"unsupported channels {short_repr(channels)}; supported: 1..{MAX_CHANNELS}"
            )
        rate = self.sample_rate_hz
        if (
            isinstance(rate, bool)
            or not isinstance(rate, int | np.integer)
            or not MIN_SAMPLE_RATE_HZ <= rate <= MAX_SAMPLE_RATE_HZ
        ):
            raise UnsupportedAudioFormat(
                f"unsupported sample_rate {short_repr(rate)}; supported: integer Hz in "
                f"{MIN_SAMPLE_RATE_HZ}..{MAX_SAMPLE_RATE_HZ}"
            )
        object.__setattr__(self, "sample_format", sample_format)
        object.__setattr__(self, "coding_format", coding_format)
        object.__setattr__(self, "channels", int(self.channels))
        object.__setattr__(self, "sample_rate_hz", int(rate))

    def __str__(self) -> str:
        """``S16LE, 2 channel(s), 48000 Hz, wave``: the format in one line."""
        coding = self.coding_format or "raw"
        return (
            f"{self.sample_format}, {self.channels} channel(s), {self.sample_rate_hz} Hz, {coding}"
        )

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
            channels: ``AudioInfo.channels`` (1 .. :data:`MAX_CHANNELS`).
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


def resampler_taps(in_rate_hz: int, out_rate_hz: int) -> int:
    """Coefficients of :class:`PolyphaseResampler`'s filter for these rates (1 when equal)."""
    g = math.gcd(int(in_rate_hz), int(out_rate_hz))
    up, down = out_rate_hz // g, in_rate_hz // g
    if up == down == 1:
        return 1
    delay = math.ceil(PolyphaseResampler.ZERO_CROSSINGS * max(up, down) / down)
    return 2 * delay * down + 1


@functools.lru_cache(maxsize=8)
def _polyphase_filter(up: int, down: int) -> tuple[int, np.ndarray]:
    """``(delay_samples, poly)`` of the low-pass for ``up / down`` (read-only, cached).

    Cached because a stream whose format flips between a few rates would otherwise design the
    same filter again for every message.
    """
    max_rate = max(up, down)
    delay_samples = math.ceil(PolyphaseResampler.ZERO_CROSSINGS * max_rate / down)
    half_len = delay_samples * down  # group delay in up-rate samples
    taps = np.arange(-half_len, half_len + 1, dtype=np.float64)
    cutoff = PolyphaseResampler.ROLLOFF * 0.5 / max_rate  # cycles per up-rate sample
    h = 2.0 * cutoff * np.sinc(2.0 * cutoff * taps)
    h *= np.kaiser(taps.size, PolyphaseResampler.KAISER_BETA)
    h *= up / h.sum()  # unit DC gain after zero-stuffing by `up`
    n_taps = -(-h.size // up)
    h = np.concatenate([h, np.zeros(n_taps * up - h.size)])
    # poly[p, j] = h[j * up + p], reversed along j so it pairs with ascending input.
    poly = h.reshape(n_taps, up).T[:, ::-1].copy()
    poly.flags.writeable = False
    return delay_samples, poly


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

    Memory: the filter has at most :data:`MAX_FILTER_TAPS` coefficients, and the temporary
    array of a vectorised block holds at most about :data:`_BLOCK_VALUES` values, whatever the
    size of the input.

    Args:
        in_rate_hz: input sample rate (Hz).
        out_rate_hz: output sample rate (Hz).

    Raises:
        UnsupportedAudioFormat: a rate is not positive, or the filter for this ratio would
            have more than :data:`MAX_FILTER_TAPS` coefficients.

    """

    ZERO_CROSSINGS = 32  # sinc zero crossings per side: sets the filter length and transition
    ROLLOFF = 0.96  # cut-off as a fraction of the lower of the two Nyquist frequencies
    KAISER_BETA = 8.0  # about 80 dB stop-band attenuation

    def __init__(self, in_rate_hz: int, out_rate_hz: int) -> None:
        if in_rate_hz <= 0 or out_rate_hz <= 0:
            raise UnsupportedAudioFormat(
                f"rates must be positive, got {in_rate_hz} -> {out_rate_hz} Hz"
            )
        n_taps = resampler_taps(in_rate_hz, out_rate_hz)
        if n_taps > MAX_FILTER_TAPS:
            raise UnsupportedAudioFormat(
                f"unsupported sample_rate {in_rate_hz}: resampling it to {out_rate_hz} Hz needs "
                f"a {n_taps}-tap filter (at most {MAX_FILTER_TAPS}); use a standard rate such as "
                "16000, 44100 or 48000 Hz"
            )
        g = math.gcd(int(in_rate_hz), int(out_rate_hz))
        self.in_rate_hz = int(in_rate_hz)
        self.out_rate_hz = int(out_rate_hz)
        self.up = self.out_rate_hz // g
        self.down = self.in_rate_hz // g
        if self.up == self.down == 1:
            self.delay_samples = 0
            self._poly = np.ones((1, 1))
        else:
            self.delay_samples, self._poly = _polyphase_filter(self.up, self.down)
        self._block = max(1, _BLOCK_VALUES // self.taps_per_phase)
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
        for b0 in range(m0, m1, self._block):
            b1 = min(b0 + self._block, m1)
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
    Finite F32LE samples are clipped to [-1, 1] before resampling, so that one wild value
    (1e38) cannot ring through the filter into its neighbours.

    Args:
        fmt: the format of the incoming bytes.
        target_rate_hz: output sample rate (Hz, default 16000, seed 003 section 4.2.2).
        channels: indices of the interleaved channels to average (each in
            ``0 .. fmt.channels - 1``, no repeats); None averages all of them (seed 003).

    Raises:
        UnsupportedAudioFormat: a channel index does not exist in ``fmt``, or the resampler
            for ``fmt.sample_rate_hz`` would be too large (see :class:`PolyphaseResampler`).

    """

    def __init__(
        self,
        fmt: PcmFormat,
        target_rate_hz: int = SAMPLE_RATE_HZ,
        channels: Sequence[int] | None = None,
    ) -> None:
        self._fmt = fmt
        self._target_rate_hz = int(target_rate_hz)
        if channels is not None:
            selected = tuple(int(c) for c in channels)
            if not selected or len(set(selected)) != len(selected):
                raise UnsupportedAudioFormat(
                    f"channel selection {list(channels)} must name distinct channels"
                )
            if not all(0 <= c < fmt.channels for c in selected):
                raise UnsupportedAudioFormat(
                    f"channel selection {list(selected)} does not exist in audio with "
                    f"{fmt.channels} channel(s) (indices 0..{fmt.channels - 1})"
                )
            channels = None if selected == tuple(range(fmt.channels)) else selected
        self._channels: tuple[int, ...] | None = channels
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
    def channels(self) -> tuple[int, ...] | None:
        """Indices of the averaged channels, or None when all channels are averaged."""
        return self._channels

    def frames_in(self, n_bytes: int) -> int:
        """Complete frames that a :meth:`feed` of ``n_bytes`` more bytes would decode."""
        return (len(self._pending) + n_bytes) // self._fmt.frame_bytes

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
        if self._fmt.sample_format == "F32LE":
            np.clip(samples, -1.0, 1.0, out=samples)
        if self._fmt.channels > 1:
            frames = samples.reshape(-1, self._fmt.channels)
            if self._channels is not None:
                frames = frames[:, self._channels]
            samples = frames.mean(axis=1)
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


WAV_BLOCK_FRAMES = 1 << 16  # frames decoded per step by read_wav (bounds its temporaries)

_WAVE_FORMAT_PCM = 0x0001
_WAVE_FORMAT_IEEE_FLOAT = 0x0003
_WAVE_FORMAT_EXTENSIBLE = 0xFFFE


@dataclass(frozen=True)
class _WavLayout:
    """The ``fmt `` chunk of a WAV file (fields as the RIFF/WAVE specification names them)."""

    format_tag: int
    channels: int
    sample_rate_hz: int
    block_align: int
    bits_per_sample: int


def _wav_chunks(raw: bytes) -> tuple[_WavLayout, memoryview]:
    """Walk the RIFF chunks of a WAV file held in ``raw``: its ``fmt `` layout and its samples.

    A chunk that claims more bytes than the file holds is cut at the end of the file, so
    nothing larger than the file is ever referenced.

    Raises:
        InvalidAudio: not RIFF/WAVE, or no well-formed ``fmt `` or ``data`` chunk (without
            the path; :func:`read_wav` adds it).

    """
    if len(raw) < 12 or raw[:4] != b"RIFF" or raw[8:12] != b"WAVE":
        raise InvalidAudio(f"not a RIFF/WAVE file ({len(raw)} bytes, starts {raw[:12]!r})")
    view = memoryview(raw)
    layout: _WavLayout | None = None
    data: memoryview | None = None
    pos = 12
    while pos + 8 <= len(raw) and (layout is None or data is None):
        chunk_id, size = raw[pos : pos + 4], struct.unpack_from("<I", raw, pos + 4)[0]
        body = view[pos + 8 : min(pos + 8 + size, len(raw))]
        if chunk_id == b"fmt ":
            if len(body) < 16:
                raise InvalidAudio(f"'fmt ' chunk of {len(body)} bytes (at least 16 needed)")
            tag, channels, rate, _, block_align, bits = struct.unpack_from("<HHIIHH", body)
            if tag == _WAVE_FORMAT_EXTENSIBLE and len(body) >= 26:
                tag = struct.unpack_from("<H", body, 24)[0]  # first field of SubFormat
            layout = _WavLayout(tag, channels, rate, block_align, bits)
        elif chunk_id == b"data":
            data = body
        pos += 8 + size + (size & 1)  # chunks are padded to an even size
    if layout is None:
        raise InvalidAudio("no 'fmt ' chunk")
    if data is None:
        raise InvalidAudio("no 'data' chunk")
    return layout, data


def _wav_samples(layout: _WavLayout, data: memoryview) -> tuple[PcmFormat, np.ndarray]:
    """The PcmFormat of a WAV layout and its (n_frames, channels) samples in that format.

    24-bit samples are left-aligned in int32 (read as S32LE), 64-bit floats become float32.

    Raises:
        UnsupportedAudioFormat: the sample type, channel count or rate is not supported.

    """
    kinds = {
        (_WAVE_FORMAT_PCM, 8): ("U8", "u1"),
        (_WAVE_FORMAT_PCM, 16): ("S16LE", "<i2"),
        (_WAVE_FORMAT_PCM, 24): ("S32LE", "V3"),
        (_WAVE_FORMAT_PCM, 32): ("S32LE", "<i4"),
        (_WAVE_FORMAT_IEEE_FLOAT, 32): ("F32LE", "<f4"),
        (_WAVE_FORMAT_IEEE_FLOAT, 64): ("F32LE", "<f8"),
    }
    kind = kinds.get((layout.format_tag, layout.bits_per_sample))
    if kind is None:
        raise UnsupportedAudioFormat(
            f"unsupported WAV sample type (format tag {layout.format_tag:#06x}, "
            f"{layout.bits_per_sample} bits); supported: 8/16/24/32-bit integer PCM, "
            "32/64-bit float"
        )
    sample_format, stored = kind
    fmt = PcmFormat(sample_format, layout.channels, layout.sample_rate_hz, "wave")
    sample_bytes = np.dtype(stored).itemsize
    if layout.block_align != sample_bytes * layout.channels:
        raise UnsupportedAudioFormat(
            f"block_align {layout.block_align} does not match {layout.channels} channel(s) of "
            f"{layout.bits_per_sample}-bit samples ({sample_bytes * layout.channels} expected)"
        )
    n_frames = len(data) // layout.block_align  # a truncated last frame is dropped
    values = np.frombuffer(data, dtype=stored, count=n_frames * layout.channels)
    if stored == "V3":  # 24-bit: place the three bytes in the top of a little-endian int32
        wide = np.zeros((values.size, 4), dtype=np.uint8)
        wide[:, 1:] = np.frombuffer(values.tobytes(), dtype=np.uint8).reshape(-1, 3)
        values = wide.view("<i4").reshape(-1)
    return fmt, values.astype(fmt.dtype, copy=False).reshape(n_frames, layout.channels)


def read_wav(
    path: str | PathLike[str], target_rate_hz: int = SAMPLE_RATE_HZ
) -> tuple[np.ndarray, int]:
    """Read a WAV file as float32 mono at the target rate (seed 003 section 4.2.2).

    The file is decoded by :class:`PcmDecoder` (same scaling, channel averaging, resampler and
    limits as the streaming path) and flushed, so the result is delay-compensated and has
    ``ceil(n * target_rate_hz / original_rate)`` samples. 8-, 16-, 24- and 32-bit integer and
    32/64-bit float WAVs (WAVE_FORMAT_EXTENSIBLE too) with 1 .. :data:`MAX_CHANNELS` channels
    at :data:`MIN_SAMPLE_RATE_HZ` .. :data:`MAX_SAMPLE_RATE_HZ` are read.

    Memory is bounded by the file's size: the file is read once, chunk sizes that its header
    claims are cut at the end of the file, and the samples are decoded
    :data:`WAV_BLOCK_FRAMES` frames at a time; the result holds at most two float32 samples
    per input frame. Peak use is about three times the file's size plus a few MiB.

    Args:
        path: WAV file.
        target_rate_hz: output sample rate (Hz, default 16000).

    Returns:
        ``(samples, original_rate)``: (n,) float32 samples in [-1, 1) and the file's rate (Hz).

    Raises:
        InputError: the file cannot be read.
        UnsupportedAudioFormat: the WAV's sample type, channel count or rate is not supported.
        InvalidAudio: the file is not a well-formed WAV, holds no samples, or holds NaN or inf.
        Every message starts with the file's path.

    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read WAV file: {exc.strerror or exc}") from None
    try:
        fmt, frames = _wav_samples(*_wav_chunks(raw))
        decoder = PcmDecoder(fmt, target_rate_hz)
        if frames.shape[0] == 0:
            raise InvalidAudio("the WAV file holds no samples")
        pieces = [
            decoder.feed(frames[start : start + WAV_BLOCK_FRAMES].tobytes())
            for start in range(0, frames.shape[0], WAV_BLOCK_FRAMES)
        ]
    except InputError as exc:
        raise type(exc)(f"{path}: {exc}") from None
    pieces.append(decoder.flush())
    return np.concatenate(pieces), fmt.sample_rate_hz
