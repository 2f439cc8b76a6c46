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
- **Where**: console_node does the decoding, the cancelling and the JPEG encoding in a thread of
  its own (:class:`~audio2pose_ros.console.room_worker.RoomWorker`), never in its executor.
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
    "CAMERA_STALE_S",
    "ECHO_TAPS",
    "MAX_ECHO_DELAY_S",
    "ROOM_HEADER",
    "SOUND_DEPTH",
    "EchoCanceller",
    "FeedWatch",
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
MIN_ECHO_CORRELATION = 0.5  # a segment less alike the voice at any lag has none (chance: 0.3)
ECHO_TAPS = 8  # the echo filter's length (samples at 16 kHz) around the delay found
FLOOR_BLOCKS = 60  # the room's own level: the quietest 10 ms left of this many blocks (10 s)
ABOVE_FLOOR_DB = 6.0  # a segment is searched for the voice only this far above that level
SAME_LAG = 2  # samples: lags this close are one echo path (its filter spans the difference)
KNOWN_MATCH = 0.95  # a segment this alike the voice at a lag known already takes it unsearched
PIECE = 160  # samples (10 ms): the room's own level is that of its quietest piece this long
MIN_RUN = 32  # samples: the shortest run of what is left searched for a missed echo path
MISSED_DB = 12.0  # a run this far above the room's noise had a path missed: it is searched
EXPLAINED_DB = 10.0  # a new lag must leave what it explains this much lower (else: a person)
MAX_ROUNDS = 4  # fits and choices of paths per block at most (steps 2 to 5)
SWITCH_COST = 64.0  # a change of echo path must explain this many noise samples' power
NOISE_POWER_MIN = 1e-12  # noise power floor (below 16-bit quantisation), so a switch costs
REFERENCE_RMS_MIN = 1e-4  # below this the operator is silent: nothing is subtracted
SILENCE_DBFS = -120.0  # the level of digital silence (log of zero)
CAMERA_STALE_S = 3.0  # no picture for this long: the camera has stopped (it sends 10 a second)


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


@dataclass
class _Search:
    """One block of the room and the voice it may hold, as :class:`EchoCanceller` searches it."""

    room: np.ndarray  # the block (float64)
    padded: np.ndarray  # the voice's last samples, ECHO_TAPS zeros after (not yet published)
    first: int  # the room sample number of room[0]
    origin: int  # the voice sample number of padded[0]
    size: int = 0  # FFT size of the lag search (0: not prepared yet)
    spectrum: np.ndarray | None = None
    energy: np.ndarray | None = None  # cumulative voice energy, for normalising

    def offset(self, start: int, lag: int) -> int:
        """The window index of the voice that room sample ``start`` hears at ``lag``."""
        return self.first + start + lag - self.origin

    def shifted(self, lag: int) -> np.ndarray:
        """``(n, ECHO_TAPS)``: for each room sample, the voice around its sample at ``lag``."""
        base = self.offset(0, lag) - ECHO_TAPS // 2
        return np.lib.stride_tricks.sliding_window_view(
            self.padded[base : base + self.room.size + ECHO_TAPS - 1], ECHO_TAPS
        )

    def inside(self, lag: int) -> bool:
        """Whether the voice that ``lag`` pairs with the whole block is in the window."""
        base = self.offset(0, lag) - ECHO_TAPS // 2
        return base >= 0 and base + self.room.size + ECHO_TAPS - 1 <= self.padded.size

    def match(self, start: int, stop: int, lag: int) -> float:
        """Normalised correlation of ``room[start:stop]`` with the voice at ``lag``."""
        part = self.room[start:stop]
        o = self.offset(start, lag)
        if o < 0 or o + part.size > self.padded.size - ECHO_TAPS:
            return 0.0
        voice = self.padded[o : o + part.size]
        return abs(float(part @ voice)) / math.sqrt(
            max(float(voice @ voice) * float(part @ part), 1e-18)
        )

    def search(self, start: int, stop: int, least: float) -> int | None:
        """The lag where the voice best matches ``room[start:stop]`` (FFT).

        None if it matches less than ``least`` (normalised correlation) everywhere.
        """
        window = self.padded[:-ECHO_TAPS]
        if self.spectrum is None or self.energy is None:
            self.size = 1 << math.ceil(math.log2(window.size + SEGMENT))
            self.spectrum = np.fft.rfft(window, self.size)
            self.energy = np.concatenate([[0.0], np.cumsum(np.square(window))])
        part = self.room[start:stop]
        m = part.size
        correlation = np.fft.irfft(self.spectrum * np.conj(np.fft.rfft(part, self.size)), self.size)
        # the segment's voice ends at most at the window's end (no delay at all)
        offsets = np.arange(window.size - self.room.size + 1) + start
        scores = np.abs(correlation[offsets]) / np.sqrt(
            np.maximum(
                (self.energy[offsets + m] - self.energy[offsets]) * float(part @ part), 1e-18
            )
        )
        best = int(np.argmax(scores))
        if scores[best] < least:
            return None
        return self.origin + int(offsets[best]) - (self.first + start)


