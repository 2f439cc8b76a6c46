"""A stop or a disable in force: only a release published *after* it ends it.

``motion_filter_node`` takes ``stop`` and ``enable`` as latched std_msgs/Bool. A stop stays in
force, across restarts too (the state file keeps it), until a ``stop: false`` published after
the stop arrives, as does ``enable: false`` until a later ``enable: true``. "After" is judged by
the message's source timestamp (the publisher's wall clock, which DDS carries with every sample;
std_msgs/Bool has no stamp) against the time the hold came into force, so a ``stop: false`` an
older panel latched before the stop never releases it, whatever the restart timing and delivery
order. The machines' clocks must agree (NTP), as ROS 2 needs for tf anyway.

:class:`Hold` is that rule for one of the two (the node keeps one for the stop, one for the
disable); the node translates the messages and reports an ignored release.
"""

from __future__ import annotations

import math
from typing import TypeVar

from audio2pose_ros.motion.state_file import FilterMemory

K = TypeVar("K")
V = TypeVar("V")


class Hold:
    """A stop (or a disable): in force since a wall-clock time, or not in force.

    Attributes:
        since_s: when the hold in force came into force (wall clock, s since the epoch); None
            while none is in force.
    """

    def __init__(self, since_s: float | None = None) -> None:
        """A hold in force since ``since_s``, or none (None)."""
        self.since_s = since_s

    @classmethod
    def restored(cls, in_force: bool, since_s: float | None, saved_at_s: float) -> Hold:
        """The hold a state file kept: in force since ``since_s``, else since it was saved.

        Files written before the time of a hold was kept (``since_s`` None or 0) date it at
        their saving, the latest time it is known to have been in force.
        """
        return cls((since_s or saved_at_s) if in_force else None)

    @classmethod
    def kept(cls, memory: FilterMemory | None) -> tuple[Hold, Hold]:
        """The stop and the disable a state file's ``memory`` kept (none without a file)."""
        if memory is None:
            return cls(), cls()
        return (
            cls.restored(memory.stopped, memory.stopped_at_s, memory.saved_at_s),
            cls.restored(not memory.enabled, memory.disabled_at_s, memory.saved_at_s),
        )

    @property
    def in_force(self) -> bool:
        """Whether a hold is in force."""
        return self.since_s is not None

    def engage(self, published_s: float, now_s: float) -> None:
        """A hold published at ``published_s`` arrives at ``now_s`` (both wall clock).

        It is in force since its publication, at the latest now (a publisher whose clock runs
        ahead cannot pin a stop in the future); a later hold moves the time forward, an older
        one (delivered late) leaves it.
        """
        published_s = min(published_s, now_s)
        self.since_s = published_s if self.since_s is None else max(self.since_s, published_s)

    def release(self, published_s: float) -> bool:
        """End the hold, unless the release was published no later than it came into force.

        Returns:
            False: the release is older than the hold in force (an older panel's latched
            value, delivered again after a restart or after a newer hold) and is ignored;
            True: no hold is in force any more.
        """
        if self.since_s is not None and published_s <= self.since_s:
            return False
        self.since_s = None
        return True


MAX_REMEMBERED = 64  # holds taken and publishers' releases kept (the oldest forgotten first)


class HoldDeliveries:
    """The holds of one topic (``stop: true``, ``enable: false``) that two readers deliver.

    The node reads each of the two topics with a latched reader of depth 1 (the newest value of
    each publisher, also for a node that starts late) and, where the middleware filters content,
    with a second reader of the holds alone, which no flood of releases can displace a hold from.
    A hold delivered by both counts once, by its publisher and sequence number; and one its own
    publisher has already released by a later message (the other reader was served first) stays
    released. Releases of other publishers do not end a hold taken after them: only one that
    comes after it does (:class:`Hold`). Without the publisher's identity (Jazzy, Humble, the
    EventsExecutor) every delivery counts.

    Attributes:
        engaged: holds taken (each once).
    """

    def __init__(self) -> None:
        """No hold taken, no release heard."""
        self.taken: dict[tuple[bytes, int], None] = {}  # (publisher, sequence): insertion order
        self.released_s: dict[bytes, float] = {}  # publisher -> its newest release's publication
        self.engaged = 0

    def take(self, publisher: bytes | None, sequence: int | None, published_s: float) -> bool:
        """Whether a hold published at ``published_s`` engages (False: taken before or released).

        ``publisher`` and ``sequence`` identify the message (None where rclpy does not say).
        """
        if publisher is not None:
            if published_s < self.released_s.get(publisher, -math.inf):
                return False
            if sequence is not None:
                key = (publisher, sequence)
                if key in self.taken:
                    return False
                _remember(self.taken, key, None)
        self.engaged += 1
        return True

    def released(self, publisher: bytes | None, published_s: float) -> None:
        """A release of ``publisher`` published at ``published_s`` was taken."""
        if publisher is not None:
            newest = max(published_s, self.released_s.pop(publisher, -math.inf))
            _remember(self.released_s, publisher, newest)


def _remember(kept: dict[K, V], key: K, value: V) -> None:
    """Keep ``key`` as the newest entry of ``kept``, forgetting the oldest beyond the bound."""
    kept.pop(key, None)
    if len(kept) >= MAX_REMEMBERED:
        del kept[next(iter(kept))]
    kept[key] = value
