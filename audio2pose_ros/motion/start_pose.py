"""Which pose the motion filter starts from: the robot's measured pose, the saved one, or neutral.

After a start or restart nothing is commanded until the filter knows where the robot is. The
robot's measured pose (``joint_states``, checked by :mod:`audio2pose_ros.motion.measured`) is
the right start; the pose the filter last commanded (the state file,
:mod:`audio2pose_ros.motion.state_file`) or neutral stand in for it only when no measured pose
can still come. :class:`StartPose` tells the cases apart by what has happened, not by how long
start-up took, so a slow discovery on a loaded machine never makes the filter guess:

- **A publisher that has sent nothing yet** (it appeared on the topic, but no message of it has
  arrived) is waited for: its first message is on the way. A publisher counts from when this
  node discovered it: it is given :data:`MEASURED_WAIT_S` from then (a driver publishes at
  50 Hz; its first message comes in milliseconds once both ends have matched), however late the
  discovery came, at most until :data:`DISCOVERY_WAIT_S` + :data:`MEASURED_WAIT_S` after start.
- **No publisher yet, but the robot reported its pose before the restart** (the state file says
  so): its driver's discovery is waited for, up to :data:`DISCOVERY_WAIT_S` after start.
- **A usable pose has just arrived** (within :data:`POSE_FRESH_S`) but has not started the
  filter yet (it is listening for a second source): the start is the measured pose's.
- **Every publisher has sent messages, none a usable pose** (another robot's joints only, every
  joint not finite, a broken message): it is a source of nothing usable; the filter starts
  without it (after ``startup_timeout_s``) and says so (WARN), naming what came.
- **Nothing publishes, and nothing was reported before**: the saved pose, or neutral.
- **A pose is published but cannot be believed** (refused messages, disagreeing sources: the
  ``doubt`` of the measured check): the start holds, commanding nothing (ERROR); neither the
  saved pose nor neutral stands in for it.

With several publishers on the topic the start first listens :data:`MEASURED_LISTEN_S` to the
pose's publisher, so a second source shows before the first command (:meth:`StartPose.listening`).

:func:`repaired_start_pose` makes a measured start pose commandable: an out-of-range joint is
clamped, a NaN one taken from the saved pose or neutral, each repair named.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

MEASURED_WAIT_S = 3.0  # a discovered publisher's first message is awaited this long from then
DISCOVERY_WAIT_S = 10.0  # the robot reported its pose before: its driver is awaited this long
MEASURED_LISTEN_S = 1.0  # with several publishers, hear the pose's source this long first
POSE_FRESH_S = 1.0  # a usable pose heard this recently will start the filter: nothing else may

WAIT = "wait"  # command nothing yet: a usable measured pose may still come (WARN)
HOLD = "hold"  # command nothing: a pose is published but cannot be believed (ERROR)
SAVED = "saved pose"  # start from the pose saved in the state file
NEUTRAL = "neutral pose"  # start from the neutral pose


@dataclass(frozen=True)
class StartStep:
    """What the start does now.

    Attributes:
        action: :data:`WAIT`, :data:`HOLD`, :data:`SAVED` or :data:`NEUTRAL`.
        reason: one line for /diagnostics: why (what is awaited, what came instead).
    """

    action: str
    reason: str


class StartPose:
    """The start's view of the measured topic: its publishers and what each has sent.

    Times are one monotonic clock (s). The node tells it of every measured message that arrived
    (:meth:`heard`) and of the publishers it sees on the topic (:meth:`discovered`), and asks
    :meth:`decide` once the start-up timeout has passed, until the filter has started.
    """

    def __init__(self, created_s: float, reported_before: bool) -> None:
        """Start-up began at ``created_s``; ``reported_before``: the state file's ``measured``."""
        self.created_s = created_s
        self.reported_before = reported_before
        self.publishers = 0  # publishers on the topic when last told
        self.discovered_s = -math.inf  # when the count of publishers last rose
        self.sources: dict[Hashable, float] = {}  # publisher -> when its last usable pose came
        self.unusable: dict[str, int] = {}  # messages that came but were no pose, by kind

    def discovered(self, publishers: int, now_s: float) -> None:
        """``publishers`` publish on the measured topic now (the graph's count)."""
        if publishers > self.publishers:
            self.discovered_s = now_s
        self.publishers = publishers

    def heard(self, source: Hashable, kind: str, now_s: float) -> None:
        """A measured message of ``source`` arrived at ``now_s``: ``kind`` ``"pose"`` is usable.

        Kinds that are no usable pose: ``"partial"`` (not every joint of the robot),
        ``"non-finite"`` (no joint finite), ``"broken"`` (names and positions differ in number).
        A refused message (``"duplicate"``, ``"old"``, ``"future"``) is a doubt instead, which
        :meth:`decide` is given; it counts here as heard.
        """
        last_s = self.sources.get(source, -math.inf)
        if kind == "pose":
            self.sources[source] = now_s
        else:
            self.sources[source] = last_s
            self.unusable[kind] = self.unusable.get(kind, 0) + 1

    @property
    def silent(self) -> int:
        """Publishers on the topic that have not sent a single message yet."""
        return max(self.publishers - len(self.sources), 0)

    @property
    def awaits_driver(self) -> bool:
        """Nothing publishes or was heard, but the robot reported its pose before the restart."""
        return not self.publishers and not self.sources and self.reported_before

    def decide(self, now_s: float, doubt: str, topic: str, saved: str) -> StartStep:
        """What to do, the start-up timeout having passed and no usable pose having started it.

        Args:
            now_s: the clock now.
            doubt: why the measured pose cannot be believed now ('' when nothing says so).
            topic: the measured topic's name (for the reason).
            saved: the state file keeping a saved pose inside the joint ranges ('' when there
                is none).
        """
        if doubt:
            return StartStep(HOLD, f"cannot tell where the robot is: {doubt}")
        waited_s = now_s - self.created_s
        if any(now_s - last_s <= POSE_FRESH_S for last_s in self.sources.values()):
            return StartStep(
                WAIT,
                f"the robot's pose is arriving on {topic}: starting from it once it can be "
                "believed, commanding nothing",
            )
        if self.silent:
            until_s = min(
                self.discovered_s + MEASURED_WAIT_S,
                self.created_s + DISCOVERY_WAIT_S + MEASURED_WAIT_S,
            )
            if now_s < until_s:
                return StartStep(
                    WAIT,
                    f"{self.silent} publisher(s) on {topic} have sent nothing yet: waiting for "
                    f"the robot's pose (up to {until_s - now_s:.1f} s more), commanding nothing",
                )
        elif self.awaits_driver and waited_s < DISCOVERY_WAIT_S:
            return StartStep(
                WAIT,
                f"no publisher on {topic} yet, but the robot reported its pose before the "
                f"restart: waiting for its driver (up to {DISCOVERY_WAIT_S - waited_s:.1f} "
                "s more), commanding nothing",
            )
        return StartStep(SAVED if saved else NEUTRAL, self._why_without(topic, saved))

    def _why_without(self, topic: str, saved: str) -> str:
        if self.unusable:
            came = ", ".join(f"{n} {kind}" for kind, n in sorted(self.unusable.items()))
            what = (
                f"{len(self.sources)} publisher(s) on {topic} sent no usable pose of the "
                f"robot ({came})"
            )
        elif self.publishers:
            what = f"{self.publishers} publisher(s) on {topic} sent nothing"
        else:
            what = f"no measured pose on {topic}"
        if saved:
            return f"{what}: started from the last commanded pose saved in {saved}"
        return (
            f"{what} and no saved pose: started from the neutral pose; the first commands move "
            "the robot there at the velocity limit"
        )

    def listening(self, publishers: int, heard_for_s: float, topic: str) -> str:
        """Why a usable pose does not start the filter yet ('' when it does).

        With more than one publisher on the topic, the pose's publisher is heard for
        :data:`MEASURED_LISTEN_S` first, so that a second source shows before the start.
        """
        if publishers > 1 and heard_for_s < MEASURED_LISTEN_S:
            return (
                f"{publishers} publishers on {topic}: listening {MEASURED_LISTEN_S:g} s for a "
                "second source of the robot's pose before starting, commanding nothing"
            )
        return ""


