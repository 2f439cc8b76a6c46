"""Who holds the emergency stop: a stop is released only by the operator who pressed it.

An operator is one identified connection (a session id the server gives it, never anything
the page claims) shown by its display name, which the server makes unique among the
connected operators and the stop's holders (:func:`unique_name`): a page cannot take the name
of someone who holds the stop, nor be mistaken for them.

- Every operator who presses STOP holds the stop; the robot stays stopped while anyone holds it.
- Each holder releases only their own press (a release from anyone else is refused, naming the
  holders).
- A holder who leaves (page closed, connection lost) keeps holding. Another operator may then
  release that press, but only by naming that holder in the release (the page's confirmation
  button says whose stop it releases); a holder still connected cannot be overruled.
- At most :data:`MAX_PRESSES` presses are kept: beyond that a new press replaces the oldest one
  of someone who has left (the stop stays held, by the new press), so operators who press and
  leave over and over cannot grow the list without bound.
- A stop that the console did not press (another tool on the stop topic, or a press before the
  console restarted) is held by :data:`OUTSIDE`, released the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from audio2pose_ros.console.protocol import MAX_NAME_CHARS

__all__ = ["MAX_PRESSES", "OUTSIDE", "StopHolders", "StopPress", "unique_name"]

OUTSIDE = "outside the console"  # the holder of a stop the console's operators did not press
MAX_PRESSES = 100  # presses kept at once (those of connected operators are at most max_clients)


@dataclass
class StopPress:
    """One operator's press of STOP.

    Attributes:
        session: the id of the connection that pressed it.
        name: its operator's display name.
        present: the connection is still open.
    """

    session: int
    name: str
    present: bool = True


@dataclass
class StopHolders:
    """The presses of STOP not yet released, in the order they were made."""

    presses: list[StopPress] = field(default_factory=list)

    @property
    def held(self) -> bool:
        """Whether anyone holds the stop."""
        return bool(self.presses)

    def holds(self, session: int) -> bool:
        """Whether ``session`` holds the stop."""
        return any(p.session == session for p in self.presses)

    def press(self, session: int, name: str) -> bool:
        """``session`` presses STOP; True if it did not hold it yet."""
        if self.holds(session):
            return False
        if len(self.presses) >= MAX_PRESSES:
            absent = next((p for p in self.presses if not p.present), None)
            if absent is not None:
                self.presses.remove(absent)
        self.presses.append(StopPress(session, name))
        return True

    def release(self, session: int) -> bool:
        """``session`` releases its own press; True if it held one."""
        kept = [p for p in self.presses if p.session != session]
        released = len(kept) != len(self.presses)
        self.presses = kept
        return released

    def left(self, session: int) -> bool:
        """``session``'s connection has ended: its press stays, as held by someone absent.

        Returns:
            Whether it held the stop.
        """
        found = False
        for press in self.presses:
            if press.session == session:
                press.present, found = False, True
        return found

    def release_absent(self, name: str) -> bool:
        """Release the press of the absent holder called ``name``; True if there was one."""
        kept = [p for p in self.presses if p.present or p.name != name]
        released = len(kept) != len(self.presses)
        self.presses = kept
        return released

    def present_holders(self) -> list[str]:
        """Names of the holders still connected."""
        return [p.name for p in self.presses if p.present]

    def names(self) -> set[str]:
        """Names of every holder, present or not."""
        return {p.name for p in self.presses}

    def view(self) -> list[dict[str, object]]:
        """The holders for the pages: name and whether still connected, in press order."""
        return [{"name": p.name, "present": p.present} for p in self.presses]


def unique_name(wanted: str, taken: set[str]) -> str:
    """``wanted``, or ``wanted (2)``, ``(3)``... if it is ``taken`` (within the name's limit).

    :data:`OUTSIDE` is always taken, so no operator can pass for a stop from outside.
    """
    taken = taken | {OUTSIDE}
    if wanted not in taken:
        return wanted
    number = 2
    while True:
        suffix = f" ({number})"
        candidate = wanted[: MAX_NAME_CHARS - len(suffix)].rstrip() + suffix
        if candidate not in taken:
            return candidate
        number += 1
