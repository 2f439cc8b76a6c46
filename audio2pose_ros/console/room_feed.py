"""The room back to the operator: the robot's camera as JPEG and its microphones, echo removed.

What the console sends every identified page of what the robot sees and hears, ROS-free:

- **Picture**: :func:`jpeg_from_image` checks a sensor_msgs/Image's fields (``rgb8``, ``bgr8``
  or ``mono8``, as naoqi_driver publishes the front camera) and encodes it as JPEG with Pillow,
  once for every page.
- **Sound**: the microphones (naoqi_bridge_msgs/AudioBuffer, 48 kHz, 4 channels) are averaged
  and resampled to 16 kHz mono by the console's
  :class:`~audio2pose_ros.audio.source.AudioInput`, then :class:`EchoCanceller` removes the
  operator's own voice, which the robot's loudspeaker plays back into the room: the console
  knows that voice (it published it on ``audio/audio``), so each block of the room's sound is
  searched for it within :data:`MAX_ECHO_DELAY_S`, segment by segment (:data:`SEGMENT`: the
  voice node releases the voice in chunks and may skip or hold one back), and the best
  least-squares short filter of the voice at each segment's delay (:data:`ECHO_TAPS` taps: a
  delay between samples, the loudspeaker's gain) is subtracted. The level of what is left
  is sent with it, and the level heard before.
- **Load**: each page has a :class:`RoomOutbox`: the newest picture only (a newer one replaces
  the one not yet sent) and at most :data:`SOUND_DEPTH` blocks of sound (the oldest dropped).
  The server sends one message at a time per page, waiting until the connection has taken it,
  so a page on a slow link gets fewer pictures, never a growing queue, and nothing waits on it.
- **Wire**: :func:`encode_room_message`: the magic ``A2PV`` (picture) or ``A2PS`` (sound), a
  uint32 sequence number, a float64 age (ms since the picture was taken or the sound ended,
  when the message is sent), two float32 levels (dBFS of the sound sent, and of the sound as
  heard before the operator's voice was removed; 0 for a picture), then the JPEG or 16 kHz mono
  S16LE samples; little-endian.
"""

from __future__ import annotations

import io
import math
import struct
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

__all__ = [
    "ECHO_TAPS",
    "MAX_ECHO_DELAY_S",
    "ROOM_HEADER",
    "SOUND_DEPTH",
    "EchoCanceller",
    "RoomItem",
    "RoomOutbox",
    "encode_room_message",
    "jpeg_from_image",
    "level_dbfs",
]

PICTURE_MAGIC = b"A2PV"
SOUND_MAGIC = b"A2PS"
ROOM_HEADER = struct.Struct("<4sIdff")  # magic, sequence, age (ms), levels (dBFS)
JPEG_QUALITY = 70
MAX_IMAGE_PIXELS = 1280 * 960  # larger pictures are refused (a page shows a small view)
ENCODINGS = {"rgb8": 3, "bgr8": 3, "mono8": 1}
SOUND_DEPTH = 6  # blocks of sound kept per page (about 1 s of naoqi_driver's 170 ms buffers)
MAX_ECHO_DELAY_S = 3.0  # voice hold-back + loudspeaker + microphone buffers + transport
SEGMENT = 320  # samples whose echo delay is searched on their own (the voice's 20 ms chunks)
MIN_ECHO_CORRELATION = 0.3  # a segment less alike the voice at any delay has none of it
SPLIT_RESIDUAL = 0.03  # a segment with more than this share left is split in two and retried
MIN_SEGMENT = 40  # samples: segments are not split below this (2.5 ms)
ECHO_TAPS = 8  # the echo filter's length (samples at 16 kHz) around the delay found
REFERENCE_RMS_MIN = 1e-4  # below this the operator is silent: nothing is subtracted
SILENCE_DBFS = -120.0  # the level of digital silence (log of zero)


@dataclass(frozen=True)
class RoomItem:
    """One picture (JPEG) or block of sound (S16LE) for the pages."""

    sound: bool
    sequence: int
    taken_s: float  # wall-clock time the picture was taken or the sound's last sample (s)
    level_dbfs: float  # of the payload
    heard_dbfs: float  # of the sound before the operator's voice was removed
    payload: bytes


def level_dbfs(samples: np.ndarray) -> float:
    """RMS level of float samples (full scale 1) in dBFS; :data:`SILENCE_DBFS` for silence."""
    if samples.size == 0:
        return SILENCE_DBFS
    rms = float(np.sqrt(np.mean(np.square(samples, dtype=np.float64))))
    return max(SILENCE_DBFS, 20.0 * math.log10(rms)) if rms > 0.0 else SILENCE_DBFS


