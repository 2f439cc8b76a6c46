"""One voice at a time: the floor of the console.

Only the operator who holds the floor talks to the robot; another one gets it only once the
holder releases it (the Talk button, or a closed page: the server releases the floor of a
connection that ends). Every page is told who holds it, by the name its operator gave.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Floor"]


@dataclass
class Floor:
    """Who may talk: at most one connection, by id, with its display name.

    Attributes:
        holder: the id of the connection that holds the floor, or None.
        holder_name: its operator's name ('' when free).
    """

    holder: int | None = None
    holder_name: str = ""

    def take(self, session: int, name: str) -> bool:
        """Give the floor to ``session`` if it is free (or already its own); True if it has it."""
        if self.holder is not None and self.holder != session:
            return False
        self.holder, self.holder_name = session, name
        return True

    def release(self, session: int) -> bool:
        """Free the floor if ``session`` holds it; True if it did."""
        if self.holder != session:
            return False
        self.holder, self.holder_name = None, ""
        return True

    def holds(self, session: int) -> bool:
        """Whether ``session`` holds the floor."""
        return self.holder == session

    def free_for(self, session: int) -> bool:
        """Whether ``session`` may act on the robot's settings: the floor is free or its own."""
        return self.holder is None or self.holder == session
