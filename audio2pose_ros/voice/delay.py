"""The voice's delay line: each chunk is released the delay in force after it arrived, in order.

The voice node pushes every decoded chunk with its arrival time and, on its clock, takes the
chunks that are due (:meth:`DelayLine.due`), with the delay the calibration asks for. A chunk is
released at ``arrival + delay in force``, never before a chunk that arrived earlier, so the
voice keeps its order. The delay in force (:attr:`DelayLine.delay_s`) never jumps while the
voice plays: a loudspeaker plays what it is given back to back, so a longer delay taken at once
would be a gap in the voice and a shorter one a burst queued behind it. It moves towards the
delay asked for by stretching or shrinking the pauses it releases (linear resampling of a chunk
below ``QUIET_RMS``, by at most ``PAUSE_STRETCH``, 50 %), so that each chunk ends where the next
one starts. Speech is never stretched (``SPEECH_STRETCH`` is 0): its pitch stays the operator's,
and the robot's loudspeaker plays it as a pure delay of what the console published, which the
console's echo canceller follows (it follows jumps of that delay, not a delay that slides under
the words; a 2 % stretch in speech left 19 dB of suppression in the simulated chain, 34 dB
without). After a gap in the voice (no chunk for ``GAP_S``, the
operator stopped talking) it takes the delay asked for with the next chunk, shortening the
silence by at most its length. A hold-up is not a gap: chunks that arrive together (the node or
the network held them up) are dated back as if they had come on time (:meth:`DelayLine.push`),
so the voice they carry is late, and the loudspeaker's queue holds it, rather than a pause
after which the delay may shorten. The line holds at most ``max_s`` seconds of audio: beyond it
the oldest chunks are dropped and counted (:attr:`DelayLine.dropped_s`), never silently.
:class:`DelayedCommands` holds the simulated Pepper's joint commands back in order (its
emulated execution latency).

:class:`SpeakerQueue` keeps the loudspeaker's own queue short: a loudspeaker plays what it is
given back to back, so every burst (chunks released together after a hold-up) leaves the rest
of the voice later by the burst's length, for as long as the voice goes on without a pause. The
queue models what the loudspeaker still has to play; while it holds more than
``max_backlog_s``, pauses between words (chunks below ``quiet_rms``) are cut by what it holds
beyond that, and while it holds more than ``max_speech_backlog_s`` any chunk is skipped, as the
motion filter skips a standing backlog of poses (its ``backlog_window_s``, 0.2 s): the voice
keeps pace with the motion. Both are counted. Up to ``max_backlog_s``, the delay line takes
what stands in the queue off its own delay (:meth:`SpeakerQueue.standing_s`); beyond it only
the queue sheds it, so that no lateness is corrected twice and the voice is never left ahead of
its delay. This
module does not import rclpy.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar

import numpy as np

__all__ = [
    "GAP_S",
    "MAX_BACKLOG_S",
    "MAX_SPEECH_BACKLOG_S",
    "PAUSE_STRETCH",
    "QUIET_RMS",
    "SPEECH_STRETCH",
    "DelayLine",
    "DelayedChunk",
    "DelayedCommands",
    "Queued",
    "SpeakerQueue",
    "is_quiet",
]

T = TypeVar("T")

QUIET_RMS = 0.01  # a chunk below this RMS (full scale 1, -40 dBFS) is a pause
SPEECH_STRETCH = 0.0  # the delay in force moves by at most this fraction of a speech chunk ...
PAUSE_STRETCH = 0.5  # ... and of a pause
GAP_S = 0.1  # no voice for this long: the delay asked for is taken at once
MAX_BACKLOG_S = 0.04  # the loudspeaker's queue beyond which pauses are cut ...
MAX_SPEECH_BACKLOG_S = 0.2  # ... and beyond which any chunk is skipped


def is_quiet(samples: np.ndarray, quiet_rms: float = QUIET_RMS) -> bool:
    """Whether ``samples`` are a pause (RMS below ``quiet_rms``)."""
    return float(np.sqrt(np.mean(np.square(samples, dtype=np.float64)))) < quiet_rms


class Queued(NamedTuple):
    """Voice samples given to the loudspeaker and when it starts playing them (s)."""

    start_s: float
    samples: np.ndarray


@dataclass(frozen=True)
class DelayedChunk:
    """One chunk of the voice: its samples and when it arrived (s, the caller's clock)."""

    arrival_s: float
    samples: np.ndarray  # mono float32 at the output rate


class DelayLine:
    """A FIFO of voice chunks released ``delay_s`` after arrival.

    Args:
        rate_hz: sample rate of the chunks (Hz), to count what the line holds in seconds.
        max_s: most audio held (s); older chunks are dropped beyond it.
    """

    def __init__(self, rate_hz: int, max_s: float = 2.0) -> None:
        self.rate_hz = int(rate_hz)
        self.max_samples = int(max_s * rate_hz)
        self._chunks: deque[DelayedChunk] = deque()
        self._held = 0
        self.dropped_s = 0.0
        self.released_samples = 0  # as released (stretched or shrunk)
        self.stretched_samples = 0  # added by stretching, less those removed by shrinking
        self.delay_s: float | None = None  # the delay in force; None before the first chunk
        self._last_end_s = -np.inf  # when the last chunk taken ended, on the arrival clock

    @property
    def held_s(self) -> float:
        """Seconds of audio waiting."""
        return self._held / self.rate_hz

    def push(self, samples: np.ndarray, arrival_s: float) -> None:
        """Add a chunk that arrived at ``arrival_s``; drop the oldest beyond ``max_s``.

        The voice is a real-time stream: a chunk cannot have been spoken later than the next
        one's arrival less its own length. Chunks that arrived together (the node or the network
        held them up) are therefore dated back, those still waiting here, as if they had come on
        time, so that a hold-up is the voice coming late, not a pause in it (see :meth:`due`).
        """
        if not len(samples):
            return
        later_s = arrival_s
        for i in range(len(self._chunks) - 1, -1, -1):
            chunk = self._chunks[i]
            on_time_s = later_s - len(chunk.samples) / self.rate_hz
            if chunk.arrival_s <= on_time_s:
                break
            self._chunks[i] = DelayedChunk(on_time_s, chunk.samples)
            later_s = on_time_s
        self._chunks.append(DelayedChunk(arrival_s, samples))
        self._held += len(samples)
        while self._held > self.max_samples and len(self._chunks) > 1:
            old = self._chunks.popleft()
            self._held -= len(old.samples)
            self.dropped_s += len(old.samples) / self.rate_hz

    def due(self, now_s: float, delay_s: float) -> list[DelayedChunk]:
        """The chunks due by ``now_s``, oldest first, the delay in force moved towards ``delay_s``.

        A chunk is due at ``arrival + delay in force``; it is released stretched or shrunk by the
        step the delay in force then takes towards ``delay_s`` (see the module text).
        """
        out: list[DelayedChunk] = []
        while self._chunks:
            chunk = self._chunks[0]
            gap = chunk.arrival_s - self._last_end_s
            in_force = delay_s if self.delay_s is None else self.delay_s
            if gap > GAP_S:  # a pause in the voice: the delay may change, shortening it at most
                in_force = max(delay_s, in_force - gap)
            if chunk.arrival_s + in_force > now_s:
                # not due: a delay taken after a pause is taken with the chunk, whose arrival
                # may still be dated back by chunks that came with it (see :meth:`push`)
                if self.delay_s is None:
                    self.delay_s = in_force
                break
            self._chunks.popleft()
            self._held -= len(chunk.samples)
            self._last_end_s = max(
                self._last_end_s, chunk.arrival_s + len(chunk.samples) / self.rate_hz
            )
            samples, self.delay_s = self._moved_towards(chunk.samples, in_force, delay_s)
            self.released_samples += len(samples)
            out.append(DelayedChunk(chunk.arrival_s, samples))
        return out

    def _moved_towards(
        self, samples: np.ndarray, in_force_s: float, delay_s: float
    ) -> tuple[np.ndarray, float]:
        """``samples`` resampled for one step of the delay towards ``delay_s``; the new delay."""
        n = len(samples)
        most = (PAUSE_STRETCH if is_quiet(samples) else SPEECH_STRETCH) * n
        change = round(min(max((delay_s - in_force_s) * self.rate_hz, -most), most))
        if change == 0 or n + change < 1:
            return samples, in_force_s
        positions = np.linspace(0.0, n - 1.0, n + change)
        stretched = np.interp(positions, np.arange(n), samples).astype(samples.dtype)
        self.stretched_samples += change
        return stretched, in_force_s + change / self.rate_hz

    def clear(self) -> float:
        """Drop every waiting chunk (muted voice); the seconds dropped."""
        dropped = self.held_s
        self._chunks.clear()
        self._held = 0
        return dropped


class SpeakerQueue:
    """What the loudspeaker has queued, and the pauses skipped to keep it short.

    Args:
        rate_hz: sample rate of the voice (Hz).
        max_backlog_s: queued audio beyond which quiet chunks are skipped (s).
        quiet_rms: a chunk below this RMS (full scale 1) is a pause (-40 dBFS by default).
        max_speech_backlog_s: queued audio beyond which any chunk is skipped (s).
    """

    def __init__(
        self,
        rate_hz: int,
        max_backlog_s: float = MAX_BACKLOG_S,
        quiet_rms: float = QUIET_RMS,
        max_speech_backlog_s: float = MAX_SPEECH_BACKLOG_S,
    ) -> None:
        self.rate_hz = int(rate_hz)
        self.max_backlog_s = max_backlog_s
        self.quiet_rms = quiet_rms
        self.max_speech_backlog_s = max_speech_backlog_s
        self.end_s = -np.inf  # when the loudspeaker will have played what it was given
        self.skipped_samples = 0  # in pauses skipped
        self.speech_skipped_samples = 0  # in louder chunks skipped beyond max_speech_backlog_s

    def quiet(self, samples: np.ndarray) -> bool:
        """Whether ``samples`` are a pause (RMS below ``quiet_rms``)."""
        return is_quiet(samples, self.quiet_rms)

    def backlog_s(self, now_s: float) -> float:
        """Audio queued at the loudspeaker at ``now_s`` (s)."""
        return max(0.0, self.end_s - now_s)

    def standing_s(self, now_s: float) -> float:
        """The part of the queue that cutting pauses leaves (s): up to ``max_backlog_s``.

        What the delay line takes off its own delay. Beyond it the queue itself sheds pauses: a
        delay line that also shortened its delay for that part would correct the same lateness
        twice and leave the voice early once the queue is short again.
        """
        return min(self.backlog_s(now_s), self.max_backlog_s)

    def flushed(self) -> None:
        """The loudspeaker dropped what it had queued (a mute): nothing is queued now."""
        self.end_s = -np.inf

    def offer(self, now_s: float, samples: np.ndarray) -> Queued | None:
        """What the loudspeaker plays of ``samples`` sent now, and when; None: all skipped.

        A pause is cut by what the queue holds beyond ``max_backlog_s`` (its first samples; the
        whole pause when that is longer), so that the queue comes back to ``max_backlog_s`` and
        no shorter: the delay line takes that part off its own delay (:meth:`standing_s`).
        """
        if not len(samples):
            return None
        backlog = self.backlog_s(now_s)
        if self.quiet(samples):
            beyond = round(max(backlog - self.max_backlog_s, 0.0) * self.rate_hz)
            cut = min(len(samples), beyond)
            self.skipped_samples += cut
            samples = samples[cut:]
            if not len(samples):
                return None
        elif backlog > self.max_speech_backlog_s:
            self.speech_skipped_samples += len(samples)
            return None
        start_s = max(now_s, self.end_s)
        self.end_s = start_s + len(samples) / self.rate_hz
        return Queued(start_s, samples)


class DelayedCommands(Generic[T]):
    """Commands applied ``latency_s`` after they arrived, in order."""

    def __init__(self, latency_s: float) -> None:
        self.latency_s = latency_s
        self._waiting: deque[tuple[float, T]] = deque()

    def push(self, arrival_s: float, command: T) -> None:
        """A command arrived."""
        self._waiting.append((arrival_s + self.latency_s, command))

    def due(self, now_s: float) -> list[T]:
        """The commands due by ``now_s``, oldest first."""
        out = []
        while self._waiting and self._waiting[0][0] <= now_s:
            out.append(self._waiting.popleft()[1])
        return out
