"""A gentle approach to a track the filter has not been following (re-acquired, or resumed).

When the input gate takes a new track (``REACQUIRE_POSES`` self-consistent poses far from the
old one) or tracking resumes after the robot glided to neutral or waited, the wanted pose can be
far from where the robot is. Smoothing and the limits alone would move there at the full
velocity and acceleration limits; a short burst of consistent wrong poses would swing an arm by
a radian. :class:`Approach` blends from the commanded pose into the tracked one along a
minimum-jerk profile (:func:`minimum_jerk`) over a
time scaled to the distance, so no joint is driven faster than ``APPROACH_VELOCITY_FRACTION``
of its velocity limit by the blend: ``T = 1.875 * d / (f * v_max)`` (1.875 is the peak of the
minimum-jerk velocity profile over the mean), at least ``MIN_APPROACH_S``. A burst of 0.3 s
towards a pose 1.2 rad away thus moves the arm by millimetres before the real track returns.
"""

from __future__ import annotations

import numpy as np

APPROACH_VELOCITY_FRACTION = 0.25  # of each joint's velocity limit, at the blend's peak
MIN_APPROACH_S = 0.1  # shortest blend (a track that continues where the robot is)
MIN_JERK_PEAK = 1.875  # peak over mean velocity of the minimum-jerk profile


def minimum_jerk(fraction: float) -> float:
    """Position fraction of a minimum-jerk move at time fraction ``fraction`` in [0, 1].

    10 s^3 - 15 s^4 + 6 s^5: zero velocity and acceleration at both ends (Flash and Hogan's
    minimum-jerk profile; seed 003 section 3.4.4 cites minimum-jerk human movement).
    """
    s = min(max(fraction, 0.0), 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


class Approach:
    """Blends the tracked pose in from the pose the robot was at when a new track began."""

    def __init__(self) -> None:
        """No blend under way."""
        self._start: tuple[float, float, np.ndarray] | None = None  # (t0, duration, from pose)
        self.count = 0  # approaches begun since start

    @property
    def active(self) -> bool:
        """Whether a blend is under way."""
        return self._start is not None

    def begin(
        self,
        now_s: float,
        from_rad: np.ndarray,
        towards_rad: np.ndarray,
        max_velocity_rad_s: np.ndarray,
    ) -> None:
        """Blend from ``from_rad`` at ``now_s``, timed for the distance to ``towards_rad``.

        The blend's peak speed is ``APPROACH_VELOCITY_FRACTION`` of ``max_velocity_rad_s`` (the
        velocity limits in force) on the joint that has furthest to go, less on the others.
        """
        speed = APPROACH_VELOCITY_FRACTION * np.asarray(max_velocity_rad_s, dtype=np.float64)
        distance = np.abs(np.asarray(towards_rad, dtype=np.float64) - from_rad)
        duration = max(MIN_APPROACH_S, float(np.max(MIN_JERK_PEAK * distance / speed)))
        self._start = (now_s, duration, np.array(from_rad, dtype=np.float64))
        self.count += 1

    def cancel(self) -> None:
        """End the blend (the robot is no longer tracking)."""
        self._start = None

    def blend(self, tracked_rad: np.ndarray, now_s: float) -> np.ndarray:
        """The pose to want at ``now_s``: ``tracked_rad`` once the blend is over."""
        if self._start is None:
            return tracked_rad
        start_s, duration_s, from_rad = self._start
        fraction = (now_s - start_s) / duration_s
        if fraction >= 1.0:
            self._start = None
            return tracked_rad
        weight = minimum_jerk(fraction)
        return from_rad + weight * (tracked_rad - from_rad)
