"""One master for the raw poses: a second publisher on ``raw_trajectory`` is refused, not mixed.

Two sources of raw poses at once (a second inference node, a replayed recording, a test tool)
interleave two tracks: the filter would jump between them, the arms oscillating at the velocity
limit. :class:`SingleSource` follows one publisher (by its DDS publisher gid) and refuses the
others' messages; the source in use is given up only once it has been silent for
``handover_s``, so a restarted inference node takes over (after its old publisher went quiet),
while two live publishers never drive the robot together. While a refused source has been heard
within ``handover_s``, :attr:`SingleSource.rivals` says so, for an ERROR on /diagnostics.
"""

from __future__ import annotations

from collections.abc import Hashable


class SingleSource:
    """Admits the messages of one source at a time (keys are publisher identities)."""

    def __init__(self, handover_s: float) -> None:
        """Follow one source; switch only after it has been silent for ``handover_s``."""
        self.handover_s = handover_s
        self.current: Hashable | None = None
        self._current_s = -float("inf")
        self._others: dict[Hashable, float] = {}
        self.refused = 0  # messages of other sources refused since start

    def admit(self, source: Hashable, now_s: float) -> bool:
        """Whether a message of ``source`` arriving at ``now_s`` may drive the robot."""
        if source == self.current or now_s - self._current_s > self.handover_s:
            if source != self.current:
                self._others.pop(source, None)
                self.current = source
            self._current_s = now_s
            return True
        self._others[source] = now_s
        self.refused += 1
        return False

    def rivals(self, now_s: float) -> int:
        """How many other sources were refused within the last ``handover_s``."""
        for key in [k for k, t in self._others.items() if now_s - t > self.handover_s]:
            del self._others[key]
        return len(self._others)