class EchoCanceller:
    """Remove the operator's voice, as the robot's loudspeaker plays it, from the room's sound.

    The voice (``reference``) is kept as published, chunk after chunk, without the pauses
    between, and numbered sample by sample, as is the room's sound. The echo of the voice is
    the voice shifted by a *lag* (room sample number to voice sample number) and filtered
    (:data:`ECHO_TAPS` taps: a delay between samples, the loudspeaker's gain): an *echo path*.
    The lag jumps wherever the voice node skips or holds back a chunk or the loudspeaker runs
    dry, at any sample, also inside a block of the room. So :meth:`process`, for each block:

    1. finds each :data:`SEGMENT`'s lag: one the previous block ended on, or found before in
       this block, where it matches (:data:`KNOWN_MATCH`), else where the voice best matches it
       (normalised cross-correlation by FFT over the last :data:`MAX_ECHO_DELAY_S` of the
       voice); a segment matching nowhere (:data:`MIN_ECHO_CORRELATION`) has none, and one no
       louder than the room alone (:data:`ABOVE_FLOOR_DB` over its noise, below) is not
       searched: the room's noise matches some
       lag by chance, and an echo under it is not heard;
    2. fits each lag's filter by least squares on the segments that found it (a lag carried
       from the previous block and found nowhere keeps its filter);
    3. chooses, sample by sample, which path (or none: no voice heard there) explains the room's
       sound, as the least-squares choice through the block that pays :data:`SWITCH_COST` times
       the power of the room's own sound for every change of path (a Viterbi search): a jump
       is placed on the sample where it happens, and noise does not make the choice wander.
       That power is the block's own where it is louder than the room's noise (a person in the
       room talking with the voice: the median 10 ms of what the first choice left), else the
       noise; a switch priced at the noise alone let a talker's every syllable flip the choice;
    4. fits each path's filter again on the samples it explains and subtracts it there; a lag
       new in this block that one segment showed, and that leaves what it explains less than
       :data:`EXPLAINED_DB` lower, is someone in the room who sounded like the voice there:
       it is dropped and the choice made again;
    5. where a run of what is left stands :data:`MISSED_DB` above the room's noise (a jump to
       a lag that no whole segment showed, in a block's last samples, say), searches that
       run's lag and goes back to 2; steps 2 to 5 are done at most :data:`MAX_ROUNDS` times.

    The room's noise power is that of the quietest :data:`PIECE` of what the last
    :data:`FLOOR_BLOCKS` blocks left (not of what they heard: while the voice node skips the
    pauses, the echo can go on for seconds without one). While no voice was published for
    :data:`MAX_ECHO_DELAY_S`, or it was silent, the block passes unchanged.

    Args:
        rate_hz: the sample rate of both signals.
    """

    def __init__(self, rate_hz: int = SAMPLE_RATE_HZ) -> None:
        self.rate_hz = rate_hz
        self._max_delay = int(MAX_ECHO_DELAY_S * rate_hz)
        self._history = self._max_delay + rate_hz  # voice samples kept
        self._reference = np.zeros(self._history, dtype=np.float64)
        self._voice_count = 0  # voice samples received so far
        self._room_count = 0  # room samples processed so far
        self._end_s: float | None = None  # when the last chunk of the voice was published
        self._paths: dict[int, np.ndarray] = {}  # lag -> filter taps, that ended the last block
        # the power of the quietest PIECE each of the last blocks left: the room's own sound
        self._quietest: deque[float] = deque(maxlen=FLOOR_BLOCKS)
        self.delay_s = math.nan  # the echo's delay found last (voice published to room heard)
        self.blocks = 0
        self.cancelled_blocks = 0

    def reference(self, samples: np.ndarray, published_s: float) -> None:
        """The operator's voice as published at ``published_s`` (monotonic s)."""
        voice = np.asarray(samples, dtype=np.float64)
        self._voice_count += voice.size
        voice = voice[-self._history :]
        self._reference = np.roll(self._reference, -voice.size)
        self._reference[-voice.size :] = voice
        self._end_s = published_s

    def process(self, room: np.ndarray, arrived_s: float) -> np.ndarray:
        """``room`` (float samples, its last one heard by ``arrived_s``) without the voice."""
        self.blocks += 1
        block = np.asarray(room, dtype=np.float64)
        n = block.size
        first = self._room_count  # the block's first room sample number
        self._room_count += n
        out = self._cancel_block(block, first, arrived_s)
        if n >= PIECE:  # the quietest 10 ms of what the last blocks left: the room's own sound
            pieces = out[: n - n % PIECE].reshape(-1, PIECE)
            self._quietest.append(float(np.min(np.mean(np.square(pieces), axis=1))))
        return out.astype(np.float32)

    def _cancel_block(self, block: np.ndarray, first: int, arrived_s: float) -> np.ndarray:
        """:meth:`process` but for the room's noise level: the block without the voice."""
        n = block.size
        silent_for_s = math.inf if self._end_s is None else arrived_s - self._end_s
        window = self._reference[-(n + self._max_delay + ECHO_TAPS) :]
        if (
            n < PIECE
            or silent_for_s > MAX_ECHO_DELAY_S + n / self.rate_hz  # the operator stopped
            or float(np.sqrt(np.mean(np.square(window)))) < REFERENCE_RMS_MIN
            or not self._quietest  # the room's own level is not known yet
        ):
            self._paths = {}
            return block
        padded = np.concatenate([window, np.zeros(ECHO_TAPS)])
        search = _Search(block, padded, first, self._voice_count - window.size)
        noise = max(min(self._quietest), NOISE_POWER_MIN)  # the room's own sound's power
        spans = self._segment_lags(search, noise)
        searched: set[tuple[int, int]] = set()
        for _ in range(MAX_ROUNDS):
            paths = self._fit(search, spans)
            out, kept, last, taken_db = _cancel(search, paths, noise)
            near = _near_power(out, noise)
            if near > noise:
                out, kept, last, taken_db = _cancel(search, paths, near)
            # a new lag, found in one segment, that does not take most of what it explains:
            # someone in the room who sounded like the voice there
            doubtful = [
                k
                for k in kept
                if k not in self._paths and len(spans[k]) < 2 and taken_db[k] < EXPLAINED_DB
            ]
            for k in doubtful:
                del spans[k]
            if doubtful:
                continue
            missed = _missed_run(out, near)
            if missed is None or missed in searched:
                break
            searched.add(missed)
            lag = search.search(*missed, MIN_ECHO_CORRELATION)
            if lag is None or any(abs(k - lag) <= SAME_LAG for k in paths):
                break
            spans.setdefault(lag, []).append(missed)
        else:  # the rounds are used up: cancel with what the last one left of the lags
            out, kept, last, _ = _cancel(search, self._fit(search, spans), noise)
        self._paths = kept
        if last is not None:
            self.cancelled_blocks += 1
            # voice published after the block's last sample's echo: how late the echo is
            self.delay_s = (self._voice_count - 1 - (first + n - 1 + last)) / self.rate_hz
        return out

    def _segment_lags(self, search: _Search, noise: float) -> dict[int, list[tuple[int, int]]]:
        """The segments of the block (``(start, stop)``) that each lag explains."""
        n = search.room.size
        spans: dict[int, list[tuple[int, int]]] = {}
        floor = noise * 10.0 ** (ABOVE_FLOOR_DB / 10.0)
        for start in range(0, n, SEGMENT):
            stop = n if n - start < 2 * SEGMENT else start + SEGMENT  # no short tail alone
            if start and stop - start < SEGMENT:
                break
            part = search.room[start:stop]
            if float(np.mean(np.square(part))) < floor:
                continue  # no louder than the room alone: any echo in it is below its noise
            known = list({**self._paths, **spans})
            scores = [search.match(start, stop, lag) for lag in known]
            if scores and max(scores) >= KNOWN_MATCH:
                lag: int | None = known[int(np.argmax(scores))]
            else:
                lag = search.search(start, stop, MIN_ECHO_CORRELATION)
            if lag is not None:
                same = next((k for k in spans if abs(k - lag) <= SAME_LAG), lag)
                spans.setdefault(same, []).append((start, stop))
        return spans

    def _fit(
        self, search: _Search, spans: dict[int, list[tuple[int, int]]]
    ) -> dict[int, np.ndarray]:
        """The candidate lags and their filters (see the class text, step 2)."""
        paths: dict[int, np.ndarray] = {}
        for lag in [*self._paths, *(k for k in spans if k not in self._paths)]:
            if not search.inside(lag):
                continue
            if lag not in spans:
                paths[lag] = self._paths[lag]
                continue
            mask = np.zeros(search.room.size, dtype=bool)
            for start, stop in spans[lag]:
                mask[start:stop] = True
            paths[lag], *_ = np.linalg.lstsq(search.shifted(lag)[mask], search.room[mask])
        return paths


