"""A problem the motion core finds, for the node to report on /diagnostics (ROS-free).

The core says what went wrong and how bad it is; ``motion_filter_node`` translates a
:class:`Problem` into its DiagnosticStatus (WARN or ERROR), reports it and clears it by its key.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Problem:
    """A problem for /diagnostics.

    Attributes:
        key: a stable identifier (the node reports and clears problems by it).
        error: ERROR when True, else WARN.
        text: one line saying what happened and what was done about it.
        hold_s: reported until this long after its last report (None: the node's default).
    """

    key: str
    error: bool
    text: str
    hold_s: float | None = None
