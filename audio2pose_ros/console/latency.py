"""The operator's voice to the robot's command: latency of each audio chunk, as it happens.

A chunk's latency runs from the moment its last sample was captured in the browser (the page's
stamp, on the console's clock) to the arrival of the first ``/joint_angles`` command that can
carry the first pose it caused. The console sees three events and relates them:

1. it publishes the chunk on ``audio/audio`` (:meth:`VoiceLatency.chunk_published`);
2. a ``raw_trajectory`` message arrives (:meth:`VoiceLatency.raw_arrived`): the features node
   turns every chunk of 10 ms or more into one features message and the inference node every
   features message into one raw_trajectory message, so it belongs to the newest chunk published
   before it that has none yet (older unanswered ones completed no feature frame, e.g. the first
   chunk of a stream, shorter than a 25 ms window). This holds while the graph answers a chunk
   within one chunk period (20 ms from the page; ``audio2pose bench --graph`` measures 2-5 ms);
3. the first command whose header stamp (the filter's tick) is not before that raw message's
   arrival (:meth:`VoiceLatency.command_arrived`, with :data:`STAMP_TOLERANCE_S` for the order in
   which DDS delivers one message to two subscribers) carries it.

The window a chunk spends filling in the page (its duration) and the feature window (25 ms) are
the algorithmic delay, outside this figure as in ``audio2pose bench --graph``. A latency that is
not finite or beyond :data:`MAX_LATENCY_S` either way (a stamp off the console's clock) is no
measurement and is not kept, so the summary is finite whatever the stamps. This module does not
import rclpy; times are seconds since the epoch.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["STAMP_TOLERANCE_S", "VoiceLatency"]

STAMP_TOLERANCE_S = 0.003  # a command ticked this long before the console saw the raw pose
# still carries it (the filter may receive the same message a little earlier than the console)
MAX_PAIRING_S = 1.0  # a chunk unanswered for this long, or a raw pose uncommanded, is dropped
MAX_UNPAIRED = 64  # chunks waiting for their raw pose, at most
# A latency (any of the three, either sign) beyond an hour is a wrong clock, not a measurement:
# dropped. The protocol already refuses stamps a minute off; this bound keeps the summary finite
# (JSON for the pages) whatever the stamps handed in.
MAX_LATENCY_S = 3600.0


@dataclass(frozen=True)
class _Chunk:
    stamp_s: float  # captured (page stamp)
    received_s: float  # arrived at the console
    published_s: float  # published on audio/audio


class VoiceLatency:
    """Pair chunks, raw poses and commands; keep the last ``window`` latencies.

    Args:
        window: latencies kept for the percentiles.
    """

    def __init__(self, window: int = 500) -> None:
        self._unpaired: deque[_Chunk] = deque(maxlen=MAX_UNPAIRED)
        self._pending: deque[tuple[_Chunk, float]] = deque(maxlen=MAX_UNPAIRED)
        # (voice -> command, page -> console, publication -> command), seconds
        self._samples: deque[tuple[float, float, float]] = deque(maxlen=window)

    def reset(self) -> None:
        """Forget chunks in flight (a new talker); measured latencies are kept."""
        self._unpaired.clear()
        self._pending.clear()

    def chunk_published(self, stamp_s: float, received_s: float, published_s: float) -> None:
        """A chunk captured at ``stamp_s`` came at ``received_s``, went out at ``published_s``."""
        self._unpaired.append(_Chunk(stamp_s, received_s, published_s))

    def raw_arrived(self, arrival_s: float) -> None:
        """A raw_trajectory message arrived: pair it with the newest chunk published before it."""
        chosen = None
        while self._unpaired and self._unpaired[0].published_s <= arrival_s:
            chosen = self._unpaired.popleft()  # older unanswered chunks completed no frame
        if chosen is not None and arrival_s - chosen.published_s <= MAX_PAIRING_S:
            self._pending.append((chosen, arrival_s))

    def command_arrived(self, stamp_s: float, arrival_s: float) -> None:
        """A command stamped ``stamp_s`` (its tick) arrived: it carries the raw poses before it."""
        while self._pending:
            chunk, raw_s = self._pending[0]
            if arrival_s - raw_s > MAX_PAIRING_S:
                self._pending.popleft()  # never commanded (stopped, disabled, a dropped pose)
                continue
            if stamp_s < raw_s - STAMP_TOLERANCE_S:
                break
            self._pending.popleft()
            sample = (
                arrival_s - chunk.stamp_s,
                chunk.received_s - chunk.stamp_s,
                arrival_s - chunk.published_s,
            )
            if all(math.isfinite(value) and abs(value) <= MAX_LATENCY_S for value in sample):
                self._samples.append(sample)

    def summary(self) -> dict[str, float | int]:
        """The latencies kept so far (ms).

        Returns:
            ``n`` (how many), and once there is one: ``p50``, ``p99`` and ``last`` voice to
            command, ``uplink_p50`` (page to console) and ``graph_p50`` (publication to command);
            all finite (samples are within :data:`MAX_LATENCY_S`).
        """
        if not self._samples:
            return {"n": 0}
        values = np.array(self._samples) * 1e3
        total = values[:, 0]
        return {
            "n": len(values),
            "p50": round(float(np.median(total)), 2),
            "p99": round(float(np.percentile(total, 99)), 2),
            "last": round(float(total[-1]), 2),
            "uplink_p50": round(float(np.median(values[:, 1])), 2),
            "graph_p50": round(float(np.median(values[:, 2])), 2),
        }
