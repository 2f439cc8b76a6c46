"""The voice's delay line: each chunk is released ``delay_s`` after it arrived, in order.

The voice node pushes every decoded chunk with its arrival time and, on its clock, takes the
chunks that are due (:meth:`DelayLine.due`). The delay may change at any time (calibration); a
chunk is released at ``arrival + delay`` with the delay in force when it is taken, but never
before a chunk that arrived earlier, so the voice keeps its order. The line holds at most
``max_s`` seconds of audio: beyond it the oldest chunks are dropped and counted
(:attr:`DelayLine.dropped_s`), never silently. This module does not import rclpy.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["DelayLine", "DelayedChunk"]


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
