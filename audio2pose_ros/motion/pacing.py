"""When the motion filter ticks and when each of its outputs is published (ROS-free).

The filter ticks at ``rate_hz``: when a pose arrives into an empty buffer, so a steady stream is
commanded on arrival, and otherwise by a timer, one period after the previous tick, or two after a
tick at an arrival that left the buffer empty (:func:`arrival_wait_s`, :func:`next_timer_s`): the
timer stands in for input that is missing, not a period late. No two ticks are closer than
:data:`MIN_TICK_SPACING` periods: no bursts. Each output (``joint_angles``, ...) has its own rate,
at most the filter's, and keeps it on average when the ticks come late (:class:`OutputPacing`): it
is published at the first tick at most half a filter period before its due time, and its due
times keep their phase, one period apart. Two publications are never closer than its period less
one filter period (10 ms for 50 Hz at a 100 Hz filter clock), nor than half a filter period.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from audio2pose_ros.errors import ConfigurationError

TIME_TOLERANCE_S = 1e-9  # a tick exactly on a bound (rounded seconds) counts as on it
MIN_TICK_SPACING = 0.5  # of a period: an arriving pose is commanded at once if the last tick
# is at least this long ago (so ticks are never closer than half a period: no bursts)


def arrival_wait_s(last_tick_s: float, arrival_s: float, period_s: float) -> float:
    """How long after a pose arrives into an empty buffer to tick (0: at once).

    At once, or :data:`MIN_TICK_SPACING` periods after the last tick if that is later.
    """
    return max(last_tick_s + MIN_TICK_SPACING * period_s - arrival_s, 0.0)


def next_timer_s(period_s: float, queued: bool) -> float:
    """The timer's wait after a tick at a pose's arrival: a period if poses remain queued.

    Else 2 periods: the next pose of a steady stream arrives first, even up to a period late,
    and is commanded on arrival; the timer ticks only when a pose is missing. (At 1.5 periods a
    pose 5 ms late at 100 Hz let the timer command the previous pose again, ~15 ms old, and the
    late one was never commanded: the tail of ``audio2pose bench --graph``'s latency.)
    """
    return period_s if queued else 2.0 * period_s


class OutputPacing:
    """Which outputs are due at a tick; each keeps its own rate on the filter's clock."""

    def __init__(self, rates_hz: Mapping[str, float], filter_rate_hz: float) -> None:
        """Pace outputs at ``rates_hz`` (0: off) on a filter clock of ``filter_rate_hz``.

        Raises:
            ConfigurationError: an output's rate exceeds the filter's (the key names the
                parameter ``<output>_rate_hz``).
        """
        period_s = 1.0 / filter_rate_hz
        for name, rate in rates_hz.items():
            if rate > filter_rate_hz:
                raise ConfigurationError(
                    f"parameter {name}_rate_hz: value {rate!r} is out of range; allowed: 0 "
                    f"(off) to rate_hz = {filter_rate_hz:g}"
                )
        #: least time between two publications of each output that is on (s)
        self.spacing_s = {
            name: max(1.0 / rate - period_s, 0.5 * period_s)
            for name, rate in rates_hz.items()
            if rate > 0
        }
        self._period_s = {name: 1.0 / rates_hz[name] for name in self.spacing_s}
        self._early_s = 0.5 * period_s  # a tick this close before the due time publishes
        self._last_s = dict.fromkeys(self.spacing_s, -math.inf)
        self._next_s = dict.fromkeys(self.spacing_s, -math.inf)

    def due(self, tick_s: float) -> list[str]:
        """The outputs due at a tick at ``tick_s`` (each counts as published then).

        An output's next due time is one period after its last one, so ticks that come late
        (every 13 ms on a loaded machine) publish a 50 Hz output at 20 ms on average, not at
        every second tick (26 ms); once a whole period behind, it counts again from this tick,
        with no burst to catch up.
        """
        due = []
        for name, last_s in self._last_s.items():
            next_s = self._next_s[name]
            if tick_s - last_s < self.spacing_s[name] - TIME_TOLERANCE_S or (
                tick_s < next_s - self._early_s - TIME_TOLERANCE_S
            ):
                continue
            due.append(name)
            self._last_s[name] = tick_s
            period_s = self._period_s[name]
            self._next_s[name] = (
                next_s + period_s if tick_s - next_s < period_s else tick_s + period_s
            )
        return due