def _cancel(
    search: _Search, paths: dict[int, np.ndarray], noise: float
) -> tuple[np.ndarray, dict[int, np.ndarray], int | None, dict[int, float]]:
    """Steps 3 and 4 of :class:`EchoCanceller`: the block without the voice.

    Args:
        search: the block and the voice.
        paths: the candidate lags and their filters.
        noise: the power of the room's own sound.

    Returns:
        What is left, the paths used with their filters fitted again, the lag of the last
        sample a path explains (None: none does), and how much lower (dB) each path used left
        the samples it explains.
    """
    block = search.room
    if not paths:
        return block, {}, None, {}
    lags = list(paths)
    shifted = [search.shifted(lag) for lag in lags]
    errors = np.stack(
        [np.square(block)]
        + [np.square(block - x @ paths[lag]) for lag, x in zip(lags, shifted, strict=True)]
    )
    choice = _cheapest_path(errors, SWITCH_COST * noise)
    out = block.copy()
    kept: dict[int, np.ndarray] = {}
    taken_db: dict[int, float] = {}
    for k, (lag, x) in enumerate(zip(lags, shifted, strict=True), start=1):
        mine = choice == k
        if not mine.any():
            continue
        taps = paths[lag]
        if int(mine.sum()) >= 2 * ECHO_TAPS:
            taps, *_ = np.linalg.lstsq(x[mine], block[mine])
        out[mine] = block[mine] - x[mine] @ taps
        kept[lag] = taps
        taken_db[lag] = level_dbfs(block[mine]) - level_dbfs(out[mine])
    explained = np.flatnonzero(choice)
    last = lags[int(choice[explained[-1]]) - 1] if explained.size else None
    return out, kept, last, taken_db


