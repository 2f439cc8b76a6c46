"""The input gate of the motion filter: raw targets are checked before any filter state sees them.

A raw pose from the model is a target for every joint. :class:`TrackGate` lets a pose through
to the jitter buffer only when it is plausible:

- **finite** (NaN and inf are rejected);
- **inside the joint's range**, give or take ``tolerance_rad``: a value a little outside (a model
  rounding over a limit) is clamped into the range, anything further out (90, 1e6, 1e308 rad) is
  rejected, so the unclamped value never reaches the smoother;
- **reachable from the recent track**: no joint may be further from the last accepted pose than
  the robot's velocity limit allows in the time between the two, plus ``tolerance_rad``. A
  one-frame spike is rejected; the track itself is kept.

Poses of one message are one filter period apart (the filter consumes one per tick), the first
at the message's arrival. A track that really moved on (after a gap the first pose is accepted
from anywhere in range, and a later rejected stream may be consistent with itself) is
re-acquired: ``REACQUIRE_POSES`` consecutive rejected poses that are plausible one after the
other become the new track, so a single wrong pose cannot lock the gate out of the real motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REACQUIRE_POSES = 5  # consecutive self-consistent poses that replace a track (0.05 s at 100 Hz)


@dataclass
class GateCounts:
    """Poses the gate refused since start, by reason (for diagnostics)."""

    non_finite: int = 0
    out_of_range: int = 0
    implausible: int = 0
    clamped: int = 0
    reacquired: int = 0


class TrackGate:
    """Range and plausibility check of raw poses against joint limits and the recent track."""

    def __init__(
        self,
        lower_rad: np.ndarray,
        upper_rad: np.ndarray,
        max_velocity_rad_s: np.ndarray,
        period_s: float,
        tolerance_rad: float,
    ) -> None:
        """Check against the given per-joint range and velocity, poses ``period_s`` apart.

        Args:
            lower_rad: (n_joints,) lower position limits.
            upper_rad: (n_joints,) upper position limits.
            max_velocity_rad_s: (n_joints,) fastest plausible motion of each joint.
            period_s: time between consecutive poses of one message.
            tolerance_rad: slack on both checks (range and reachability).
        """
        self.lower_rad = np.asarray(lower_rad, dtype=np.float64)
        self.upper_rad = np.asarray(upper_rad, dtype=np.float64)
        self.max_velocity_rad_s = np.asarray(max_velocity_rad_s, dtype=np.float64)
        self.period_s = period_s
        self.tolerance_rad = tolerance_rad
        self.counts = GateCounts()
        self._track: np.ndarray | None = None
        self._track_s = -np.inf
        self._candidate: np.ndarray | None = None
        self._candidate_s = -np.inf
        self._candidates = 0
        self.new_track_at: int | None = None  # of the last admit's result: first new-track pose

    def reset(self, pose_rad: np.ndarray | None = None, now_s: float = -np.inf) -> None:
        """Forget the track, or start it at ``pose_rad`` as of ``now_s``."""
        self._track = None if pose_rad is None else np.asarray(pose_rad, dtype=np.float64).copy()
        self._track_s = now_s
        self._candidate, self._candidates = None, 0

    def _reachable(self, pose: np.ndarray, reference: np.ndarray, elapsed_s: float) -> bool:
        bound = self.max_velocity_rad_s * max(elapsed_s, self.period_s) + self.tolerance_rad
        return bool((np.abs(pose - reference) <= bound).all())

    def admit(self, poses_rad: np.ndarray, now_s: float) -> np.ndarray:
        """The poses of one message that may enter the filter, clamped into the joint ranges.

        Args:
            poses_rad: (n_poses, n_joints) raw poses in time order.
            now_s: arrival time of the message (s, the filter's clock).

        Returns:
            (n_accepted, n_joints) accepted poses, in order; when a new track was taken,
            :attr:`new_track_at` is the index of its first pose among them (else None).
        """
        accepted: list[np.ndarray] = []
        self.new_track_at = None
        tolerance = self.tolerance_rad
        for i, pose in enumerate(np.asarray(poses_rad, dtype=np.float64)):
            pose_s = now_s + i * self.period_s
            if not np.isfinite(pose).all():
                self.counts.non_finite += 1
                continue
            if (pose < self.lower_rad - tolerance).any() or (
                pose > self.upper_rad + tolerance
            ).any():
                self.counts.out_of_range += 1
                continue
            clamped = np.minimum(np.maximum(pose, self.lower_rad), self.upper_rad)
            if (clamped != pose).any():
                self.counts.clamped += 1
            if self._track is None or self._reachable(clamped, self._track, pose_s - self._track_s):
                self._candidate, self._candidates = None, 0
            else:
                if self._candidate is not None and self._reachable(
                    clamped, self._candidate, pose_s - self._candidate_s
                ):
                    self._candidates += 1
                else:
                    self._candidates = 1
                self._candidate, self._candidate_s = clamped, pose_s
                if self._candidates < REACQUIRE_POSES:
                    self.counts.implausible += 1
                    continue
                self.counts.reacquired += 1
                self.new_track_at = len(accepted)
                self._candidate, self._candidates = None, 0
            self._track, self._track_s = clamped, max(pose_s, self._track_s + self.period_s)
            accepted.append(clamped)
        return np.array(accepted).reshape(-1, len(self.lower_rad))
