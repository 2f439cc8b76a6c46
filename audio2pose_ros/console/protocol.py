"""What a browser may send the console, checked before anything acts on it, and what it is sent.

Two kinds of WebSocket frames come from the page:

- **Binary: one audio chunk.** A 16-byte header, little-endian: the magic ``A2PA``, a uint32
  sequence number, a float64 stamp (ms since the Unix epoch, on the console's clock: the page
  corrects its own by the offset its pings measure; within :data:`MAX_STAMP_SKEW_S` of the
  console's clock), then 16 kHz mono S16LE samples, a whole number of them, at most
  ``max_browser_chunk_s`` long (:func:`parse_audio_frame`). The page sends 20 ms (320 samples).
- **Text: one control message**, a JSON object of at most :data:`MAX_TEXT_BYTES` whose ``type``
  says what it is and whose fields are exactly those of :data:`CONTROL_FIELDS`, of the right
  type and range (:func:`parse_control`): ``hello`` (token and display name, the first message),
  ``talk`` (take or release the floor), ``stop`` (emergency stop or release; the release of a
  holder who has left names them in ``confirm``: :mod:`~audio2pose_ros.console.stop`),
  ``enable``, ``mute`` (the operator's voice out of the robot: muted or played; the motion
  goes on either way), ``style_set`` (any of the filter's live style parameters,
  :data:`~audio2pose_ros.motion.style.STYLE_FIELDS`: the size and tempo of each part, where the
  hands rest and how high they go, each within its declared range), ``ping`` (clock offset and
  round trip), ``enroll`` (a ticket to upload a recording of one's style:
  :mod:`~audio2pose_ros.console.enrollment`) and ``style`` (use the learned style, a named
  preset, or go back to the graph's own).
  Every string is text that UTF-8 can encode (JSON can carry lone surrogates, which it
  cannot) and every integer within :data:`MAX_JSON_INT` of zero, so every number is a finite
  float.

Anything else raises :class:`ProtocolError` with a one-line reason sent back to the page; the
connection, the graph and the robot carry on. Rates are bounded per connection by the server
(:class:`~audio2pose_ros.audio.source.AudioBudget` for seconds of audio, audio frames and
messages). What the console sends is made of finite numbers (:func:`encode`,
:func:`json_ready`).
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from typing import Any

from audio2pose_ros.errors import ConfigurationError, InputError, short_repr
from audio2pose_ros.motion.style import STYLE_FIELDS, StyleSettings

__all__ = [
    "AUDIO_HEADER",
    "AUDIO_MAGIC",
    "CONTROL_FIELDS",
    "MAX_JSON_INT",
    "MAX_NAME_CHARS",
    "MAX_STAMP_SKEW_S",
    "MAX_TEXT_BYTES",
    "STYLE_CHOICES",
    "AudioDroppedError",
    "AudioFrame",
    "Control",
    "ProtocolError",
    "audio_frame",
    "encode",
    "json_ready",
    "parse_audio_frame",
    "parse_control",
]

AUDIO_MAGIC = b"A2PA"
AUDIO_HEADER = struct.Struct("<4sId")  # magic, sequence number, stamp (ms since the epoch)
MAX_TEXT_BYTES = 1024  # a control message is a few dozen bytes
MAX_TOKEN_CHARS = 256
MAX_NAME_CHARS = 40
# JavaScript's largest exact integer: the page's numbers are doubles, so no integer it sends is
# larger; beyond it an integer would not even convert to a float (10**400 overflows).
MAX_JSON_INT = 2**53
# A chunk's stamp further than this from the console's clock (either way) cannot be the page's
# corrected clock: its pings measure the offset to within a round trip, and it drops chunks that
# wait in its buffer for more than about a second. What is left is a clock stepped under a
# running page (its offset follows within a few pings) or a client that stamps at random.
MAX_STAMP_SKEW_S = 60.0
# Every control message type and its fields: (name, type, required).
CONTROL_FIELDS: dict[str, tuple[tuple[str, type, bool], ...]] = {
    "hello": (("token", str, True), ("name", str, False)),
    "talk": (("on", bool, True),),
    "stop": (("on", bool, True), ("confirm", str, False)),
    "enable": (("on", bool, True),),
    "mute": (("on", bool, True),),  # the operator's voice out of the robot muted (True) or not
    "style_set": tuple((name, float, False) for name in STYLE_FIELDS),
    "ping": (("t", float, True),),
    "enroll": (("keep", bool, True),),  # ask for a ticket to upload a recording of one's style
    # the learned style ("personal"), the graph's own ("default"), or a preset's name
    "style": (("use", str, True),),
}
STYLE_CHOICES = ("personal", "default")  # besides the presets' names


class ProtocolError(InputError):
    """A frame from a browser that the console does not act on (the reason is sent back)."""


class AudioDroppedError(ProtocolError):
    """An audio chunk dropped and counted that is no fault of the connection, which stays open.

    Audio beyond its rate, or stamped off the console's clock: a page catching up after a
    stall, or whose clock offset is catching up after a clock step, sends such chunks for a
    moment (the server does not count them towards closing the connection).
    """


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


def parse_audio_frame(data: bytes, max_pcm_bytes: int, now_ms: float) -> AudioFrame:
    """Check and unpack one binary frame.

    Args:
        data: the frame as received.
        max_pcm_bytes: largest PCM payload allowed (``ConsoleSettings.max_chunk_bytes``).
        now_ms: the console's clock when the frame arrived (ms since the epoch).

    Raises:
        ProtocolError: too short, wrong magic, a non-finite stamp, an odd or empty payload, or
            one longer than ``max_pcm_bytes``.
        AudioDroppedError: a stamp more than :data:`MAX_STAMP_SKEW_S` from ``now_ms``.
    """
    if len(data) < AUDIO_HEADER.size + 2:
        raise ProtocolError(f"audio frame of {len(data)} bytes is shorter than header + 1 sample")
    magic, seq, stamp_ms = AUDIO_HEADER.unpack_from(data)
    if magic != AUDIO_MAGIC:
        raise ProtocolError(f"audio frame with magic {magic!r}, expected {AUDIO_MAGIC!r}")
    if not math.isfinite(stamp_ms):
        raise ProtocolError("audio frame with a non-finite stamp")
    if not abs(stamp_ms - now_ms) <= MAX_STAMP_SKEW_S * 1e3:
        raise AudioDroppedError(
            f"audio frame stamped {(stamp_ms - now_ms) * 1e-3:+.3g} s from the console's clock "
            f"(at most {MAX_STAMP_SKEW_S:g} s either way): dropped"
        )
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
        number = float(value)  # an int is within MAX_JSON_INT (_parse_int): no OverflowError
        if not math.isfinite(number):
            raise ProtocolError(f"{kind}.{name} must be finite")
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
        try:  # JSON's "\ud800" is a str that no UTF-8 encoder (hmac, logs, replies) accepts
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ProtocolError(f"{kind}.{name} must be valid UTF-8 text") from None
        if name in ("name", "confirm") and not value.isprintable():
            raise ProtocolError(f"{kind}.{name} must be printable text")
        if kind == "style" and not (value in STYLE_CHOICES or value.isidentifier()):
            raise ProtocolError(f"style.use must be one of {list(STYLE_CHOICES)} or a preset")
    return value


def parse_control(text: str | bytes) -> Control:
    """Check one text frame and return the message it carries.

    Raises:
        ProtocolError: too long, not JSON, not an object, an unknown type, a missing or unknown
            field, a field of the wrong type, a string that is not valid UTF-8 text, a style
            value outside its parameter's range, a non-finite number or an integer beyond
            :data:`MAX_JSON_INT`.
    """
    try:
        size = len(text.encode("utf-8") if isinstance(text, str) else text)
    except UnicodeEncodeError:
        raise ProtocolError("message is not valid UTF-8 text") from None
    if size > MAX_TEXT_BYTES:
        raise ProtocolError(f"message of {size} bytes is over the limit of {MAX_TEXT_BYTES}")
    try:
        message = json.loads(text, parse_constant=_refuse_constant, parse_int=_parse_int)
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
    if kind == "style_set":
        if not fields:
            raise ProtocolError(f"style_set needs at least one of {list(STYLE_FIELDS)}")
        try:  # each value against its parameter's declaration (range), the rest as they are
            StyleSettings(**fields)
        except ConfigurationError as exc:
            raise ProtocolError(f"style_set: {exc}") from None
    return Control(type=kind, fields=fields)


def _refuse_constant(name: str) -> float:
    """JSON's NaN / Infinity extensions are not JSON: refused."""
    raise ValueError(name)