def _near_power(left: np.ndarray, noise: float) -> float:
    """The power of the room's own sound in this block: the median 10 ms piece of ``left``."""
    n = left.size - left.size % PIECE
    if not n:
        return noise
    pieces = np.mean(np.square(left[:n].reshape(-1, PIECE)), axis=1)
    return max(noise, float(np.median(pieces)))


def _missed_run(left: np.ndarray, noise: float) -> tuple[int, int] | None:
    """Where a path was missed: the loudest run of ``left`` :data:`MISSED_DB` over ``noise``.

    The run's power is taken over a quarter of a :data:`PIECE`; it is widened to
    :data:`MIN_RUN` samples. None if no sample stands that high.
    """
    if left.size < PIECE:
        return None
    over = noise * 10.0 ** (MISSED_DB / 10.0)
    width = np.ones(PIECE // 4)
    # mean power around each sample; at the block's edges over the samples there are
    power = np.convolve(np.square(left), width, "same") / np.convolve(
        np.ones(left.size), width, "same"
    )
    peak = int(np.argmax(power))
    if power[peak] < over:
        return None
    quiet = np.flatnonzero(power < over)
    start = int(quiet[quiet < peak][-1]) + 1 if (quiet < peak).any() else 0
    stop = int(quiet[quiet > peak][0]) if (quiet > peak).any() else left.size
    if stop - start < MIN_RUN:  # too short to be searched alone: widen it, inside the block
        start = min(max(0, (start + stop - MIN_RUN) // 2), left.size - MIN_RUN)
        stop = start + MIN_RUN
    return start, stop


def _cheapest_path(errors: np.ndarray, switch: float) -> np.ndarray:
    """The path index of each sample minimising the summed ``errors``, ``switch`` a change.

    Viterbi search over ``errors`` (paths x samples): every path may follow any other at the
    same price. Plain Python: a few paths, a few thousand samples.
    """
    rows = errors.T.tolist()
    cost = list(rows[0])
    paths = range(len(cost))
    came: list[list[int]] = []
    for row in rows[1:]:
        low = min(cost)
        best = cost.index(low)
        limit = low + switch
        came.append([best if cost[k] > limit else k for k in paths])
        cost = [min(cost[k], limit) + row[k] for k in paths]
    choice = [cost.index(min(cost))]
    for back in reversed(came):
        choice.append(back[choice[-1]])
    return np.array(choice[::-1], dtype=np.int16)


class FeedWatch:
    """When pictures last came from a camera topic, to tell that the camera has stopped.

    A camera that sent pictures and has sent none for ``stale_after_s`` has stopped (its
    process died, its driver hung, its topic went away): :meth:`problem` says so, naming the
    topic and the last picture's age, until a picture comes again. A topic that never sent a
    picture is no camera, not a stopped one.

    Args:
        topic: the camera topic, as named in the reports.
        stale_after_s: how long without a picture means the camera has stopped (s).
    """

    def __init__(self, topic: str, stale_after_s: float = CAMERA_STALE_S) -> None:
        self.topic = topic
        self.stale_after_s = stale_after_s
        self.frames = 0
        self.stops = 0  # times the camera was found stopped
        self._last_s = -math.inf  # monotonic time of the last picture
        self._last_wall_s = math.nan  # wall-clock time of the last picture
        self._stopped = False

    def arrived(self, now_s: float, wall_s: float) -> None:
        """A picture arrived at ``now_s`` (monotonic s), ``wall_s`` (wall-clock s)."""
        self.frames += 1
        self._last_s, self._last_wall_s = now_s, wall_s
        self._stopped = False

    def age_s(self, now_s: float) -> float | None:
        """Seconds since the last picture; None before the first."""
        return now_s - self._last_s if self.frames else None

    def stopped(self, now_s: float) -> bool:
        """Whether the camera sent pictures and has sent none for ``stale_after_s``."""
        stale = self.frames > 0 and now_s - self._last_s > self.stale_after_s
        if stale and not self._stopped:
            self.stops += 1
        self._stopped = stale
        return stale

    def problem(self, now_s: float) -> str | None:
        """``no picture on TOPIC for N s (since HH:MM:SS UTC)`` while stopped, else None."""
        if not self.stopped(now_s):
            return None
        since = time.strftime("%H:%M:%S", time.gmtime(self._last_wall_s))
        return f"no picture on {self.topic} for {now_s - self._last_s:.1f} s (since {since} UTC)"

    def view(self, now_s: float) -> dict[str, object]:
        """For the pages: topic, pictures, last one's age (s) and wall-clock time, stopped."""
        age = self.age_s(now_s)
        return {
            "topic": self.topic,
            "frames": self.frames,
            "age_s": None if age is None else round(age, 1),
            "last_s": None if math.isnan(self._last_wall_s) else self._last_wall_s,
            "stopped": self.stopped(now_s),
        }


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
