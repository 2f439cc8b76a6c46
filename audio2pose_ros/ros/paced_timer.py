"""The scheduler of the timers a node's safety depends on: :class:`PacedTimer`."""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.timer import Timer


class PacedTimer:
    """A periodic callback that a backlog of messages cannot delay by more than one callback.

    An executor decides the order in which it serves what is ready, and no node may depend on
    it: rclpy's EventsExecutor (opt-in, :mod:`audio2pose_ros.ros.executor`) serves events first
    come, first served, so a timer that falls due while messages arrive faster than the node
    serves them waits behind every message queued before it (a flooded simulated Pepper sent 0-2
    joint_states a second, and no heartbeat for seconds). A paced timer therefore also runs
    wherever the node gets control: after every guarded callback
    (:meth:`~audio2pose_ros.ros.diagnosed_node.DiagnosedNode.run_overdue_timers`) and between
    two executor rounds (:func:`~audio2pose_ros.ros.spin.spin_executor`), when it is more than
    ``OVERDUE_GRACE`` of its period past its due time (:meth:`run_if_overdue`, counted in
    ``runs_between_events``); when the executor's own timer comes later, it finds the run done
    and skips it (:meth:`on_timer`). Due times keep their phase: a timer served between
    callbacks keeps its rate, never bursts to make up for a missed period, and an idle node
    runs it from the executor's timer. Only rclpy's public Timer is used (its period, reset and
    cancel), the same on Humble, Jazzy and Kilted.

    The schedule may change while the node runs: :meth:`schedule` moves the next run (and the
    executor's timer, ``timer``, with it) and may give a new period, after which the runs
    follow that period again; :meth:`cancel` stops the runs until the next :meth:`schedule`.
    A run never starts inside the callback's own run (where a request served from the motion
    filter's tick runs the overdue timers, which would otherwise tick again within the tick).
    """

    OVERDUE_GRACE = 0.25  # of the period: a timer this late is run between events

    def __init__(
        self,
        period_s: float,
        callback: Callable[[], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Due first one period from now (``clock``), like rclpy's timer created beside it."""
        self.period_s = period_s
        self.callback = callback
        self.clock = clock
        self.next_due_s = clock() + period_s
        self.runs_between_events = 0
        self.cancelled = False
        self.timer: Timer | None = None  # the executor's timer (create_paced_timer), if any
        self._timer_ns = _period_ns(period_s)  # the executor's timer's period now
        self._running = False  # within the callback

    def schedule(self, delay_s: float, period_s: float | None = None) -> None:
        """Run next ``delay_s`` from now, then every ``period_s`` (None: the period in force).

        The executor's timer is re-programmed to fire then (a cancelled timer restarts).
        """
        if period_s is not None:
            self.period_s = period_s
        self.next_due_s = self.clock() + delay_s
        self.cancelled = False
        self._program(delay_s)

    def cancel(self) -> None:
        """No more runs until the next :meth:`schedule` (the executor's timer is cancelled)."""
        self.cancelled = True
        if self.timer is not None:
            self.timer.cancel()

    def on_timer(self) -> None:
        """The executor's timer event: run unless the last run already served this period."""
        now = self.clock()
        if not (self.cancelled or self._running) and now >= self.next_due_s - 0.5 * self.period_s:
            self._run(now)

    def run_if_overdue(self, now: float) -> None:
        """Run now if the executor's timer event is overdue (it waits behind messages)."""
        overdue = now >= self.next_due_s + self.OVERDUE_GRACE * self.period_s
        if overdue and not (self.cancelled or self._running):
            self.runs_between_events += 1
            self._run(now)

    def _run(self, now: float) -> None:
        self.next_due_s += self.period_s
        if self.next_due_s <= now:  # a whole period missed (a slow callback): no catch-up burst
            self.next_due_s = now + self.period_s
        if self._timer_ns != _period_ns(self.period_s):  # programmed for a scheduled delay
            self._program(self.period_s)
        self._running = True
        try:
            self.callback()
        finally:
            self._running = False

    def _program(self, delay_s: float) -> None:
        """The executor's timer fires ``delay_s`` from now, then every ``delay_s``."""
        if self.timer is None:
            return
        period_ns = _period_ns(delay_s)
        if period_ns != self._timer_ns:
            self.timer.timer_period_ns = self._timer_ns = period_ns
        self.timer.reset()


def _period_ns(period_s: float) -> int:
    """A timer period in whole nanoseconds, at least 1 (rcl refuses 0 for a periodic timer)."""
    return max(round(period_s * 1e9), 1)
