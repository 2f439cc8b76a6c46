"""What a browser may send the console, checked before anything acts on it, and what it is sent.

Two kinds of WebSocket frames come from the page:

- **Binary: one audio chunk.** A 16-byte header, little-endian: the magic ``A2PA``, a uint32
  sequence number, a float64 stamp (ms since the Unix epoch, on the console's clock: the page
  corrects its own by the offset its pings measure), then 16 kHz mono S16LE samples, a whole
  number of them, at most ``max_browser_chunk_s`` long (:func:`parse_audio_frame`). The page
  sends 20 ms (320 samples).
- **Text: one control message**, a JSON object of at most :data:`MAX_TEXT_BYTES` whose ``type``
  says what it is and whose fields are exactly those of :data:`CONTROL_FIELDS`, of the right
  type and range (:func:`parse_control`): ``hello`` (token and display name, the first message),
  ``talk`` (take or release the floor), ``stop`` (emergency stop or release), ``enable``,
  ``gains`` (``head``, ``arms``, ``hip`` in [0, 1]) and ``ping`` (clock offset and round trip).

Anything else raises :class:`ProtocolError` with a one-line reason sent back to the page; the
connection, the graph and the robot carry on. Rates are bounded per connection by the server
(:class:`~audio2pose_ros.audio.source.AudioBudget` for seconds of audio and for messages).
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from typing import Any

from audio2pose_ros.errors import InputError

__all__ = [
    "AUDIO_HEADER",
    "AUDIO_MAGIC",
    "CONTROL_FIELDS",
    "GAIN_GROUPS",
    "MAX_NAME_CHARS",
    "MAX_TEXT_BYTES",
    "AudioFrame",
    "Control",
    "ProtocolError",
    "audio_frame",
    "encode",
    "parse_audio_frame",
    "parse_control",
]

AUDIO_MAGIC = b"A2PA"
AUDIO_HEADER = struct.Struct("<4sId")  # magic, sequence number, stamp (ms since the epoch)
MAX_TEXT_BYTES = 1024  # a control message is a few dozen bytes
MAX_TOKEN_CHARS = 256
MAX_NAME_CHARS = 40
GAIN_GROUPS = ("head", "arms", "hip")  # the filter's head_gain, arms_gain, hip_gain
# Every control message type and its fields: (name, type, required).
CONTROL_FIELDS: dict[str, tuple[tuple[str, type, bool], ...]] = {
    "hello": (("token", str, True), ("name", str, False)),
    "talk": (("on", bool, True),),
    "stop": (("on", bool, True),),
    "enable": (("on", bool, True),),
    "gains": tuple((group, float, False) for group in GAIN_GROUPS),
    "ping": (("t", float, True),),
}


class ProtocolError(InputError):
    """A frame from a browser that the console does not act on (the reason is sent back)."""


@dataclass(frozen=True)
class AudioFrame:
    """One audio chunk from the page.

    Attributes:
        seq: the page's sequence number (wraps at 2**32).
        stamp_ms: when the chunk's last sample was captured (ms since the epoch, console clock).
        pcm: 16 kHz mono S16LE bytes.
    """

    seq: int
    stamp_ms: float
    pcm: bytes

    @property
    def duration_s(self) -> float:
        """Length of the chunk (s)."""
        return len(self.pcm) / 32000.0


@dataclass(frozen=True)
class Control:
    """One checked control message: its type and its fields (only those given)."""

    type: str
    fields: dict[str, Any]


def audio_frame(seq: int, stamp_ms: float, pcm: bytes) -> bytes:
    """The binary frame the page sends for one chunk (for clients other than the page)."""
    return AUDIO_HEADER.pack(AUDIO_MAGIC, seq & 0xFFFFFFFF, stamp_ms) + pcm


def parse_audio_frame(data: bytes, max_pcm_bytes: int) -> AudioFrame:
    """Check and unpack one binary frame.

    Args:
        data: the frame as received.
        max_pcm_bytes: largest PCM payload allowed (``ConsoleSettings.max_chunk_bytes``).

    Raises:
        ProtocolError: too short, wrong magic, a non-finite stamp, an odd or empty payload, or
            one longer than ``max_pcm_bytes``.
    """
    if len(data) < AUDIO_HEADER.size + 2:
        raise ProtocolError(f"audio frame of {len(data)} bytes is shorter than header + 1 sample")
    magic, seq, stamp_ms = AUDIO_HEADER.unpack_from(data)
    if magic != AUDIO_MAGIC:
        raise ProtocolError(f"audio frame with magic {magic!r}, expected {AUDIO_MAGIC!r}")
    if not math.isfinite(stamp_ms):
        raise ProtocolError("audio frame with a non-finite stamp")
    n_pcm = len(data) - AUDIO_HEADER.size
    if n_pcm % 2:
        raise ProtocolError(f"audio frame of {n_pcm} bytes is not whole 16-bit samples")
    if n_pcm > max_pcm_bytes:
        raise ProtocolError(
            f"audio chunk of {n_pcm} bytes ({n_pcm / 32:.0f} ms) is over the limit of "
            f"{max_pcm_bytes} bytes"
        )
    return AudioFrame(seq=seq, stamp_ms=stamp_ms, pcm=bytes(data[AUDIO_HEADER.size :]))


def _field(kind: str, name: str, expected: type, value: object) -> object:
    """``value`` checked against the field's type (and range for gains and names)."""
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ProtocolError(f"{kind}.{name} must be a number, got {type(value).__name__}")
        number = float(value)
        if not math.isfinite(number):
            raise ProtocolError(f"{kind}.{name} must be finite")
        if kind == "gains" and not 0.0 <= number <= 1.0:
            raise ProtocolError(f"gains.{name} must be in [0, 1], got {number:g}")
        return number
    if not isinstance(value, expected):
        raise ProtocolError(
            f"{kind}.{name} must be {expected.__name__}, got {type(value).__name__}"
        )
    if expected is str:
        assert isinstance(value, str)
        limit = MAX_TOKEN_CHARS if name == "token" else MAX_NAME_CHARS
        if len(value) > limit:
            raise ProtocolError(f"{kind}.{name} is longer than {limit} characters")
        if name == "name" and not value.isprintable():
            raise ProtocolError("hello.name must be printable text")
    return value


