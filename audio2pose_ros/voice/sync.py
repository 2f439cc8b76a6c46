"""How long to hold the operator's voice back so that it is heard with the motion made from it.

A piece of speech arrives at the graph at ``a``. The motion made from it reaches Pepper's joints
at ``a + graph + execution``; its sound is heard from the loudspeakers at
``a + delay + loudspeaker``. The offset ``motion - heard`` must stay within
``[-WINDOW_EARLY_S, WINDOW_LATE_S]`` = [-80 ms, +20 ms]: people notice sound ahead of the
picture from about 45 ms and behind it from about 125 ms (ITU-R BT.1359), and a speaker's
gesture starts with the stressed syllable or a little before it, seldom after. The voice is
therefore delayed by ``graph + execution - loudspeaker + TARGET_LEAD_S`` (the motion 45 ms ahead
of the sound), never less than nothing. The motion path's own lag wanders from one stretch of
speech to the next, by some 20 ms earlier and 50 ms later than its median (measured at the
simulated Pepper, ``audio2pose bench --voice``), so the aim leaves 35 ms to the early edge of
the window and 65 ms to the late.

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

The loudspeaker plays what it is given back to back, so a chunk sent late (a loaded machine)
leaves every chunk after it waiting behind it, for as long as the voice goes on: that wait is
part of the voice's delay. The delay line is therefore asked for the delay minus what stands in
the loudspeaker's queue when it releases (:meth:`SyncEstimator.line_delay_s`), at once, not
through the slow median of a measured part.

A part not measured (no robot microphones, no measured joint states, too little speech or
motion yet) uses its documented default (:data:`DEFAULTS_S`) and says so. Each estimate is the
median of the recent measurements whose score passed its threshold, once there are
``MIN_MEASUREMENTS`` of them (one measurement taken while the motion filter starts is not the
graph's latency); a part's median only takes measurements made since the last update, never the
same one again. :attr:`SyncEstimator.delay_s` is the delay the estimates call for; the delay
line moves the voice to it gradually (:class:`~audio2pose_ros.voice.delay.DelayLine`), so the
voice never jumps. This module does not import rclpy.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.voice.lag import ENVELOPE_RATE_HZ, ChunkPairing, loudness, motion_lag, sound_lag

__all__ = [
    "CALIBRATED_WITHIN_S",
    "DEFAULTS_S",
    "MAX_DELAY_S",
    "MIN_MEASUREMENTS",
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
# Aimed at: the motion this long ahead of the sound (see the module text for why not the middle)
TARGET_LEAD_S = 0.045
MAX_DELAY_S = 1.0  # the voice is never held back longer
MIN_MEASUREMENTS = 3  # a part is measured once it has this many measurements (their median)
CALIBRATED_WITHIN_S = 0.005  # calibrated: every part measured, the delay in force this close
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
# Measurements kept per part, one a second at most: their median is the estimate. A long memory
# keeps the delay steady: a short one chases the motion lag's wander, seconds late,
# and so widens it; a lasting change (another robot, another network) is followed within ~20 s.
KEPT = 40


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
        """True once ``MIN_MEASUREMENTS`` measurements passed."""
        return len(self.measurements) >= MIN_MEASUREMENTS

    @property
    def value_s(self) -> float:
        """The median measurement once measured, or the part's default."""
        if self.measured:
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
    and sets :attr:`delay_s` to :func:`voice_delay_s` of the estimates (the delay line moves the
    voice there gradually).
    """

    def __init__(self, output_rate_hz: int) -> None:
        self.output_rate_hz = output_rate_hz
        self.pairing = ChunkPairing()
        self.parts = {name: PartEstimate(name, deque(maxlen=KEPT)) for name in DEFAULTS_S}
        self.raw = _Series()
        self.commanded = _Series()
        self.measured = _Series()
        self.sent: deque[tuple[float, np.ndarray]] = deque()
        self.waited_s = 0.0  # how long the last chunk sent waits for the loudspeaker
        self.heard: deque[tuple[float, np.ndarray]] = deque()
        self.heard_rate_hz = 0
        self.delay_s = self.target_delay_s()

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

    def on_sent(self, first_sample_s: float, mono: np.ndarray, waited_s: float = 0.0) -> None:
        """Voice samples handed to the loudspeaker, to start playing at ``first_sample_s``.

        ``waited_s``: how long they wait there for what was sent before them (the loudspeaker's
        queue when they were sent). Kept as their loudness
        (:func:`~audio2pose_ros.voice.lag.loudness`), as are the microphones'.
        """
        self._keep(self.sent, *loudness(first_sample_s, mono, self.output_rate_hz))
        self.waited_s = waited_s

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
        """The graph's latency and whether it is measured."""
        graph = self.parts["graph"]
        return graph.value_s, graph.measured

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

    def apply(self, lags: dict[str, float]) -> None:
        """Keep the lags :func:`measure` found (each once); set the delay they call for.

        The graph's latency is measured when the filter's lag is: the chunk-to-pose pairing's
        median then, plus that lag.
        """
        pairing = self.pairing.median_s()
        if "filter" in lags and math.isfinite(pairing):
            self.parts["graph"].measurements.append(pairing + lags["filter"])
        for name in ("execution", "loudspeaker"):
            if name in lags:
                self.parts[name].measurements.append(lags[name])
        self.delay_s = self.target_delay_s()

    def line_delay_s(self, queued_s: float) -> float:
        """What the delay line is asked for: the delay, less what the loudspeaker has queued.

        ``queued_s``: what stands in the loudspeaker's queue now
        (:meth:`~audio2pose_ros.voice.delay.SpeakerQueue.standing_s`). Not the wait of the last
        chunk sent: pauses skipped since then have shortened the queue, and a delay line asked
        for less by what is no longer queued would leave the voice early.
        """
        return max(self.delay_s - queued_s, 0.0)

    def target_delay_s(self) -> float:
        """The delay the current estimates call for."""
        return voice_delay_s(*(p.value_s for p in self.parts.values()))

    def expected_offset_s(self, in_force_s: float) -> float:
        """``motion - heard`` with the voice held back ``in_force_s`` (negative: motion ahead).

        ``in_force_s``: the delay line's delay and the loudspeaker's wait.
        """
        parts = self.parts
        return (
            parts["graph"].value_s
            + parts["execution"].value_s
            - in_force_s
            - parts["loudspeaker"].value_s
        )

    def calibrated(self, in_force_s: float) -> bool:
        """Every part measured and the voice held back ``in_force_s``, as they call for."""
        measured = all(part.measured for part in self.parts.values())
        return measured and abs(in_force_s - self.delay_s) <= CALIBRATED_WITHIN_S


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
    ``loudspeaker``: voice sent to the microphones (from when it should start playing).
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
