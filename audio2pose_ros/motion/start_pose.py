"""Which pose the motion filter starts from: the robot's measured pose, or nothing.

After a start or restart nothing is commanded until the filter knows where the robot is: the
robot's measured pose (``joint_states``, checked by :mod:`audio2pose_ros.motion.measured`). Not
knowing where the robot is never moves it: however long the discovery of its driver takes (a
robot over Wi-Fi can take seconds), the start waits, commanding nothing, and says why.
Starting from the pose the filter last commanded (the state file,
:mod:`audio2pose_ros.motion.state_file`) or from neutral without a measured pose is a choice
made in configuration (``start_without_measured_pose``, for a robot that publishes no joint
states, or no robot at all); no timeout makes it. :class:`StartPose` tells the cases apart by
what has happened, not by how long start-up took:

- **Nothing usable has come** (no publisher yet, a publisher that has not sent yet, publishers
  of other joints only, of no finite joint, of broken messages): the start waits (WARN), naming
  what came. Only with ``start_without_measured_pose`` does it start from the saved pose or
  neutral, once no measured pose can still come:

  - a publisher that has sent nothing yet (it appeared on the topic, but no message of it has
    arrived) is waited for :data:`MEASURED_WAIT_S` from when this node discovered it, at most
    until :data:`DISCOVERY_WAIT_S` + :data:`MEASURED_WAIT_S` after start;
  - with no publisher yet, but a robot that reported its pose before the restart (the state
    file says so), its driver is waited for up to :data:`DISCOVERY_WAIT_S` after start;
  - publishers that sent only messages that are no pose of the robot are not waited for.

- **A usable pose has just arrived** (within :data:`POSE_FRESH_S`) but has not started the
  filter yet (it is listening for a second source): the start is the measured pose's.
- **A pose is published but cannot be believed** (refused messages, disagreeing sources: the
  ``doubt`` of the measured check): the start holds, commanding nothing (ERROR); neither the
  saved pose nor neutral stands in for it, whatever the configuration.

The start goes ahead only on one believable source. The publishers of the topic are those the
graph shows (:meth:`StartPose.discovered`, by their identities) together with those heard
(:meth:`StartPose.heard`): a publisher whose first message arrives before the graph shows it
counts from that message. With more than one, the pose's publisher is heard for
:data:`MEASURED_LISTEN_S` first, and every other discovered publisher that has not sent yet is
awaited (up to :data:`MEASURED_WAIT_S` from its discovery), so that a second source of the
robot's pose shows before the first command (:meth:`StartPose.listening`); two that disagree
hold the start (ERROR) until one stops.

:func:`repaired_start_pose` makes a measured start pose commandable: an out-of-range joint is
clamped, a NaN one taken from the saved pose or neutral, each repair named.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.measured import ANONYMOUS

MEASURED_WAIT_S = 3.0  # a discovered publisher's first message is awaited this long from then
DISCOVERY_WAIT_S = 10.0  # the robot reported its pose before: its driver is awaited this long
MEASURED_LISTEN_S = 1.0  # with several publishers, hear the pose's source this long first
POSE_FRESH_S = 1.0  # a usable pose heard this recently will start the filter: nothing else may

WAIT = "wait"  # command nothing yet: a usable measured pose may still come (WARN)
HOLD = "hold"  # command nothing: a pose is published but cannot be believed (ERROR)
SAVED = "saved pose"  # start from the pose saved in the state file
NEUTRAL = "neutral pose"  # start from the neutral pose


UNKNOWN = ANONYMOUS  # the identity of a message whose publisher cannot be told (no gid given)


def identity(gid: bytes | str | Sequence[int]) -> Hashable:
    """A publisher's identity as the graph and a message's info both give it (its DDS gid).

    The graph's endpoint gid and a message's publisher gid can differ in length (the rmw pads
    the GUID to its gid storage size with zeros), so trailing zeros are dropped; a gid that is
    not bytes (an rmw's own form) is kept as it is.
    """
    return gid if isinstance(gid, str) else bytes(gid).rstrip(b"\0")


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
    Publishers are told apart by their identities (DDS gids); messages whose publisher cannot
    be told (:data:`UNKNOWN`: an rmw that gives no gid) count as the publishers their readings
    show (:attr:`anonymous`: tracks of poses that follow each other, and refusals).
    """

    def __init__(self, created_s: float, reported_before: bool, without_measured: bool) -> None:
        """Start-up began at ``created_s``.

        Args:
            created_s: when start-up began (monotonic, s).
            reported_before: the state file's ``measured`` (the robot reported its pose before
                the restart).
            without_measured: ``start_without_measured_pose``: the saved pose or neutral may
                stand in once no measured pose can still come; otherwise the start waits for
                one, however long.
        """
        self.created_s = created_s
        self.reported_before = reported_before
        self.without_measured = without_measured
        self.graph: dict[Hashable, float] = {}  # discovered publisher -> when first discovered
        self.sources: dict[Hashable, float] = {}  # publisher -> when its last usable pose came
        self.unusable: dict[str, int] = {}  # messages that came but were no pose, by kind
        self.anonymous = 0  # publishers that messages of UNKNOWN publishers show, live now

    def discovered(self, publishers: Collection[Hashable], now_s: float) -> None:
        """``publishers`` (their identities) publish on the measured topic now (the graph's)."""
        self.graph = {key: self.graph.get(key, now_s) for key in publishers}

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
    def publishers(self) -> int:
        """Publishers known on the topic: discovered, or heard before the graph showed them.

        Messages whose publisher cannot be told (:data:`UNKNOWN`) count as the publishers they
        show (:attr:`anonymous`, at least one once any came), which may be any of the
        discovered ones.
        """
        told = len(self.graph.keys() | (self.sources.keys() - {UNKNOWN}))
        return max(told, self.anonymous_heard)

    @property
    def anonymous_heard(self) -> int:
        """Publishers heard among those that cannot be told apart (0 when none came)."""
        return max(self.anonymous, 1) if UNKNOWN in self.sources else 0

    def silent(self, now_s: float) -> int:
        """Discovered publishers that have sent nothing yet and are still awaited.

        Each is awaited :data:`MEASURED_WAIT_S` from its discovery, at most until
        :data:`DISCOVERY_WAIT_S` + :data:`MEASURED_WAIT_S` after start. Messages whose publisher
        cannot be told may have come from any of them: as many fewer as they show are counted.
        """
        latest_s = self.created_s + DISCOVERY_WAIT_S + MEASURED_WAIT_S
        awaited = sum(
            1
            for key, found_s in self.graph.items()
            if key not in self.sources and now_s < min(found_s + MEASURED_WAIT_S, latest_s)
        )
        return max(awaited - self.anonymous_heard, 0)

    @property
    def awaits_driver(self) -> bool:
        """Nothing publishes or was heard, but the robot reported its pose before the restart."""
        return not self.publishers and self.reported_before

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
        if any(now_s - last_s <= POSE_FRESH_S for last_s in self.sources.values()):
            return StartStep(
                WAIT,
                f"the robot's pose is arriving on {topic}: starting from it once it can be "
                "believed, commanding nothing",
            )
        if not self.without_measured:
            return StartStep(
                WAIT,
                f"{self._what_came(topic, ' yet')}: waiting for the robot's measured pose, "
                "commanding nothing (a robot that publishes no joint states needs "
                "start_without_measured_pose: true)",
            )
        silent = self.silent(now_s)
        if silent:
            return StartStep(
                WAIT,
                f"{silent} publisher(s) on {topic} have sent nothing yet: waiting for the "
                "robot's pose, commanding nothing",
            )
        waited_s = now_s - self.created_s
        if self.awaits_driver and waited_s < DISCOVERY_WAIT_S:
            return StartStep(
                WAIT,
                f"no publisher on {topic} yet, but the robot reported its pose before the "
                f"restart: waiting for its driver (up to {DISCOVERY_WAIT_S - waited_s:.1f} "
                "s more), commanding nothing",
            )
        return StartStep(SAVED if saved else NEUTRAL, self._why_without(topic, saved))

    def _what_came(self, topic: str, so_far: str = "") -> str:
        """What the measured topic gave ``so_far``, none of it a usable pose (one clause)."""
        if self.unusable:
            came = ", ".join(f"{n} {kind}" for kind, n in sorted(self.unusable.items()))
            return (
                f"{len(self.sources)} publisher(s) on {topic} sent no usable pose of the "
                f"robot ({came})"
            )
        if self.publishers:
            return f"{self.publishers} publisher(s) on {topic} sent nothing{so_far}"
        return f"no measured pose on {topic} (no publisher)"

    def _why_without(self, topic: str, saved: str) -> str:
        what = f"{self._what_came(topic)}; start_without_measured_pose is true"
        if saved:
            return f"{what}: started from the last commanded pose saved in {saved}"
        return (
            f"{what} and there is no saved pose: started from the neutral pose; the first "
            "commands move the robot there at the velocity limit"
        )

    def listening(self, heard_for_s: float, now_s: float, topic: str) -> str:
        """Why a pose heard for ``heard_for_s`` does not start the filter yet ('' when it does).

        With more than one publisher known on the topic (:attr:`publishers`), the pose's
        publisher is heard for :data:`MEASURED_LISTEN_S` first, and the other discovered
        publishers that have not sent yet are awaited (:meth:`silent`), so that a second
        source of the robot's pose shows before the start.
        """
        publishers = self.publishers
        if publishers < 2:
            return ""
        if heard_for_s < MEASURED_LISTEN_S:
            return (
                f"{publishers} publishers on {topic}: listening {MEASURED_LISTEN_S:g} s for a "
                "second source of the robot's pose before starting, commanding nothing"
            )
        silent = self.silent(now_s)
        if silent:
            return (
                f"{publishers} publishers on {topic}, {silent} of them silent so far: waiting "
                "for what they send before starting, commanding nothing"
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
