"""Does the robot follow its commands? The robot's measured joint states against recent commands.

A filter that commands perfectly safe motion is of no use when the robot does not carry it out:
its motors are off or resting, an arm is blocked, or another controller (naoqi's autonomous life,
a teleoperation tool) moves the same joints. The motion filter node reports that on /diagnostics.

A real robot follows with a lag (transport, its own controller), so a measured angle is compared
with the range of angles commanded over the last ``lag_s``, not with the newest command: a joint
is off by how far it lies outside that range. Only a joint off by more than ``tolerance_rad`` for
``hold_s`` without a break counts, so a brief lag behind a fast gesture does not. The price: a
joint that stops inside the range it swept over the last ``lag_s`` is found only once its commands
move on.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

TRACKING_TOLERANCE_RAD = 0.15  # a joint this far outside its recent commands is not following
TRACKING_LAG_S = 0.5  # the robot may lag its commands by this much
TRACKING_HOLD_S = 1.0  # ...and be off for this long before it is reported


@dataclass(frozen=True)
class NotFollowing:
    """The robot has not followed its commands for a while.

    Attributes:
        joint: index of the joint furthest off (in the robot description's order).
        off_rad: how far that joint lies outside the range it was commanded over the lag.
        for_s: how long some joint has been off by more than the tolerance.
    """

    joint: int
    off_rad: float
    for_s: float


class TrackingWatch:
    """Compares measured poses with the poses commanded over the last ``lag_s``.

    :meth:`command` is fed every commanded pose, :meth:`measure` every measured one; times are
    seconds of one monotonic clock.
    """

    def __init__(
        self,
        tolerance_rad: float = TRACKING_TOLERANCE_RAD,
        lag_s: float = TRACKING_LAG_S,
        hold_s: float = TRACKING_HOLD_S,
    ) -> None:
        """Watch with the given tolerance, allowed lag and holding time (all positive)."""
        if not (tolerance_rad > 0 and lag_s > 0 and hold_s > 0):
            raise ValueError(
                f"tolerance, lag and hold must be positive, got {tolerance_rad}, {lag_s}, {hold_s}"
            )
        self.tolerance_rad = tolerance_rad
        self.lag_s = lag_s
        self.hold_s = hold_s
        self._commands: deque[tuple[float, np.ndarray]] = deque()
        self._off_since_s: float | None = None
        self.off_rad = 0.0  # how far the last measured pose lay outside its recent commands

    def command(self, pose_rad: np.ndarray, now_s: float) -> None:
        """The pose commanded at ``now_s`` (poses older than ``lag_s`` before it are forgotten)."""
        self._commands.append((now_s, np.array(pose_rad, dtype=float)))
        while len(self._commands) > 1 and self._commands[1][0] <= now_s - self.lag_s:
            self._commands.popleft()

    def measure(self, pose_rad: np.ndarray, now_s: float) -> NotFollowing | None:
        """The pose measured at ``now_s``: the finding when the robot has not followed for long.

        Nothing is known (None) before the first command, after ``lag_s`` without one (nothing
        is commanded, so the robot may be anywhere), or for a pose that is not finite.
        """
        pose = np.asarray(pose_rad, dtype=float)
        if (
            not self._commands
            or now_s - self._commands[-1][0] > self.lag_s
            or pose.shape != self._commands[-1][1].shape
            or not np.isfinite(pose).all()
        ):
            self._off_since_s, self.off_rad = None, 0.0
            return None
        recent = np.stack([p for t, p in self._commands if t >= now_s - self.lag_s])
        off = np.maximum(recent.min(axis=0) - pose, pose - recent.max(axis=0)).clip(min=0.0)
        joint = int(off.argmax())
        self.off_rad = float(off[joint])
        if self.off_rad <= self.tolerance_rad:
            self._off_since_s = None
            return None
        if self._off_since_s is None:
            self._off_since_s = now_s
        off_for_s = now_s - self._off_since_s
        return NotFollowing(joint, self.off_rad, off_for_s) if off_for_s >= self.hold_s else None
