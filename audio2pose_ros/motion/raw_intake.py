"""Which raw poses reach the motion filter: one source, believable names and stamps, bounded.

A raw trajectory (from ``raw_trajectory``, or handed over directly in single-process mode) is
taken only from the one source in use (:class:`~audio2pose_ros.motion.sources.SingleSource`),
only when its joint names say one thing about each of the robot's joints (no joint listed
twice, which would leave the value to whichever the reader takes, and no joint the robot does
not have: the stream is another robot's or another model's; :meth:`RawIntake.joint_names`, as
the start pose refuses a joint listed twice on ``joint_states``), only once the filter has
started (its start pose is known), only with a stamp that is neither wild nor out of order
(:class:`~audio2pose_ros.motion.timing.StampCheck`), and only its first
``max_points_per_message`` poses; the filter's gate then checks each pose. What is dropped is
counted, and each reason is a :class:`~audio2pose_ros.motion.problems.Problem` for the node to
report.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Sequence

import numpy as np

from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.problems import Problem
from audio2pose_ros.motion.sources import SingleSource
from audio2pose_ros.motion.timing import StampCheck

CLOCK_STEP_HOLD_S = 10.0  # a clock step back is reported this long (it happens once)
SECOND_SOURCE_HOLD_S = 1.0  # a second source is reported until it has been quiet this long


class RawIntake:
    """The raw poses' way into one filter.

    Attributes:
        sources: the one source in use, and the others refused.
        stamps: the stamps' check (its limits follow the node's parameters).
        messages: raw messages (or hand-overs) that came since start.
        dropped: messages dropped whole (a second source, refused names or stamp, malformed).
        duplicate_names: messages refused because they list a joint more than once.
        unknown_names: messages refused because they name a joint the robot does not have.
    """

    def __init__(
        self, filt: MotionFilter, handover_s: float, max_future_s: float, max_age_s: float
    ) -> None:
        """Feed ``filt``; a source is given up after ``handover_s`` of silence (s)."""
        self.filter = filt
        self.sources = SingleSource(handover_s)
        self.stamps = StampCheck(max_future_s, max_age_s)
        self.messages = 0
        self.dropped = 0
        self.duplicate_names = 0
        self.unknown_names = 0
        self._names_taken: tuple[str, ...] = ()  # the last names taken (a stream repeats them)

    def from_source(self, source: Hashable, now_s: float) -> Problem | None:
        """None when a message of ``source`` (arriving at monotonic ``now_s``) may be used."""
        if self.sources.admit(source, now_s):
            return None
        self.dropped += 1
        return Problem(
            "raw_second_source",
            True,
            "a second publisher sends raw_trajectory: its poses are refused; only the first "
            "drives the robot (stop the other one)",
            SECOND_SOURCE_HOLD_S,
        )

    def joint_names(self, names: Sequence[str]) -> Problem | None:
        """None when a raw trajectory's joint ``names`` may be read; else refused (counted).

        A joint listed more than once, or a name the robot does not have, refuses the whole
        message (a WARN naming the joints): which of two values is meant cannot be told, and a
        stream naming joints this robot lacks is not meant for it. A joint of the robot that
        the message lacks is the reader's to refuse (a malformed message).
        """
        names = tuple(names)
        if names == self._names_taken:
            return None
        repeated = sorted(name for name, count in Counter(names).items() if count > 1)
        robot = set(self.filter.robot.names)
        unknown = sorted({name for name in names if name not in robot})
        if not repeated and not unknown:
            self._names_taken = names
            return None
        self.dropped += 1
        if repeated:
            self.duplicate_names += 1
            why = f"lists {_quoted(repeated)} more than once (which value is meant?)"
        else:
            self.unknown_names += 1
            why = f"names {len(unknown)} joint(s) this robot does not have ({_quoted(unknown)})"
        return Problem("raw_names", False, f"raw trajectory dropped: it {why}")

    def admit(
        self, stamp_s: float, n_points: int, now_s: float, started: bool
    ) -> tuple[int | None, list[Problem]]:
        """How many of a message's ``n_points`` poses to use (None: none), and what was wrong.

        None before the start and for a refused stamp (counted: a WARN); else at most
        ``max_points_per_message`` (the rest counted as truncated: a WARN). ``stamp_s`` is the
        message's stamp, ``now_s`` the node clock.
        """
        self.messages += 1
        if not started:
            return None, []  # the start pose is not known yet: generated motion waits
        problems = []
        steps_back = self.stamps.counts.clock_steps_back
        refused = self.stamps.check(stamp_s, now_s)
        if self.stamps.counts.clock_steps_back > steps_back:
            text = (
                "the clock stepped back behind the newest raw trajectory stamp: ordering "
                "restarted from the next message"
            )
            problems.append(Problem("clock_step", False, text, CLOCK_STEP_HOLD_S))
        if refused:
            self.dropped += 1
            problems.append(Problem("raw_stamp", False, f"raw trajectory dropped: {refused}"))
            return None, problems
        take = self.filter.points_to_take(n_points)
        if take < n_points:
            text = (
                f"raw trajectory longer than max_points_per_message "
                f"({self.filter.settings.max_points_per_message}): the rest dropped"
            )
            problems.append(Problem("raw_truncated", False, text))
        return take, problems

    def malformed(self, reason: str) -> Problem:
        """A message whose poses cannot be read (``reason``): dropped, a WARN."""
        self.dropped += 1
        return Problem("raw_malformed", False, f"raw trajectory dropped: {reason}")

    def push(self, poses_rad: np.ndarray, arrival_s: float) -> Problem | None:
        """Hand admitted poses to the filter (its gate); a WARN when it rejected some."""
        status = self.filter.status
        before = (status.rejected, status.out_of_range, status.implausible)
        self.filter.push(poses_rad, arrival_s)
        if (status.rejected, status.out_of_range, status.implausible) == before:
            return None
        return Problem(
            "raw_rejected",
            False,
            f"raw poses rejected before the filter: {status.rejected} non-finite, "
            f"{status.out_of_range} out of range, {status.implausible} unreachable (total)",
        )

    def values(self) -> dict[str, object]:
        """Messages taken and dropped, stamps refused by reason, and the input latency."""
        counts = self.stamps.counts
        return {
            "input_messages": self.messages,
            "dropped_messages": self.dropped,
            "raw_messages_of_a_second_source": self.sources.refused,
            "raw_refused_duplicate_names": self.duplicate_names,
            "raw_refused_unknown_names": self.unknown_names,
            "stale_messages_dropped": counts.out_of_order,
            "future_stamps_rejected": counts.future,
            "old_stamps_rejected": counts.too_old,
            "clock_steps_back": counts.clock_steps_back,
            "input_latency_ms": f"{self.stamps.latency_s * 1e3:.2f}",
        }


def _quoted(names: Sequence[str]) -> str:
    """The first few of ``names``, each cut short (a message may carry names of any length)."""
    return ", ".join(name[:40] for name in names[:5]) + (", ..." if len(names) > 5 else "")