def jpeg_from_image(width: int, height: int, encoding: str, step: int, data: bytes) -> bytes:
    """A sensor_msgs/Image's fields as JPEG bytes.

    Raises:
        InputError: an encoding other than :data:`ENCODINGS`, a size out of range, or data
            that does not hold ``height`` rows of ``step`` bytes.
    """
    channels = ENCODINGS.get(encoding)
    if channels is None:
        raise InputError(f"image encoding {encoding[:32]!r}; supported: {list(ENCODINGS)}")
    if not (width > 0 and height > 0 and width * height <= MAX_IMAGE_PIXELS):
        raise InputError(f"image of {width}x{height} pixels (at most {MAX_IMAGE_PIXELS})")
    if step < width * channels or len(data) < step * height:
        raise InputError(
            f"image {width}x{height} {encoding}: step {step}, {len(data)} bytes do not hold it"
        )
    rows = np.frombuffer(data, dtype=np.uint8, count=step * height).reshape(height, step)
    pixels = rows[:, : width * channels].reshape(height, width, channels)
    if encoding == "bgr8":
        pixels = pixels[:, :, ::-1]
    from PIL import Image

    picture = Image.fromarray(np.ascontiguousarray(pixels.squeeze(axis=2) if channels == 1
                                                   else pixels))  # fmt: skip
    out = io.BytesIO()
    picture.save(out, format="JPEG", quality=JPEG_QUALITY)
    return out.getvalue()


class EchoCanceller:
    """Remove the operator's voice, as the robot's loudspeaker plays it, from the room's sound.

    The voice (``reference``) is kept as published, chunk after chunk, without the pauses
    between: the voice node holds it back, releases it in chunks and may skip one, so what
    matters is the voice itself, not when it was published. A block of the room's sound can
    hold the last :data:`MAX_ECHO_DELAY_S` of it; while none was published for that long, the
    block passes unchanged. :meth:`process` finds, for each
    :data:`SEGMENT` of the block, the delay where the voice best matches it (normalised
    cross-correlation by FFT), fits the :data:`ECHO_TAPS`-tap filter of the voice around that
    delay to the segment by least squares, and subtracts that filtered voice; where more than
    :data:`SPLIT_RESIDUAL` of a segment is left (its delay changed inside it), its halves are
    fitted on their own, down to :data:`MIN_SEGMENT`. A segment that
    matches the voice nowhere (:data:`MIN_ECHO_CORRELATION`) and every block while the operator
    is silent pass unchanged.

    Args:
        rate_hz: the sample rate of both signals.
    """

    def __init__(self, rate_hz: int = SAMPLE_RATE_HZ) -> None:
        self.rate_hz = rate_hz
        self._history = int(MAX_ECHO_DELAY_S * rate_hz) + rate_hz  # voice samples kept
        self._reference = np.zeros(self._history, dtype=np.float64)
        self._end_s: float | None = None  # when the last chunk of the voice was published
        self.delay_s = math.nan  # the echo's delay found last
        self.blocks = 0
        self.cancelled_blocks = 0

    def reference(self, samples: np.ndarray, published_s: float) -> None:
        """The operator's voice as published at ``published_s`` (monotonic s)."""
        voice = np.asarray(samples, dtype=np.float64)[-self._history :]
        self._reference = np.roll(self._reference, -voice.size)
        self._reference[-voice.size :] = voice
        self._end_s = published_s

    def process(self, room: np.ndarray, arrived_s: float) -> np.ndarray:
        """``room`` (float samples, its last one heard by ``arrived_s``) without the voice."""
        self.blocks += 1
        block = np.asarray(room, dtype=np.float64)
        n = block.size
        if n == 0 or self._end_s is None:
            return block.astype(np.float32)
        if arrived_s - self._end_s > MAX_ECHO_DELAY_S + n / self.rate_hz:
            return block.astype(np.float32)  # the operator has been silent for long enough
        window = self._reference[-(n + int(MAX_ECHO_DELAY_S * self.rate_hz) + ECHO_TAPS) :]
        if float(np.sqrt(np.mean(np.square(window)))) < REFERENCE_RMS_MIN:
            return block.astype(np.float32)
        out = block.copy()
        size = 1 << math.ceil(math.log2(window.size + SEGMENT))
        spectrum = np.fft.rfft(window, size)
        energy = np.concatenate([[0.0], np.cumsum(np.square(window))])
        cancelled = False
        for start in range(0, n, SEGMENT):
            stop = n if n - start < 2 * SEGMENT else start + SEGMENT  # no short tail alone
            if start and stop - start < SEGMENT:
                break
            cancelled |= self._cancel(out, block, start, stop, window, spectrum, energy, size)
        self.cancelled_blocks += int(cancelled)
        return out.astype(np.float32)

    def _cancel(
        self,
        out: np.ndarray,
        block: np.ndarray,
        start: int,
        stop: int,
        window: np.ndarray,
        spectrum: np.ndarray,
        energy: np.ndarray,
        size: int,
    ) -> bool:
        """Subtract the voice from ``block[start:stop]`` into ``out``; True if it was there.

        The segment's own delay is searched (the voice node releases the voice in chunks, and
        may skip or hold one back: the delay can change between chunks).
        """
        part = block[start:stop]
        m = part.size
        correlation = np.fft.irfft(spectrum * np.conj(np.fft.rfft(part, size)), size)
        # the segment may start at window offset k + start (k: the delay's offset for the block)
        count = window.size - block.size + 1
        offsets = np.arange(count) + start
        scores = np.abs(correlation[offsets]) / np.sqrt(
            np.maximum((energy[offsets + m] - energy[offsets]) * float(part @ part), 1e-18)
        )
        best = int(np.argmax(scores))
        if scores[best] < MIN_ECHO_CORRELATION:  # no voice in this segment
            return False
        offset = int(offsets[best])
        half = ECHO_TAPS // 2
        first = min(max(offset - half, 0), window.size - m - ECHO_TAPS + 1)
        shifted = np.stack([window[first + k : first + k + m] for k in range(ECHO_TAPS)], axis=1)
        taps, *_ = np.linalg.lstsq(shifted, part, rcond=None)
        left = part - shifted @ taps
        if float(left @ left) > SPLIT_RESIDUAL * float(part @ part) and m >= 2 * MIN_SEGMENT:
            # the delay changed inside the segment (a chunk skipped or held): each half alone
            middle = start + m // 2
            args = (window, spectrum, energy, size)
            halves = self._cancel(out, block, start, middle, *args)
            halves |= self._cancel(out, block, middle, stop, *args)
            whole = float(left @ left)
            if halves and float(np.sum(np.square(out[start:stop]))) <= whole:
                return True
        out[start:stop] = left
        self.delay_s = (window.size - (offset - start) - block.size) / self.rate_hz
        return True


