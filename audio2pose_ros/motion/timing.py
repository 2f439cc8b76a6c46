"""Message stamps against the node's clock: a wild stamp is rejected, never the new time base.

``motion_filter_node`` orders raw trajectories by their header stamps (a duplicate or a late,
reordered message is dropped). A stamp far from the node's clock (once, one message
stamped 1e6 s in the future made every later message look late, forever) is rejected and
counted instead, and only accepted stamps move the ordering forward. A zero stamp means
"unstamped" and is accepted without ordering. When the clock itself steps back (an NTP or
chrony correction on a wall clock), the newest stamp seen lies ahead of the clock by more than a
stamp may: it is forgotten and the step counted, so motion resumes with the next message stamped
on the new clock instead of being dropped as out of order until the clock catches up.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class StampCounts:
    """Messages rejected by :class:`StampCheck`, by reason."""

    future: int = 0
    too_old: int = 0
    out_of_order: int = 0
    clock_steps_back: int = 0  # the newest accepted stamp lay ahead of the clock: forgotten


class StampCheck:
    """Accepts stamps within ``[now - max_age_s, now + max_future_s]`` that move forward."""

    def __init__(self, max_future_s: float, max_age_s: float) -> None:
        """Allow stamps up to ``max_future_s`` ahead of and ``max_age_s`` behind the clock."""
        self.max_future_s = max_future_s
        self.max_age_s = max_age_s
        self.counts = StampCounts()
        self.last_s = 0.0
        self.latency_s = 0.0

    def check(self, stamp_s: float, now_s: float) -> str:
        """'' when a message stamped ``stamp_s`` may be used at ``now_s``, else the reason why not.

        Accepting a stamp makes it the newest one seen and updates ``latency_s``.
        """
        if stamp_s == 0.0:
            return ""
        if self.last_s > now_s + self.max_future_s:  # the clock stepped back past it
            self.counts.clock_steps_back += 1
            self.last_s = 0.0
        if stamp_s > now_s + self.max_future_s:
            self.counts.future += 1
            return (
                f"stamp {stamp_s:.3f} s is {stamp_s - now_s:.3f} s ahead of the node clock "
                f"(max_stamp_future_s {self.max_future_s:g})"
            )
        if stamp_s < now_s - self.max_age_s:
            self.counts.too_old += 1
            return (
                f"stamp {stamp_s:.3f} s is {now_s - stamp_s:.3f} s behind the node clock "
                f"(max_stamp_age_s {self.max_age_s:g})"
            )
        if stamp_s <= self.last_s:
            self.counts.out_of_order += 1
            return "duplicated or out-of-order message (stamp not newer than the last one)"
        self.last_s = stamp_s
        self.latency_s = now_s - stamp_s
        return ""
