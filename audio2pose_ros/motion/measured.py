"""Is a measured joint state the robot's? Checks before the filter believes ``joint_states``.

The motion filter starts from the robot's measured pose (``joint_states``, published by
naoqi_driver), so the first command is only as right as that message. Believed blindly, a
message could put the first command 1.37 rad away from the real robot:

- **A joint listed twice.** A JointState whose names repeat one of the robot's joints says two
  things about it; taking the last (or the first) is a guess. Such a message is refused.
- **Old or future stamps.** A second publisher replaying an old pose (a bag, a stuck relay) or a
  clock an hour ahead. The header stamp is checked against the node clock: older than
  :data:`MAX_AGE_S` or further ahead than :data:`MAX_FUTURE_S` is refused. **A zero stamp** (a
  driver that does not stamp) is judged by the time the message was published instead, which
  DDS carries with every sample (the publisher's clock); without that, by its arrival: a driver
  that does not stamp is believed as fresh as it is delivered.
- **Two sources.** Two publishers sending the robot's whole pose (a second robot's driver on the
  same topic, a simulator left running) are two sources. Their readings are compared at nearby
  stamps: two readings of one robot differ by at most its velocity limit times the time between
  them (counted up to :data:`MOTION_ALLOWANCE_S`), plus :data:`AGREE_TOLERANCE_RAD`; more than
  that, within :data:`SOURCE_WINDOW_S` of each other, is a conflict. While there is one, no
  pose of either can be told to be the robot's. A publisher that sends other joints only (a
  gripper, another robot's partial state) is none. At most :data:`MAX_SOURCES` sources are
  compared; more at once count as a conflict.
- **Publishers that cannot be told apart.** Where rclpy gives no publisher gid (Jazzy, Humble)
  every message's publisher is :data:`ANONYMOUS`. Its readings are then sorted into tracks,
  each a source of its own: a reading joins the nearest track whose newest reading it can
  follow (it differs from it by at most the velocity limit times the time between them,
  counted up to :data:`MOTION_ALLOWANCE_S` beyond their arrivals, plus
  :data:`AGREE_TOLERANCE_RAD`), or starts a new one. Two drivers that disagree make two
  tracks, and so a conflict, as two gids would; two that agree are one track, which is as
  believable as either.

:class:`MeasuredPoseCheck` keeps what it needs for that and says, for each message, what it is;
the node decides what to do (``ros/nodes/motion_filter_node.py``: refuse, report, hold the start).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.errors import InputError

MAX_AGE_S = 2.0  # a measured pose stamped longer ago than this is not where the robot is now
MAX_FUTURE_S = 0.5  # ...nor one stamped further ahead of the node clock than this
SOURCE_WINDOW_S = 1.0  # a source heard within this long is live (and compared with the others)
AGREE_TOLERANCE_RAD = 0.1  # two readings of one robot differ by no more (beyond its velocity)
MOTION_ALLOWANCE_S = 0.05  # ...and the velocity limit excuses at most this much stamp difference
READINGS_KEPT = 64  # readings per source kept for the comparison (over a second at 50 Hz)
MAX_SOURCES = 8  # live sources compared at most; more at once is a conflict by itself
ANONYMOUS = b""  # the source of a message whose publisher cannot be told (no gid given)


@dataclass(frozen=True)
class Track:
    """A source made of anonymous readings that follow each other (see the module)."""

    number: int


@dataclass(frozen=True)
class Reading:
    """What one measured JointState is.

    Attributes:
        pose_rad: the robot's joints in its own order (None unless ``kind`` is ``"pose"``).
        kind: ``"pose"`` (a believable reading of every joint), ``"partial"`` (not every joint
            of the robot: another robot's or another part's), or a refusal: ``"duplicate"``,
            ``"old"``, ``"future"``.
        reason: for a refusal, one line saying why (names the joint or the stamp).
    """

    pose_rad: np.ndarray | None
    kind: str
    reason: str = ""


@dataclass
class _Source:
    readings: deque[tuple[float, np.ndarray]] = field(
        default_factory=lambda: deque(maxlen=READINGS_KEPT)
    )  # (stamp s, pose)
    first_heard_s: float = math.inf
    last_heard_s: float = -math.inf

    def follows(
        self, stamp_s: float, pose: np.ndarray, arrival_s: float, limit: np.ndarray
    ) -> float:
        """By how much ``pose`` leaves what the newest reading allows (rad; <= 0: it follows)."""
        last_stamp_s, last_pose = self.readings[-1]
        gap_s = min(abs(stamp_s - last_stamp_s), arrival_s - self.last_heard_s + MOTION_ALLOWANCE_S)
        off = np.abs(pose - last_pose) - limit * max(gap_s, 0.0)
        finite = np.isfinite(off)
        return float(off[finite].max()) if finite.any() else 0.0


@dataclass
class MeasuredCounts:
    """Measured messages by what they were, since start."""

    poses: int = 0
    partial: int = 0
    duplicate: int = 0
    old: int = 0
    future: int = 0
    unstamped: int = 0  # zero header stamp: judged by the publication time instead


class MeasuredPoseCheck:
    """Reads measured JointStates for one robot and watches their sources.

    Times: ``now_s`` is the node clock (seconds since the epoch, what stamps are compared with),
    ``arrival_s`` a monotonic clock (when sources were heard).
    """

    def __init__(self, joint_names: Sequence[str], max_velocity_rad_s: np.ndarray) -> None:
        """Check readings of the joints ``joint_names`` (the robot's order) and their speeds."""
        self.names = tuple(joint_names)
        self.max_velocity_rad_s = np.asarray(max_velocity_rad_s, dtype=np.float64)
        self.counts = MeasuredCounts()
        self.last_refused_s = -math.inf  # arrival of the last refused message (monotonic)
        self.last_reason = ""
        self._sources: dict[Hashable, _Source] = {}
        self.crowded_s = -math.inf  # arrival of the last pose of a source beyond MAX_SOURCES
        self._tracks = 0  # anonymous tracks begun
        self.last_track: Hashable = ANONYMOUS  # the track of the newest anonymous reading
        self.anonymous_refused_s = -math.inf  # arrival of the last refused anonymous message

    def read(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        stamp_s: float,
        published_s: float | None,
        now_s: float,
        source: Hashable,
        arrival_s: float,
    ) -> Reading:
        """What the message (``names``, ``positions``, header ``stamp_s``) is.

        Args:
            names: the JointState's joint names.
            positions: its positions, one per name.
            stamp_s: its header stamp (s; 0 = not stamped).
            published_s: when it was published (DDS source timestamp, s), if known.
            now_s: the node clock now (s).
            source: the publisher's identity (its DDS gid).
            arrival_s: monotonic time of arrival.

        Raises:
            InputError: names and positions differ in number (a broken message).
        """
        if len(names) != len(positions):
            raise InputError(
                f"measured joint states: {len(names)} names, {len(positions)} positions"
            )
        ours = set(self.names)
        repeated = sorted(n for n, k in Counter(names).items() if k > 1 and n in ours)
        if repeated:
            self.counts.duplicate += 1
            return self._refuse(
                "duplicate",
                f"measured joint states list {', '.join(repeated)} more than once: refused "
                "(which of the values is the robot's?)",
                arrival_s,
                source,
            )
        index = {name: i for i, name in enumerate(names)}
        if any(name not in index for name in self.names):
            self.counts.partial += 1
            return Reading(None, "partial")
        if stamp_s == 0.0:
            self.counts.unstamped += 1
            stamp_s = published_s if published_s else now_s
        if stamp_s < now_s - MAX_AGE_S:
            self.counts.old += 1
            return self._refuse(
                "old",
                f"measured joint states stamped {now_s - stamp_s:.1f} s ago (at most "
                f"{MAX_AGE_S:g} s): refused, not where the robot is now",
                arrival_s,
                source,
            )
        if stamp_s > now_s + MAX_FUTURE_S:
            self.counts.future += 1
            return self._refuse(
                "future",
                f"measured joint states stamped {stamp_s - now_s:.1f} s ahead of this node's "
                f"clock (at most {MAX_FUTURE_S:g} s): refused",
                arrival_s,
                source,
            )
        pose = np.array([positions[index[name]] for name in self.names], dtype=np.float64)
        if source == ANONYMOUS:
            source = self._track_of(stamp_s, pose, arrival_s)
        if source not in self._sources and self.live_sources(arrival_s) >= MAX_SOURCES:
            self.crowded_s = arrival_s  # not compared (bounded work), but not believed either
            return Reading(pose, "pose")
        heard = self._sources.setdefault(source, _Source())
        heard.first_heard_s = min(heard.first_heard_s, arrival_s)
        heard.last_heard_s = arrival_s
        heard.readings.append((stamp_s, pose))
        self.counts.poses += 1
        return Reading(pose, "pose")

    def _track_of(self, stamp_s: float, pose: np.ndarray, arrival_s: float) -> Hashable:
        """The anonymous track that ``pose`` follows best, or a new one (see the module)."""
        self.live_sources(arrival_s)
        best: Hashable | None = None
        nearest_rad = math.inf
        for key, heard in self._sources.items():
            if not isinstance(key, Track):
                continue
            if (
                heard.follows(stamp_s, pose, arrival_s, self.max_velocity_rad_s)
                > AGREE_TOLERANCE_RAD
            ):
                continue
            apart = np.abs(pose - heard.readings[-1][1])
            finite = np.isfinite(apart)
            distance_rad = float(apart[finite].max()) if finite.any() else 0.0
            if distance_rad < nearest_rad:  # the nearest of those it can follow
                best, nearest_rad = key, distance_rad
        if best is None:
            best = Track(self._tracks)
            self._tracks += 1
        self.last_track = best
        return best

    def anonymous_publishers(self, arrival_s: float) -> int:
        """Publishers that anonymous messages show now: live tracks, one more if any refused.

        A publisher whose messages are all refused (a stale replay) has no track; its refusals
        within :data:`SOURCE_WINDOW_S` count as one publisher.
        """
        self.live_sources(arrival_s)
        tracks = sum(1 for key in self._sources if isinstance(key, Track))
        return tracks + int(arrival_s - self.anonymous_refused_s <= SOURCE_WINDOW_S)

    def _refuse(self, kind: str, reason: str, arrival_s: float, source: Hashable) -> Reading:
        self.last_refused_s = arrival_s
        if source == ANONYMOUS:
            self.anonymous_refused_s = arrival_s
        self.last_reason = reason
        return Reading(None, kind, reason)

    def refusing(self, arrival_s: float) -> bool:
        """Whether a message was refused within the last :data:`SOURCE_WINDOW_S`."""
        return arrival_s - self.last_refused_s <= SOURCE_WINDOW_S

    def live_sources(self, arrival_s: float) -> int:
        """Sources that sent a pose within the last :data:`SOURCE_WINDOW_S` (older forgotten)."""
        for key in [
            k for k, s in self._sources.items() if arrival_s - s.last_heard_s > SOURCE_WINDOW_S
        ]:
            del self._sources[key]
        return len(self._sources)

    def heard_for_s(self, source: Hashable, arrival_s: float) -> float:
        """How long ``source`` has been sending poses (0 when it is not live).

        For :data:`ANONYMOUS`, the track of the newest anonymous reading.
        """
        heard = self._sources.get(self.last_track if source == ANONYMOUS else source)
        return 0.0 if heard is None else max(arrival_s - heard.first_heard_s, 0.0)

    def disagreement_rad(self, arrival_s: float) -> float:
        """How far the live sources disagree, beyond what one moving robot explains (rad).

        Each source's newest reading is compared with each other source's reading nearest in
        stamp: per joint, the difference less the velocity limit times the stamp difference (at
        most :data:`MOTION_ALLOWANCE_S` of it, so stamps set apart on purpose excuse no more).
        0 with fewer than two live sources.
        """
        self.live_sources(arrival_s)
        sources = list(self._sources.values())
        worst = 0.0
        for a in sources:
            stamp_a, pose_a = a.readings[-1]
            for b in sources:
                if b is a:
                    continue
                stamp_b, pose_b = min(b.readings, key=lambda r: abs(r[0] - stamp_a))
                if abs(stamp_b - stamp_a) > SOURCE_WINDOW_S:
                    continue
                gap_s = min(abs(stamp_b - stamp_a), MOTION_ALLOWANCE_S)
                allowed = self.max_velocity_rad_s * gap_s
                off = np.abs(pose_a - pose_b) - allowed
                finite = np.isfinite(off)
                if finite.any():
                    worst = max(worst, float(off[finite].max()))
        return worst

    def conflict(self, arrival_s: float) -> bool:
        """Whether two live sources disagree by more than :data:`AGREE_TOLERANCE_RAD`.

        More than :data:`MAX_SOURCES` live sources at once count as a conflict too: they are
        not all compared (the work per message stays bounded), so none can be believed.
        """
        if arrival_s - self.crowded_s <= SOURCE_WINDOW_S:
            return True
        return self.disagreement_rad(arrival_s) > AGREE_TOLERANCE_RAD
