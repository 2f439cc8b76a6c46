"""Guarded audio input: audio_common AudioInfo/AudioData or naoqi AudioBuffer -> 16 kHz mono.

The features node hands every message it receives to an :class:`AudioInput`, which decodes
it with :class:`~audio2pose_ros.audio.pcm.PcmDecoder` (seed 003 section 4.2.2: channels
averaged, resampled to 16 kHz) inside limits that hold whatever a publisher sends:

- the format: the rates, channel counts, sample formats and codings of
  :mod:`audio2pose_ros.audio.pcm` (8 to 192 kHz, 1 to 16 channels, uncompressed PCM);
- per message: at most ``max_chunk_bytes`` bytes and ``max_chunk_s`` seconds of audio, so that
  one message decodes to at most ``max_chunk_s * 16000`` output samples and the resampler's
  temporaries stay a few MiB;
- per second: at most ``max_audio_s_per_s`` seconds of audio per second of wall-clock time
  (a token bucket holding ``max(max_audio_s_per_s, max_chunk_s)`` seconds), so that a flood of
  small messages cannot keep the node busy for longer than real time allows.

Two inputs, chosen by ``input_type``:

- ``audio_common``: audio_common_msgs AudioInfo (the format, latched by audio_capture) and
  AudioData (raw bytes). A rejected AudioInfo stops decoding until a valid one arrives, and
  the reason stays in :attr:`AudioInput.format_problem` until then.
- ``naoqi``: naoqi_bridge_msgs AudioBuffer, as naoqi_driver publishes the robot's microphones
  (48 kHz, 4 interleaved int16 channels, ``channel_map`` naming each channel). Every message
  carries its own format.

``channels`` selects what is averaged: ``mean`` (all channels, the seed's choice), indices of
the interleaved channels (``0`` or ``0,2``), or, for AudioBuffer, names of the channel_map
constants (``front_left`` or ``front_left,front_right``). This module does not import rclpy.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.audio.pcm import MAX_CHANNELS, PcmDecoder, PcmFormat
from audio2pose_ros.errors import (
    ConfigurationError,
    InputError,
    InvalidAudio,
    UnsupportedAudioFormat,
    short_repr,
)
from audio2pose_ros.parameters import param, validate_settings
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

__all__ = [
    "INPUT_TYPES",
    "NAOQI_CHANNELS",
    "AudioBudget",
    "AudioDropped",
    "AudioInput",
    "AudioInputSettings",
    "ChannelSelection",
]

INPUT_TYPES: tuple[str, ...] = ("audio_common", "naoqi")

# naoqi_bridge_msgs/AudioBuffer's CHANNEL_* constants, by the lower-case name of the constant.
NAOQI_CHANNELS: dict[str, int] = {
    "front_left": 0,
    "front_center": 1,
    "front_right": 2,
    "rear_left": 3,
    "rear_center": 4,
    "rear_right": 5,
    "surround_left": 6,
    "surround_right": 7,
    "subwoofer": 8,
    "lfe": 9,
}
_NAOQI_NAMES = {code: name for name, code in NAOQI_CHANNELS.items()}


class AudioDropped(InputError):  # noqa: N818 (reads as what happened to the message)
    """A message was dropped: no usable format yet, or a per-message or per-second limit."""


@dataclass(frozen=True)
class ChannelSelection:
    """The channels to average, parsed from the ``channels`` parameter.

    Attributes:
        indices: positions in the interleaved frame (empty when names are used or for all).
        names: naoqi channel names (keys of :data:`NAOQI_CHANNELS`).
    """

    indices: tuple[int, ...] = ()
    names: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str) -> ChannelSelection:
        """Parse ``mean``, ``0,2`` or ``front_left,front_right`` (spaces and case ignored).

        Raises:
            ConfigurationError: the text is none of these; the message names the parameter.
        """
        items = [item.strip().lower() for item in str(text).split(",")]
        if items in (["mean"], ["all"]):
            return cls()
        problem = ""
        if all(item.isdigit() for item in items):
            indices = tuple(int(item) for item in items)
            if max(indices) >= MAX_CHANNELS:
                problem = f"index above {MAX_CHANNELS - 1}"
            selection = cls(indices=indices)
        elif all(item in NAOQI_CHANNELS for item in items):
            selection = cls(names=tuple(items))
        else:
            problem = "not understood"
        if not problem and len(set(items)) != len(items):
            problem = "names a channel twice"
        if problem:
            raise ConfigurationError(
                f"parameter channels: value {short_repr(text)} {problem}; allowed: 'mean', channel "
                f"indices such as '0' or '0,2', or AudioBuffer channel names such as "
                f"'front_left,front_right' (names: {', '.join(NAOQI_CHANNELS)})"
            )
        return selection

    def resolve(self, n_channels: int, channel_map: Sequence[int] = ()) -> tuple[int, ...] | None:
        """Positions to average in frames of ``n_channels`` channels; None for all of them.

        Args:
            n_channels: channels of the incoming audio.
            channel_map: AudioBuffer's ``channel_map`` (the CHANNEL_* constant of each
                position), needed for names.

        Raises:
            UnsupportedAudioFormat: an index or name does not exist in this audio.
        """
        if self.names:
            positions = tuple(
                i for i, code in enumerate(channel_map) if _NAOQI_NAMES.get(code) in self.names
            )
            found = {_NAOQI_NAMES[channel_map[i]] for i in positions}
            missing = [name for name in self.names if name not in found]
            if missing:
                have = [_NAOQI_NAMES.get(code, str(code)) for code in channel_map]
                raise UnsupportedAudioFormat(
                    f"channels {list(missing)} not in this audio's channel_map {have}"
                )
            return positions
        if not self.indices:
            return None
        if max(self.indices) >= n_channels:
            raise UnsupportedAudioFormat(
                f"channels {list(self.indices)} selected but the audio has {n_channels} "
                f"channel(s) (indices 0..{n_channels - 1})"
            )
        return self.indices

    def describe(self) -> str:
        """The selection in words, for diagnostics."""
        if self.names:
            return "mean of " + ", ".join(self.names)
        if self.indices:
            return "mean of channel(s) " + ", ".join(str(i) for i in self.indices)
        return "mean of all channels"


@dataclass(frozen=True)
class AudioInputSettings:
    """Settings of :class:`AudioInput`; each field is a parameter of audio_features_node."""

    input_type: str = field(
        default="audio_common",
        metadata=param(
            "audio input: 'audio_common' (audio_common_msgs AudioData on audio/audio and "
            "AudioInfo on audio/audio_info) or 'naoqi' (naoqi_bridge_msgs AudioBuffer on "
            "audio/audio, as naoqi_driver publishes the robot's microphones)",
            choices=INPUT_TYPES,
            read_only=True,
        ),
    )
    channels: str = field(
        default="mean",
        metadata=param(
            "channels averaged into the mono signal: 'mean' (all), indices such as '0' or "
            "'0,2', or AudioBuffer channel names such as 'front_left,front_right'"
        ),
    )
    max_chunk_bytes: int = field(
        default=1 << 20,
        metadata=param(
            "largest audio message decoded; larger ones are dropped and counted",
            minimum=64,
            maximum=1 << 26,
            unit="bytes",
        ),
    )
    max_chunk_s: float = field(
        default=2.0,
        metadata=param(
            "longest audio message decoded (its duration at its own rate); longer ones are "
            "dropped and counted",
            minimum=0.01,
            maximum=60.0,
            unit="s",
        ),
    )
    max_audio_s_per_s: float = field(
        default=8.0,
        metadata=param(
            "seconds of audio decoded per second of wall-clock time at most (replay at up to "
            "8x real time passes); audio beyond it is dropped and counted",
            minimum=1.0,
            maximum=100.0,
            unit="s/s",
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field; channel names need the naoqi input."""
        validate_settings(self)
        selection = ChannelSelection.parse(self.channels)
        if selection.names and self.input_type != "naoqi":
            raise ConfigurationError(
                f"parameter channels: value {self.channels!r} names channels, which only "
                "AudioBuffer carries; allowed with input_type 'audio_common': 'mean' or "
                "indices such as '0,1'"
            )

    @property
    def selection(self) -> ChannelSelection:
        """The parsed ``channels``."""
        return ChannelSelection.parse(self.channels)


