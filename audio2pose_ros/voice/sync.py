"""How long to hold the operator's voice back so that it is heard with the motion made from it.

A piece of speech arrives at the graph at ``a``. The motion made from it reaches Pepper's joints
at ``a + graph + execution``; its sound is heard from the loudspeakers at
``a + delay + loudspeaker``. The offset ``motion - heard`` must stay within
``[-WINDOW_EARLY_S, WINDOW_LATE_S]`` = [-80 ms, +20 ms]: people notice sound ahead of the
picture from about 45 ms and behind it from about 125 ms (ITU-R BT.1359), and a speaker's
gesture starts with the stressed syllable or a little before it, seldom after. The voice is
therefore delayed by ``graph + execution - loudspeaker + TARGET_LEAD_S`` (the motion 15 ms ahead
of the sound, and up to 40 ms more while the loudspeaker has audio queued: about the middle of
the window), never less than nothing.

The three parts are measured while the operator talks (:class:`SyncEstimator`):

- **graph**: from an audio chunk's arrival to the pose message computed from it (event order,
  :class:`~audio2pose_ros.voice.lag.ChunkPairing`), plus how long the commands follow those
  poses (the motion filter's smoothing; stamps of ``raw_trajectory`` against
  ``commanded_joint_states``, :func:`~audio2pose_ros.voice.lag.motion_lag`);
- **execution**: how long the measured ``joint_states`` follow the commands
  (:func:`~audio2pose_ros.voice.lag.motion_lag`);
- **loudspeaker**: how long after the voice should start playing (when it is sent, or when
  what was sent before it has played) the robot's microphones hear it
  (:func:`~audio2pose_ros.voice.lag.sound_lag`).

A part not measured (no robot microphones, no measured joint states, too little speech or
motion yet) uses its documented default (:data:`DEFAULTS_S`) and says so. Each estimate is the
median of the recent measurements whose score passed its threshold. The delay follows the
estimates by at most ``MAX_DELAY_STEP_S`` (20 ms) per update while the operator speaks, so
the voice never jumps, and by up to ``MAX_PAUSE_STEP_S`` (100 ms) in a pause. This module
does not import rclpy.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.voice.lag import ENVELOPE_RATE_HZ, ChunkPairing, loudness, motion_lag, sound_lag

__all__ = [
    "DEFAULTS_S",
    "MAX_DELAY_S",
    "TARGET_LEAD_S",
    "WINDOW_EARLY_S",
    "WINDOW_LATE_S",
    "PartEstimate",
    "Snapshot",
    "SyncEstimator",
    "measure",
    "voice_delay_s",
]

WINDOW_EARLY_S = 0.080  # the motion may reach the joints this long before the sound is heard
WINDOW_LATE_S = 0.020  # ... and this long after it
# Aimed at: the motion this long ahead of the sound; the loudspeaker's queue, kept under 40 ms
# (delay.SpeakerQueue), adds to it, so the offset stays about mid-window.
TARGET_LEAD_S = 0.015
MAX_DELAY_S = 1.0  # the voice is never held back longer
MAX_DELAY_STEP_S = 0.02  # the delay changes by at most this much per update during speech ...
MAX_PAUSE_STEP_S = 0.1  # ... and by at most this much during a pause, where no one hears it
# Used while a part is not measured: the graph's own latency (chunk to command, with the motion
# filter's smoothing, as `audio2pose bench --voice` measures it on the simulated Pepper), the
# robot's execution latency (naoqi_driver's setAngles to a measured joint state) and the
# loudspeaker's (ALAudioDevice's remote buffer to sound).
DEFAULTS_S = {"graph": 0.08, "execution": 0.1, "loudspeaker": 0.1}
MOTION_SCORE = 0.4  # a motion lag below this score is no measurement
SOUND_SCORE = 0.5  # a sound lag below this score is no measurement
MAX_MOTION_LAG_S = 0.6  # longest lag searched between two trajectories (s)
MAX_SOUND_LAG_S = 1.0  # longest loudspeaker lag searched (s)
HISTORY_S = 6.0  # each measurement looks at this much of the recent past (s)
KEPT = 15  # measurements kept per part (their median is the estimate)


def voice_delay_s(graph_s: float, execution_s: float, loudspeaker_s: float) -> float:
    """The delay that puts the motion ``TARGET_LEAD_S`` ahead of the sound, in [0, MAX_DELAY_S]."""
    return min(max(graph_s + execution_s - loudspeaker_s + TARGET_LEAD_S, 0.0), MAX_DELAY_S)


@dataclass
class PartEstimate:
    """One part of the latency: the recent measurements and what is used."""

    name: str
    measurements: deque[float]

    @property
    def measured(self) -> bool:
        """True once at least one measurement passed."""
        return bool(self.measurements)

    @property
    def value_s(self) -> float:
        """The median measurement, or the part's default."""
        if self.measurements:
            return float(np.median(self.measurements))
        return DEFAULTS_S[self.name]

    def describe(self) -> str:
        """``85 ms (measured, 12)`` or ``100 ms (default: not measured)``."""
        if self.measured:
            return f"{self.value_s * 1e3:.0f} ms (measured, {len(self.measurements)})"
        return f"{self.value_s * 1e3:.0f} ms (default: not measured)"