class RoomOutbox:
    """What one page has yet to be sent: the newest picture, the last blocks of sound.

    Attributes:
        offered, sent, dropped: pictures and blocks of sound by kind (``picture``, ``sound``).
    """

    def __init__(self, sound_depth: int = SOUND_DEPTH) -> None:
        self.picture: RoomItem | None = None
        self.sound: deque[RoomItem] = deque(maxlen=sound_depth)
        self.offered = {"picture": 0, "sound": 0}
        self.sent = {"picture": 0, "sound": 0}
        self.dropped = {"picture": 0, "sound": 0}

    def offer(self, item: RoomItem) -> None:
        """Keep ``item`` for sending; drop the picture it replaces or the oldest sound."""
        kind = "sound" if item.sound else "picture"
        self.offered[kind] += 1
        if item.sound:
            if len(self.sound) == self.sound.maxlen:
                self.dropped["sound"] += 1
            self.sound.append(item)
        else:
            if self.picture is not None:
                self.dropped["picture"] += 1
            self.picture = item

    def take(self) -> RoomItem | None:
        """The next item to send (sound first, oldest first; then the picture), or None."""
        if self.sound:
            item = self.sound.popleft()
        elif self.picture is not None:
            item, self.picture = self.picture, None
        else:
            return None
        self.sent["sound" if item.sound else "picture"] += 1
        return item


def encode_room_message(item: RoomItem, now_s: float | None = None) -> bytes:
    """``item`` as one binary WebSocket message (see the module text), aged at ``now_s``."""
    age_ms = max(0.0, ((time.time() if now_s is None else now_s) - item.taken_s) * 1e3)
    magic = SOUND_MAGIC if item.sound else PICTURE_MAGIC
    header = ROOM_HEADER.pack(
        magic, item.sequence & 0xFFFFFFFF, age_ms, item.level_dbfs, item.heard_dbfs
    )
    return header + item.payload