class AudioBudget:
    """Token bucket in seconds of audio: refills at ``rate_s_per_s``, holds ``capacity_s``.

    Args:
        rate_s_per_s: seconds of audio allowed per second of clock time.
        capacity_s: the most that can be taken at once after a pause.
        clock: monotonic clock in seconds (``time.monotonic`` by default; tests pass a fake).
    """

    def __init__(
        self,
        rate_s_per_s: float,
        capacity_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.rate_s_per_s = float(rate_s_per_s)
        self.capacity_s = float(capacity_s)
        self._clock = clock
        self._tokens = self.capacity_s
        self._last = clock()

    def take(self, seconds: float) -> bool:
        """Take ``seconds`` of audio from the bucket; False (nothing taken) when it lacks them."""
        now = self._clock()
        elapsed = max(0.0, now - self._last)
        self._last = now
        self._tokens = min(self.capacity_s, self._tokens + elapsed * self.rate_s_per_s)
        if seconds > self._tokens:
            return False
        self._tokens -= seconds
        return True


class AudioInput:
    """Decode audio messages to 16 kHz mono float32 within the limits of the module docstring.

    Every ``decode_*`` method returns the samples that became available, or raises an
    :class:`~audio2pose_ros.errors.InputError` (:class:`AudioDropped`,
    :class:`~audio2pose_ros.errors.UnsupportedAudioFormat` or
    :class:`~audio2pose_ros.errors.InvalidAudio`) saying why the message was dropped; the
    input stays usable either way.

    Args:
        settings: limits, input type and channel selection.
        target_rate_hz: output rate (Hz, default 16000, seed 003 section 4.2.2).
        clock: monotonic clock for the per-second budget (seconds).

    Attributes:
        format: the format being decoded, or None.
        format_problem: why there is no format ('' while there is one).
        info_rejected: True from a refused AudioInfo until a valid one arrives (the stream's
            declared format is unusable: a state, not a passing event).
        format_changes: formats adopted so far.
        chunks: messages received; dropped_chunks, dropped_bytes: those dropped.
    """

    def __init__(
        self,
        settings: AudioInputSettings,
        target_rate_hz: int = SAMPLE_RATE_HZ,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.settings = settings
        self.target_rate_hz = int(target_rate_hz)
        self._clock = clock
        self._budget = self._make_budget()
        self._decoder: PcmDecoder | None = None
        self._channel_map: tuple[int, ...] = ()
        self.format: PcmFormat | None = None
        self.format_problem = (
            "no usable AudioInfo received yet on audio/audio_info"
            if settings.input_type == "audio_common"
            else "no AudioBuffer received yet on audio/audio"
        )
        self.info_rejected = False
        self.format_changes = 0
        # an AudioBuffer format adopted but no message of it decoded yet: the next decoded one
        # says the stream restarted, even when the message that brought the format was dropped
        self._buffer_restart = False
        self.chunks = 0
        self._chunks_in_call = 1  # messages in the payload being decoded
        self.dropped_chunks = 0
        self.dropped_bytes = 0

    def _make_budget(self) -> AudioBudget:
        capacity = max(self.settings.max_audio_s_per_s, self.settings.max_chunk_s)
        return AudioBudget(self.settings.max_audio_s_per_s, capacity, self._clock)

    @property
    def channels_used(self) -> tuple[int, ...] | None:
        """Positions averaged in the current format (None: all, or no format)."""
        return None if self._decoder is None else self._decoder.channels

    def update_settings(self, settings: AudioInputSettings) -> None:
        """Apply new limits or channels from the next message on (input_type cannot change).

        Raises:
            ConfigurationError: ``input_type`` differs from the running one, or the new
                channels do not exist in the audio being decoded (nothing is changed then).
        """
        if settings.input_type != self.settings.input_type:
            raise ConfigurationError("parameter input_type cannot change while the node runs")
        decoder = self._decoder
        if settings.channels != self.settings.channels and self.format is not None:
            try:
                channels = settings.selection.resolve(self.format.channels, self._channel_map)
            except UnsupportedAudioFormat as exc:
                raise ConfigurationError(f"parameter channels: {exc}") from None
            decoder = PcmDecoder(self.format, self.target_rate_hz, channels)
        old, self.settings, self._decoder = self.settings, settings, decoder
        if (settings.max_audio_s_per_s, settings.max_chunk_s) != (
            old.max_audio_s_per_s,
            old.max_chunk_s,
        ):
            self._budget = self._make_budget()

    def set_audio_info(
        self, channels: int, sample_rate: int, sample_format: str, coding_format: str
    ) -> bool:
        """Adopt the format of an audio_common_msgs AudioInfo.

        Returns:
            True when the format changed (the stream restarts: reset what follows it).

        Raises:
            UnsupportedAudioFormat: the AudioInfo is refused; audio is dropped until a valid
                AudioInfo arrives and :attr:`format_problem` keeps the reason until then.
        """
        try:
            fmt = PcmFormat.from_audio_info(channels, sample_rate, sample_format, coding_format)
            return self._adopt(fmt, ())
        except UnsupportedAudioFormat as exc:
            self._reject(f"AudioInfo rejected: {exc}")
            self.info_rejected = True
            raise UnsupportedAudioFormat(self.format_problem) from None

    def decode_audio_data(
        self, data: bytes | bytearray | memoryview | Sequence[int], chunks: int = 1
    ) -> np.ndarray:
        """Decode the bytes of one audio_common_msgs AudioData, or of several small ones.

        Args:
            data: the payload of ``chunks`` consecutive messages.
            chunks: how many messages ``data`` holds (a node accumulates tiny chunks and
                decodes them at once); they are counted, and dropped, together.

        Raises:
            AudioDropped: no usable AudioInfo, or the message is over a limit.
            InvalidAudio: the samples are not finite.
        """
        self.chunks += chunks
        self._chunks_in_call = chunks
        self._check_bytes("AudioData", len(data))
        if self._decoder is None:
            raise self._dropped(len(data), AudioDropped(f"audio dropped: {self.format_problem}"))
        return self._decode("AudioData", self._decoder, data, len(data))

    def decode_audio_buffer(
        self, frequency: int, channel_map: Sequence[int], data: Sequence[int] | np.ndarray
    ) -> tuple[np.ndarray, bool]:
        """Decode one naoqi_bridge_msgs AudioBuffer (interleaved int16, ``channel_map`` order).

        Returns:
            ``(samples, format_changed)``: format_changed is True for the first message decoded
            in a frequency or channel map other than the previous decoded message's (the
            stream restarts: reset what follows it), also when the message that brought the
            new format was dropped.

        Raises:
            AudioDropped: the message is over a limit.
            UnsupportedAudioFormat: frequency, channel count or channel selection refused.
            InvalidAudio: the data is not a whole number of frames.
        """
        self.chunks += 1
        self._chunks_in_call = 1
        n_bytes = 2 * len(data)
        self._check_bytes("AudioBuffer", n_bytes)
        channel_map = tuple(int(code) for code in channel_map)
        try:
            if not channel_map:
                raise UnsupportedAudioFormat("AudioBuffer with an empty channel_map")
            fmt = PcmFormat("S16LE", len(channel_map), int(frequency), "wave")
            self._buffer_restart |= self._adopt(fmt, channel_map)
        except UnsupportedAudioFormat as exc:
            self._reject(f"AudioBuffer rejected: {exc}")
            raise self._dropped(n_bytes, UnsupportedAudioFormat(self.format_problem)) from None
        if len(data) % len(channel_map):
            raise self._dropped(
                n_bytes,
                InvalidAudio(
                    f"AudioBuffer dropped: {len(data)} samples are not whole frames of "
                    f"{len(channel_map)} channels"
                ),
            )
        assert self._decoder is not None  # adopted above
        samples = np.asarray(data, dtype="<i2")
        decoded = self._decode("AudioBuffer", self._decoder, samples.tobytes(), n_bytes)
        changed, self._buffer_restart = self._buffer_restart, False
        return decoded, changed

    def _adopt(self, fmt: PcmFormat, channel_map: tuple[int, ...]) -> bool:
        """Switch to ``fmt`` unless already decoding it; True when switched."""
        if fmt == self.format and channel_map == self._channel_map:
            return False
        channels = self.settings.selection.resolve(fmt.channels, channel_map)
        self._decoder = PcmDecoder(fmt, self.target_rate_hz, channels)
        self.format, self._channel_map, self.format_problem = fmt, channel_map, ""
        self.info_rejected = False
        self.format_changes += 1
        return True

    def _reject(self, reason: str) -> None:
        self._decoder, self.format, self._channel_map = None, None, ()
        self.format_problem = reason

    def _check_bytes(self, kind: str, n_bytes: int) -> None:
        """Refuse a ``kind`` message (AudioData, AudioBuffer) over ``max_chunk_bytes``."""
        if n_bytes > self.settings.max_chunk_bytes:
            raise self._dropped(
                n_bytes,
                AudioDropped(
                    f"dropped an {kind} message of {n_bytes} bytes (max_chunk_bytes "
                    f"{self.settings.max_chunk_bytes})"
                ),
            )

    def _decode(self, kind: str, decoder: PcmDecoder, payload: object, n_bytes: int) -> np.ndarray:
        """Check the duration limits, then decode (the message is counted as dropped if not)."""
        seconds = decoder.frames_in(n_bytes) / decoder.fmt.sample_rate_hz
        if seconds > self.settings.max_chunk_s:
            raise self._dropped(
                n_bytes,
                AudioDropped(
                    f"dropped an {kind} message of {seconds:.3f} s (max_chunk_s "
                    f"{self.settings.max_chunk_s:g})"
                ),
            )
        if not self._budget.take(seconds):
            raise self._dropped(
                n_bytes,
                AudioDropped(
                    f"dropped an {kind} message of {seconds:.3f} s: audio arrives faster than "
                    f"max_audio_s_per_s {self.settings.max_audio_s_per_s:g}"
                ),
            )
        try:
            return decoder.feed(payload)  # type: ignore[arg-type]
        except InvalidAudio as exc:
            raise self._dropped(
                n_bytes, InvalidAudio(f"dropped an audio chunk ({kind}): {exc}")
            ) from None

    def _dropped(self, n_bytes: int, error: InputError) -> InputError:
        """Count a dropped message of ``n_bytes``; return ``error`` for the caller to raise."""
        self.dropped_chunks += self._chunks_in_call
        self.dropped_bytes += n_bytes
        return error