class _Series:
    """Stamped rows kept for ``HISTORY_S``."""

    def __init__(self) -> None:
        self.rows: deque[tuple[float, np.ndarray]] = deque()

    def add(self, stamp_s: float, row: np.ndarray) -> None:
        if self.rows and stamp_s <= self.rows[-1][0]:
            return  # out of order or repeated: the series stays increasing
        self.rows.append((stamp_s, row))
        while self.rows and stamp_s - self.rows[0][0] > HISTORY_S:
            self.rows.popleft()

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.rows:
            return np.zeros(0), np.zeros((0, 0))
        return np.array([t for t, _ in self.rows]), np.stack([r for _, r in self.rows])


class SyncEstimator:
    """Measure the three parts as the graph runs and give the voice's delay.

    Feed it what the voice node sees (each ``on_*`` method, times in seconds on one clock) and
    call :meth:`update` about once a second: it measures each part over the last ``HISTORY_S``
    and moves :attr:`delay_s` towards :func:`voice_delay_s` of the estimates.
    """

    def __init__(self, output_rate_hz: int) -> None:
        self.output_rate_hz = output_rate_hz
        self.pairing = ChunkPairing()
        self.parts = {name: PartEstimate(name, deque(maxlen=KEPT)) for name in DEFAULTS_S}
        self.filter_lag = PartEstimate("graph", deque(maxlen=KEPT))  # raw poses to commands
        self.raw = _Series()
        self.commanded = _Series()
        self.measured = _Series()
        self.sent: deque[tuple[float, np.ndarray]] = deque()
        self.heard: deque[tuple[float, np.ndarray]] = deque()
        self.heard_rate_hz = 0
        self.delay_s = voice_delay_s(*(p.value_s for p in self.parts.values()))

    # --- what the node sees -------------------------------------------------------------------

    def on_chunk(self, arrival_s: float) -> None:
        """An audio chunk arrived on the graph's audio topic."""
        self.pairing.chunk(arrival_s)

    def on_raw(self, arrival_s: float, stamp_s: float, pose: np.ndarray) -> None:
        """A raw pose message arrived (its last pose, in the commands' joint order)."""
        self.pairing.poses(arrival_s)
        self.raw.add(stamp_s, pose)

    def on_commanded(self, stamp_s: float, pose: np.ndarray) -> None:
        """A command (commanded_joint_states), in the same joint order."""
        self.commanded.add(stamp_s, pose)

    def on_measured(self, stamp_s: float, pose: np.ndarray) -> None:
        """Measured joint_states, in the same joint order."""
        self.measured.add(stamp_s, pose)

    def on_sent(self, first_sample_s: float, mono: np.ndarray) -> None:
        """Voice samples handed to the loudspeaker, the first at ``first_sample_s``.

        Kept as their loudness (:func:`~audio2pose_ros.voice.lag.loudness`), as are the
        microphones'.
        """
        self._keep(self.sent, *loudness(first_sample_s, mono, self.output_rate_hz))

    def on_heard(self, first_sample_s: float, mono: np.ndarray, rate_hz: int) -> None:
        """The robot's microphones (mean of channels), the first sample at ``first_sample_s``."""
        self.heard_rate_hz = ENVELOPE_RATE_HZ
        self._keep(self.heard, *loudness(first_sample_s, mono, rate_hz))

    @staticmethod
    def _keep(pieces: deque[tuple[float, np.ndarray]], t: float, mono: np.ndarray) -> None:
        pieces.append((t, mono))
        while pieces and t - pieces[0][0] > HISTORY_S:
            pieces.popleft()

    # --- estimates ------------------------------------------------------------------------------

    def graph_s(self) -> tuple[float, bool]:
        """The graph's latency and whether both of its halves are measured."""
        pairing = self.pairing.median_s()
        measured = math.isfinite(pairing) and self.filter_lag.measured
        if not measured:
            return DEFAULTS_S["graph"], False
        return pairing + self.filter_lag.value_s, True

    def update(self) -> None:
        """Measure each part over the recent past; move the delay towards its new value."""
        self.apply(measure(self.snapshot()))

    def snapshot(self) -> Snapshot:
        """Copies of what the measurements need (quick: the node takes it on its own thread)."""
        return Snapshot(
            raw=self.raw.arrays(),
            commanded=self.commanded.arrays(),
            measured=self.measured.arrays(),
            sent=list(self.sent),
            heard=list(self.heard) if self.heard_rate_hz else [],
        )

    def apply(self, lags: dict[str, float], pause: bool = False) -> None:
        """Keep the lags :func:`measure` found; move the delay by at most one step.

        During a ``pause`` in the voice the step may be longer (``MAX_PAUSE_STEP_S``).
        """
        if "filter" in lags:
            self.filter_lag.measurements.append(lags["filter"])
        graph, graph_measured = self.graph_s()
        if graph_measured:
            self.parts["graph"].measurements.append(graph)
        for name in ("execution", "loudspeaker"):
            if name in lags:
                self.parts[name].measurements.append(lags[name])
        target = self.target_delay_s()
        most = MAX_PAUSE_STEP_S if pause else MAX_DELAY_STEP_S
        self.delay_s += min(max(target - self.delay_s, -most), most)

    def target_delay_s(self) -> float:
        """The delay the current estimates call for."""
        return voice_delay_s(*(p.value_s for p in self.parts.values()))

    def expected_offset_s(self) -> float:
        """``motion - heard`` with the delay in force (negative: the motion is ahead)."""
        parts = self.parts
        return (
            parts["graph"].value_s
            + parts["execution"].value_s
            - self.delay_s
            - parts["loudspeaker"].value_s
        )


