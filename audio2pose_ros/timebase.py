"""The frame grid every layer shares (seed 003 section 4.2.2), defined once.

Audio is resampled to 16 kHz mono; features are computed on 25 ms windows every 10 ms, so poses,
features, data set clips and the live graph all run at 100 frames per second. Frame ``i`` covers
the samples ``[160 i, 160 i + 400)`` and stands for the instant at the centre of that window,
``(160 i + 200) / 16000`` s.

A feature set may ask for another grid (:class:`~audio2pose_ros.audio.features.FeatureSpec`
carries its own rate, window and step for checkpoints that were trained so); these constants are
the defaults, and what the data set, the importers and the live graph use.
"""

from __future__ import annotations

import numpy as np

SAMPLE_RATE_HZ = 16000  # f_s: every audio input is resampled to this rate
WINDOW_SAMPLES = 400  # 25 ms analysis window
SAMPLES_PER_FRAME = 160  # 10 ms frame step (hop)
FRAME_RATE_HZ = SAMPLE_RATE_HZ / SAMPLES_PER_FRAME  # 100 frames (poses) per second
FRAME_PERIOD_S = SAMPLES_PER_FRAME / SAMPLE_RATE_HZ  # 0.01 s between frames
WINDOW_S = WINDOW_SAMPLES / SAMPLE_RATE_HZ  # 0.025 s
# A features stream runs at most this many times real time (``audio2pose run --rate`` and bag
# replay go up to 100) ...
MAX_STREAM_SPEEDUP = 100.0
MAX_STREAM_SLACK_FRAMES = 10_000  # ... give or take this many frames (100 s) of timing


def complete_frames(n_samples: int) -> int:
    """Frames whose whole window lies inside ``n_samples`` samples (0 if shorter than a window)."""
    if n_samples < WINDOW_SAMPLES:
        return 0
    return 1 + (n_samples - WINDOW_SAMPLES) // SAMPLES_PER_FRAME


def frame_times_s(n_samples: int) -> np.ndarray:
    """Time (s) of each complete frame of ``n_samples`` samples: ``(160 i + 200) / 16000``."""
    starts = np.arange(complete_frames(n_samples)) * SAMPLES_PER_FRAME
    return (starts + WINDOW_SAMPLES / 2.0) / SAMPLE_RATE_HZ


def duration_s(n_samples: int) -> float:
    """Duration (s) of ``n_samples`` samples at :data:`SAMPLE_RATE_HZ`."""
    return n_samples / SAMPLE_RATE_HZ


class FrameSequence:
    """Frames missing from a stream whose batches say the index of their first frame.

    A publisher numbers its frames from 0 and each batch carries the index of its first frame.
    A batch that starts past the frame the receiver expects shows that the frames between were
    lost on the way (a reliable subscription's queue keeps only the newest messages when the
    receiver falls behind). A batch that starts before it is a new stream (the publisher
    restarted), and a batch without an index (another publisher, or an older one) says nothing.
    The frames after the last batch received cannot be known lost until a later batch arrives.
    A batch further ahead than the time since the last one allows, even at
    :data:`MAX_STREAM_SPEEDUP` times real time (a bag replayed fast), is not a count of lost
    frames but a new stream too: an index says what its sender claims.
    """

    def __init__(self) -> None:
        """No stream seen yet."""
        self.expected: int | None = None
        self.lost = 0  # frames known missing, over every stream
        self.restarts = 0  # batches that started a new stream (index before the expected one)
        self._last_s: float | None = None

    def observe(self, first: int | None, n_frames: int, now_s: float | None = None) -> int:
        """Frames missing just before a batch of ``n_frames`` starting at index ``first``.

        ``now_s`` (a monotonic clock) bounds the frames that can have gone missing since the
        previous batch; None: unbounded.
        """
        missing = 0
        if first is None:
            self.expected = None
            return 0
        previous_s, self._last_s = self._last_s, now_s
        if self.expected is not None:
            if first > self.expected:
                missing = first - self.expected
                if now_s is not None and previous_s is not None:
                    possible = (now_s - previous_s) * FRAME_RATE_HZ * MAX_STREAM_SPEEDUP
                    if missing > possible + MAX_STREAM_SLACK_FRAMES:
                        missing = 0
                        self.restarts += 1
            elif first < self.expected:
                self.restarts += 1
        self.lost += missing
        self.expected = first + n_frames
        return missing