def _parse_int(text: str) -> int:
    """A JSON integer, refused beyond :data:`MAX_JSON_INT` whatever field it is in."""
    value = int(text)  # at most MAX_TEXT_BYTES digits: cheap, and below Python's digit limit
    if abs(value) > MAX_JSON_INT:
        raise ProtocolError(
            f"integer {short_repr(text, 24)} is out of range (at most 2**53 in magnitude)"
        )
    return value


def encode(kind: str, **fields: object) -> str:
    """A message to the page: a JSON object with ``type`` and ``fields`` (finite numbers only).

    Raises:
        ValueError: a number is NaN or infinite (:func:`json_ready` replaces them first).
    """
    return json.dumps({"type": kind, **fields}, allow_nan=False, separators=(",", ":"))


def json_ready(value: object) -> tuple[object, list[str]]:
    """``value`` with everything JSON cannot carry replaced by None, and where that was.

    A snapshot for the pages (status, pose) holds statistics and values from other nodes: a NaN,
    an infinity or an object that is not JSON becomes ``null`` in its own field, so one bad
    value never stops the whole message.

    Returns:
        The cleaned copy (dicts, with their keys as text, lists, strings, booleans, integers,
        finite floats, None) and the paths of the values replaced (``latency.p50``,
        ``health[2].level``).
    """
    replaced: list[str] = []

    def clean(item: object, at: str) -> object:
        if item is None or isinstance(item, str | bool | int):
            return item
        if isinstance(item, float) and math.isfinite(item):
            return item
        if isinstance(item, dict):
            return {str(k): clean(v, f"{at}.{k}" if at else str(k)) for k, v in item.items()}
        if isinstance(item, list | tuple):
            return [clean(v, f"{at}[{i}]") for i, v in enumerate(item)]
        replaced.append(at or "(the value)")
        return None

    return clean(value, ""), replaced