@dataclass(frozen=True)
class Snapshot:
    """What :func:`measure` works on: stamped joint series and loudness pieces."""

    raw: tuple[np.ndarray, np.ndarray]
    commanded: tuple[np.ndarray, np.ndarray]
    measured: tuple[np.ndarray, np.ndarray]
    sent: list[tuple[float, np.ndarray]]
    heard: list[tuple[float, np.ndarray]]


def measure(snapshot: Snapshot) -> dict[str, float]:
    """The lags (s) that passed their score, by part.

    ``filter``: raw poses to commands; ``execution``: commands to measured joints;
    ``loudspeaker``: voice sent to the microphones.
    The heavy part of :meth:`SyncEstimator.update`; it touches nothing shared, so a node may
    run it on a thread of its own.
    """
    lags: dict[str, float] = {}
    (raw_t, raw), (cmd_t, cmd), (meas_t, meas) = (
        snapshot.raw,
        snapshot.commanded,
        snapshot.measured,
    )
    if raw.shape[1:] == cmd.shape[1:]:
        lag = motion_lag(raw_t, raw, cmd_t, cmd, MAX_MOTION_LAG_S)
        if lag.score >= MOTION_SCORE:
            lags["filter"] = lag.lag_s
    if cmd.shape[1:] == meas.shape[1:]:
        lag = motion_lag(cmd_t, cmd, meas_t, meas, MAX_MOTION_LAG_S)
        if lag.score >= MOTION_SCORE:
            lags["execution"] = lag.lag_s
    if snapshot.heard:
        lag = sound_lag(
            snapshot.sent, ENVELOPE_RATE_HZ, snapshot.heard, ENVELOPE_RATE_HZ, MAX_SOUND_LAG_S
        )
        if lag.score >= SOUND_SCORE:
            lags["loudspeaker"] = lag.lag_s
    return lags
