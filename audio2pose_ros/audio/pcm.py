"""Decoding raw PCM audio (audio_common_msgs AudioData as AudioInfo describes it) to 16 kHz mono.

Seed 003 section 4.2.2: "The stereo audio signal was first averaged to a single channel and
downsampled to f_s = 16 kHz". :class:`PcmDecoder` does exactly that on a byte stream that
arrives in arbitrary pieces (ROS messages, odd byte counts, single bytes): it keeps the bytes of
an incomplete frame, averages the channels and resamples any input rate to the target rate with
a streaming polyphase FIR (:mod:`~audio2pose_ros.audio.resample`) whose state is carried
across calls, so that feeding a signal in chunks gives the same samples as feeding it whole.
WAV files are read by :mod:`~audio2pose_ros.audio.wav` with the same decoder.

Samples are float32 in the nominal range [-1, 1): integer formats are scaled by their full
scale (S16LE by 2**15, S32LE by 2**31, U8 by 2**7 around 128); the decoder's output is clipped
to [-1, 1) so float input and filter overshoot cannot leave it.

Limits (what an AudioInfo, a WAV header or an AudioBuffer may claim):

- sample rates :data:`MIN_SAMPLE_RATE_HZ` .. :data:`MAX_SAMPLE_RATE_HZ` (8 kHz, the lowest
  telephony rate, to 192 kHz, the highest rate of USB Audio Class 2 interfaces and of ALSA's
  common hardware). Above 16 kHz the features only see the band below 8 kHz anyway; below
  8 kHz the upper mel bands would be empty. At the target rate of 16 kHz one input sample gives
  at most two output samples, so the output of a message is bounded by its size;
- the resampling filter has at most
  :data:`~audio2pose_ros.audio.resample.MAX_FILTER_TAPS` coefficients (4 MiB). Every
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

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.audio.resample import PolyphaseResampler
from audio2pose_ros.errors import InvalidAudio, UnsupportedAudioFormat, short_repr
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

SUPPORTED_SAMPLE_FORMATS: tuple[str, ...] = ("S16LE", "S32LE", "F32LE", "U8")
SUPPORTED_CODING_FORMATS: tuple[str, ...] = ("wave", "")
MIN_SAMPLE_RATE_HZ = 8000  # lowest accepted input rate (telephony)
MAX_SAMPLE_RATE_HZ = 192000  # highest accepted input rate (USB Audio Class 2, ALSA hardware)
MAX_CHANNELS = 16  # interleaved channels accepted (Pepper: 4, microphone arrays: 4 to 8)

# numpy dtype and bytes per sample of each supported sample format (all little-endian).
_DTYPES: dict[str, np.dtype] = {
    "S16LE": np.dtype("<i2"),
    "S32LE": np.dtype("<i4"),
    "F32LE": np.dtype("<f4"),
    "U8": np.dtype("u1"),
}

# Largest float32 below 1.0: the decoder's output is clipped to [-1, _MAX_SAMPLE].
_MAX_SAMPLE = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
_S16_SCALE = np.float32(1.0 / 32768.0)  # S16LE full scale; every int16 / 2^15 lies in [-1, 1)


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
        # the real-time common case: nothing to average, resample or clip (in range by type)
        self._direct = (
            fmt.sample_format == "S16LE" and fmt.channels == 1 and self._resampler.passthrough
        )

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
        if self._direct:  # S16LE mono at the target rate: int16 / 2^15 is exact in float32
            return raw.astype(np.float32) * _S16_SCALE
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
