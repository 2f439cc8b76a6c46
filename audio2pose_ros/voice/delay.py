"""The voice's delay line: each chunk is released ``delay_s`` after it arrived, in order.

The voice node pushes every decoded chunk with its arrival time and, on its clock, takes the
chunks that are due (:meth:`DelayLine.due`). The delay may change at any time (calibration); a
chunk is released at ``arrival + delay`` with the delay in force when it is taken, but never
before a chunk that arrived earlier, so the voice keeps its order. The line holds at most
``max_s`` seconds of audio: beyond it the oldest chunks are dropped and counted
(:attr:`DelayLine.dropped_s`), never silently. :class:`DelayedCommands` does the same for the
simulated Pepper's joint commands (its emulated execution latency).

:class:`SpeakerQueue` keeps the loudspeaker's own queue short: a loudspeaker plays what it is
given back to back, so every burst (chunks that arrived together after a hiccup of the network
or of a loaded machine, a shorter delay after calibration) leaves the rest of the voice later by
the burst's length, for as long as the voice goes on without a pause. The queue models what the
loudspeaker still has to play; while it holds more than ``max_backlog_s``, quiet chunks (a pause
between words, below ``quiet_rms``) are skipped, and while it holds more than
``max_speech_backlog_s`` any chunk is, as the motion filter skips a standing backlog of poses
(its ``backlog_window_s``, 0.2 s): the voice keeps pace with the motion. Both are counted. This
module does not import rclpy.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

__all__ = ["DelayLine", "DelayedChunk", "DelayedCommands", "SpeakerQueue"]

T = TypeVar("T")


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
        self.released_samples = 0

    @property
    def held_s(self) -> float:
        """Seconds of audio waiting."""
        return self._held / self.rate_hz

    def push(self, samples: np.ndarray, arrival_s: float) -> None:
        """Add a chunk that arrived at ``arrival_s``; drop the oldest beyond ``max_s``."""
        if not len(samples):
            return
        self._chunks.append(DelayedChunk(arrival_s, samples))
        self._held += len(samples)
        while self._held > self.max_samples and len(self._chunks) > 1:
            old = self._chunks.popleft()
            self._held -= len(old.samples)
            self.dropped_s += len(old.samples) / self.rate_hz

    def due(self, now_s: float, delay_s: float) -> list[DelayedChunk]:
        """The chunks whose ``arrival + delay_s`` is not after ``now_s``, oldest first."""
        out: list[DelayedChunk] = []
        while self._chunks and self._chunks[0].arrival_s + delay_s <= now_s:
            chunk = self._chunks.popleft()
            self._held -= len(chunk.samples)
            self.released_samples += len(chunk.samples)
            out.append(chunk)
        return out

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
        max_backlog_s: float = 0.04,
        quiet_rms: float = 0.01,
        max_speech_backlog_s: float = 0.2,
    ) -> None:
        self.rate_hz = int(rate_hz)
        self.max_backlog_s = max_backlog_s
        self.quiet_rms = quiet_rms
        self.max_speech_backlog_s = max_speech_backlog_s
        self.end_s = -np.inf  # when the loudspeaker will have played what it was given
        self.skipped_samples = 0  # in pauses skipped
        self.speech_skipped_samples = 0  # in louder chunks skipped beyond max_speech_backlog_s
        self.last_quiet = True  # the last chunk offered was a pause

    def quiet(self, samples: np.ndarray) -> bool:
        """Whether ``samples`` are a pause (RMS below ``quiet_rms``)."""
        return float(np.sqrt(np.mean(np.square(samples, dtype=np.float64)))) < self.quiet_rms

    def backlog_s(self, now_s: float) -> float:
        """Audio queued at the loudspeaker at ``now_s`` (s)."""
        return max(0.0, self.end_s - now_s)

    def offer(self, now_s: float, samples: np.ndarray) -> float | None:
        """When the loudspeaker will start playing ``samples`` sent now, or None: skip them."""
        if not len(samples):
            return None
        duration = len(samples) / self.rate_hz
        quiet = self.quiet(samples)
        self.last_quiet = quiet
        backlog = self.backlog_s(now_s)
        if quiet and backlog > self.max_backlog_s:
            self.skipped_samples += len(samples)
            return None
        if backlog > self.max_speech_backlog_s:
            self.speech_skipped_samples += len(samples)
            return None
        start_s = max(now_s, self.end_s)
        self.end_s = start_s + duration
        return start_s


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
