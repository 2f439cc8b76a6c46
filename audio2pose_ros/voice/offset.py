"""The voice-to-motion offset at the robot, judged from what the robot reports.

An observer that publishes the operator's voice into the graph records:

- each chunk it published (time, samples);
- when each ``raw_trajectory`` message arrived, and its poses (stamped);
- the robot's measured ``joint_states`` (stamped);
- the robot's microphones (naoqi_driver's AudioBuffer, each stamped with its last sample).

Over each window of the recording, :func:`window_offsets` measures, independently of the
voice node's own estimates:

- when a piece of speech is *heard*: the lag from the published voice to the microphones
  (:func:`~audio2pose_ros.voice.lag.sound_lag`), which holds the voice node's delay, the
  transport and the loudspeaker;
- when the motion made from it *reaches the joints*: the lag from a chunk's publication to the
  pose message computed from it (event order, :class:`~audio2pose_ros.voice.lag.ChunkPairing`)
  plus the lag from those poses to the measured joints
  (:func:`~audio2pose_ros.voice.lag.motion_lag`: filter, transport and execution together);

and gives ``motion - heard`` (negative: the motion comes first). The window the voice is held to
is [-80 ms, +20 ms] (:mod:`audio2pose_ros.voice.sync`). This module does not import rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.voice.lag import ChunkPairing, motion_lag, sound_lag

__all__ = ["VoiceMotionRecord", "percentiles_ms", "window_offsets"]

MOTION_SCORE = 0.3  # raw model poses are rougher than commands: a lower bar than the node's
SOUND_SCORE = 0.4
MAX_MOTION_LAG_S = 1.0
MAX_SOUND_LAG_S = 1.5


@dataclass
class VoiceMotionRecord:
    """What the observer recorded, each on the one clock (s)."""

    voice: list[tuple[float, np.ndarray]] = field(default_factory=list)  # published chunks
    voice_rate_hz: int = 16000
    raw_arrivals: list[float] = field(default_factory=list)
    raw_poses: list[tuple[float, np.ndarray]] = field(default_factory=list)
    measured: list[tuple[float, np.ndarray]] = field(default_factory=list)
    heard: list[tuple[float, np.ndarray]] = field(default_factory=list)  # first sample's time
    heard_rate_hz: int = 48000


def _inside(
    rows: list[tuple[float, np.ndarray]], start: float, end: float
) -> list[tuple[float, np.ndarray]]:
    return [(t, r) for t, r in rows if start <= t < end]


def _series(rows: list[tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    rows = sorted(rows, key=lambda row: row[0])
    return np.array([t for t, _ in rows]), np.stack([r for _, r in rows])


def window_offsets(
    record: VoiceMotionRecord, window_s: float = 2.0, step_s: float = 1.0
) -> list[float]:
    """``motion - heard`` (s) in each window where both lags could be measured."""
    if not record.voice:
        return []
    start, end = record.voice[0][0], record.voice[-1][0]
    offsets = []
    t = start
    while t + window_s <= end:
        pairing = ChunkPairing()
        events = sorted(
            [(a, 0) for a, _ in _inside(record.voice, t, t + window_s)]
            + [(a, 1) for a in record.raw_arrivals if t <= a < t + window_s + 0.5]
        )
        for arrival, kind in events:
            (pairing.poses if kind else pairing.chunk)(arrival)
        graph = pairing.median_s()
        raw = _inside(record.raw_poses, t, t + window_s)
        measured = _inside(record.measured, t, t + window_s + MAX_MOTION_LAG_S)
        voice = _inside(record.voice, t, t + window_s)
        heard = _inside(record.heard, t, t + window_s + MAX_SOUND_LAG_S)
        t += step_s
        if len(raw) < 10 or len(measured) < 10 or not voice or not heard or math.isnan(graph):
            continue
        motion = motion_lag(*_series(raw), *_series(measured), MAX_MOTION_LAG_S)
        sound = sound_lag(voice, record.voice_rate_hz, heard, record.heard_rate_hz, MAX_SOUND_LAG_S)
        if motion.score >= MOTION_SCORE and sound.score >= SOUND_SCORE:
            offsets.append(graph + motion.lag_s - sound.lag_s)
    return offsets


def percentiles_ms(offsets: list[float]) -> tuple[float, float, float]:
    """p5, p50 and p95 of the offsets, in ms (NaN without any)."""
    if not offsets:
        return math.nan, math.nan, math.nan
    p5, p50, p95 = np.percentile(np.asarray(offsets) * 1e3, [5, 50, 95])
    return float(p5), float(p50), float(p95)