@dataclass(frozen=True)
class Repair:
    """Joints of a measured start pose that were repaired, and how (one line)."""

    joints: tuple[str, ...]
    how: str


def repaired_start_pose(
    pose_rad: np.ndarray,
    names: Sequence[str],
    lower_rad: np.ndarray,
    upper_rad: np.ndarray,
    fallback_rad: np.ndarray,
    fallback: str,
) -> tuple[np.ndarray, list[Repair]]:
    """Every valid joint of a measured pose: out of range clamped, NaN from ``fallback_rad``.

    Args:
        pose_rad: the measured pose in the robot's joint order (may hold NaN, out-of-range).
        names: the robot's joint names.
        lower_rad: lower position limits.
        upper_rad: upper position limits.
        fallback_rad: where a joint that is not finite is taken from (the saved pose, neutral).
        fallback: what ``fallback_rad`` is, for the repair's line (e.g. ``"saved pose"``).

    Returns:
        The start pose (finite, inside the limits) and the repairs made.
    """
    finite = np.isfinite(pose_rad)
    outside = finite & ((pose_rad < lower_rad) | (pose_rad > upper_rad))
    repairs = []
    for mask, how in (
        (outside, "out of range, clamped into it"),
        (~finite, f"not finite, taken from the {fallback}"),
    ):
        if mask.any():
            repairs.append(Repair(tuple(n for n, bad in zip(names, mask, strict=True) if bad), how))
    return np.clip(np.where(finite, pose_rad, fallback_rad), lower_rad, upper_rad), repairs