def parse_control(text: str | bytes) -> Control:
    """Check one text frame and return the message it carries.

    Raises:
        ProtocolError: too long, not JSON, not an object, an unknown type, a missing or unknown
            field, a field of the wrong type, a gain outside [0, 1] or a non-finite number.
    """
    size = len(text.encode("utf-8") if isinstance(text, str) else text)
    if size > MAX_TEXT_BYTES:
        raise ProtocolError(f"message of {size} bytes is over the limit of {MAX_TEXT_BYTES}")
    try:
        message = json.loads(text, parse_constant=_refuse_constant)
    except (ValueError, RecursionError):
        raise ProtocolError("message is not JSON") from None
    if not isinstance(message, dict):
        raise ProtocolError(f"message must be a JSON object, got {type(message).__name__}")
    kind = message.get("type")
    if not isinstance(kind, str) or kind not in CONTROL_FIELDS:
        raise ProtocolError(
            f"unknown message type {str(kind)[:32]!r}; known: {list(CONTROL_FIELDS)}"
        )
    spec = {name: (expected, required) for name, expected, required in CONTROL_FIELDS[kind]}
    unknown = sorted(set(message) - set(spec) - {"type"})
    if unknown:
        raise ProtocolError(f"{kind} has unknown fields {[str(u)[:32] for u in unknown[:4]]}")
    fields: dict[str, Any] = {}
    for name, (expected, required) in spec.items():
        if name not in message:
            if required:
                raise ProtocolError(f"{kind} needs the field {name!r}")
            continue
        fields[name] = _field(kind, name, expected, message[name])
    if kind == "gains" and not fields:
        raise ProtocolError(f"gains needs at least one of {list(GAIN_GROUPS)}")
    return Control(type=kind, fields=fields)


def _refuse_constant(name: str) -> float:
    """JSON's NaN / Infinity extensions are not JSON: refused."""
    raise ValueError(name)


def encode(kind: str, **fields: object) -> str:
    """A message to the page: a JSON object with ``type`` and ``fields`` (finite numbers only)."""
    return json.dumps({"type": kind, **fields}, allow_nan=False, separators=(",", ":"))
