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

from audio2pose_ros.motion.state_file import FilterMemory


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
