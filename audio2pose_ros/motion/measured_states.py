"""What the robot's measured joint states mean for the motion filter: its start, then a check.

``motion_filter_node`` hands every measured JointState to :class:`MeasuredStates` and translates
what comes back: the problems to report on /diagnostics and, once, the pose to start from.

Only a believable reading counts (:class:`~audio2pose_ros.motion.measured.MeasuredPoseCheck`):
a joint listed twice, or a stamp too old or ahead, is refused and reported (WARN); two
publishers whose poses disagree are an ERROR, and no pose of either is used while they do.
Before the start, a refused reading holds the start (ERROR: the robot's pose is published but
cannot be known); with more than one publisher on the topic (those the graph shows and those
heard) the start waits until the pose's publisher has been heard for a while and the others
have spoken, so a second source shows first
(:meth:`~audio2pose_ros.motion.start_pose.StartPose.listening`); every message that arrived is
told to the start (:meth:`~audio2pose_ros.motion.start_pose.StartPose.heard`). The first pose
used is the start pose, every valid joint of it
(:func:`~audio2pose_ros.motion.start_pose.repaired_start_pose`: repairs are WARNs). After the
start, the measured pose is checked against the commands
(:class:`~audio2pose_ros.motion.tracking.TrackingWatch`): a robot that does not follow them is
a WARN.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.measured import ANONYMOUS, SOURCE_WINDOW_S, MeasuredPoseCheck
from audio2pose_ros.motion.problems import Problem
from audio2pose_ros.motion.start_pose import StartPose, repaired_start_pose
from audio2pose_ros.motion.tracking import TrackingWatch
from audio2pose_ros.robot.description import RobotDescription

REPAIR_HOLD_S = 10.0  # a repaired start pose is reported this long (it happens once)


@dataclass
class MeasuredUse:
    """What one measured message means: problems over and new, and perhaps the start pose."""

    cleared: list[str] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    start_rad: np.ndarray | None = None  # start the filter from this pose (the measured one)


def start_held(doubt: str, topic: str) -> Problem:
    """ERROR: the start waits, commanding nothing, because of ``doubt``."""
    return Problem(
        "start_pose",
        True,
        f"{doubt}; commanding nothing until a believable pose arrives on {topic}",
        SOURCE_WINDOW_S,
    )


class MeasuredStates:
    """The robot's measured joint states: the start pose's decision, then the commands' check.

    Attributes:
        check: whether a reading can be believed, and its sources.
        start: which pose the filter starts from, and when.
        tracking: whether the robot follows its commands (fed the commands by the node).
        pose_rad: the last measured pose used (None: none yet).
        partial: messages without every joint of the robot (another robot's): not used.
        conflicts: poses ignored because two sources disagreed.
    """

    def __init__(
        self,
        robot: RobotDescription,
        now_s: float,
        measured_before: bool,
        without_measured: bool,
    ) -> None:
        """Watch ``robot``'s joints from ``now_s`` (monotonic; the start's clock starts there).

        ``measured_before``: the process before a restart heard the robot's measured pose.
        ``without_measured``: ``start_without_measured_pose`` (:class:`StartPose`).
        """
        self.robot = robot
        self.check = MeasuredPoseCheck(robot.names, robot.max_velocity_rad_s)
        self.start = StartPose(now_s, measured_before, without_measured)
        self.tracking = TrackingWatch()
        self.pose_rad: np.ndarray | None = None
        self.partial = 0
        self.conflicts = 0

    def take(
        self,
        names: Sequence[str],
        positions: Sequence[float],
        stamp_s: float,
        published_s: float | None,
        now_s: float,
        source: Hashable,
        arrival_s: float,
        started: bool,
        topic: str,
        publishers: Callable[[], Collection[Hashable]],
        saved_rad: Callable[[], np.ndarray | None],
    ) -> MeasuredUse:
        """One measured message: what it means (see the module's description).

        Args:
            names: the message's joint names.
            positions: its positions, one per name.
            stamp_s: its header stamp (s).
            published_s: when it was published (the publisher's clock), None when unknown.
            now_s: the node clock (what stamps are compared with).
            source: its publisher's identity.
            arrival_s: when it arrived (monotonic).
            started: whether the filter has started.
            topic: the measured states' topic (for the messages).
            publishers: the identities of the topic's publishers now, as the graph shows them
                (asked only before the start).
            saved_rad: the saved pose, if any (asked only at the start: it fills joints the
                measured pose lacks, else neutral does).

        Raises:
            InputError: the message is malformed (names and positions disagree).
        """
        use = MeasuredUse()
        check = self.check
        try:
            reading = check.read(names, positions, stamp_s, published_s, now_s, source, arrival_s)
        except InputError:
            self.start.heard(source, "broken", arrival_s)
            raise
        if source == ANONYMOUS:
            self.start.anonymous = check.anonymous_publishers(arrival_s)
        pose = reading.pose_rad
        usable = pose is not None and bool(np.isfinite(pose).any())
        self.start.heard(
            source, reading.kind if pose is None or usable else "non-finite", arrival_s
        )
        if reading.kind == "partial":
            self.partial += 1  # another robot's, or a partial message: not a pose
            return use
        if pose is None:
            use.problems.append(Problem("measured_refused", False, reading.reason))
            if not started:
                use.problems.append(
                    start_held(f"cannot tell where the robot is: {reading.reason}", topic)
                )
            return use
        if not usable:
            use.problems.append(
                Problem("measured_invalid", False, "measured joint states all non-finite")
            )
            return use
        if check.conflict(arrival_s):
            self.conflicts += 1
            held = (
                "measured poses ignored until one stops"
                if started
                else "cannot tell which is the robot: commanding nothing until one stops"
            )
            text = (
                f"{check.live_sources(arrival_s)} publishers send the robot's pose on {topic} "
                f"and disagree by {check.disagreement_rad(arrival_s):.2f} rad (another robot's "
                f"driver, a replay, a simulator?): {held}"
            )
            use.problems.append(Problem("measured_sources", True, text, SOURCE_WINDOW_S))
            return use
        if not started:
            self.start.discovered(publishers(), arrival_s)
            listening = self.start.listening(check.heard_for_s(source, arrival_s), arrival_s, topic)
            if listening:
                use.problems.append(Problem("start_pose", False, listening, SOURCE_WINDOW_S))
                return use
        assert pose is not None
        self.pose_rad = pose
        if not started:
            use.cleared.append("start_pose")
            use.start_rad = self._start_pose(pose, saved_rad(), use)
            return use
        lagging = self.tracking.measure(pose, arrival_s)
        if lagging is None:
            use.cleared.append("not_following")
            return use
        text = (
            f"the robot does not follow its commands: {self.robot.names[lagging.joint]} is "
            f"{lagging.off_rad:.2f} rad from what it was commanded over the last "
            f"{self.tracking.lag_s:g} s, for {lagging.for_s:.1f} s (motors off or resting, a "
            "joint blocked, or another controller moving it)"
        )
        use.problems.append(Problem("not_following", False, text))
        return use

    def _start_pose(
        self, pose: np.ndarray, saved: np.ndarray | None, use: MeasuredUse
    ) -> np.ndarray:
        """Every valid joint of a measured pose (:func:`repaired_start_pose`), repairs as WARNs."""
        robot = self.robot
        start, repairs = repaired_start_pose(
            pose,
            robot.names,
            robot.lower_rad,
            robot.upper_rad,
            robot.neutral_rad if saved is None else saved,
            "neutral pose" if saved is None else "saved pose",
        )
        for repair in repairs:
            text = f"measured joint states of {', '.join(repair.joints)} {repair.how}"
            use.problems.append(Problem("measured_invalid", False, text, REPAIR_HOLD_S))
        return start

    def doubt(self, now_s: float) -> str:
        """Why the measured joint states cannot be believed now ('' when nothing says so).

        Measured messages refused within ``SOURCE_WINDOW_S`` (a joint listed twice, an old or a
        future stamp), or live sources that disagree: the robot's pose is being published but
        cannot be known, so neither the saved pose nor neutral may stand in for it.
        """
        check = self.check
        if check.conflict(now_s):
            return f"{check.live_sources(now_s)} publishers send poses that disagree"
        if check.refusing(now_s):
            return check.last_reason
        return ""

    def values(self, now_s: float, commanded_rad: np.ndarray) -> dict[str, object]:
        """Measured states for /diagnostics: refused by reason, sources, how far from commands."""
        counts = self.check.counts
        values: dict[str, object] = {
            "measured_partial_messages": self.partial,
            "measured_refused_duplicate_names": counts.duplicate,
            "measured_refused_old_stamps": counts.old,
            "measured_refused_future_stamps": counts.future,
            "measured_unstamped": counts.unstamped,
            "measured_sources": self.check.live_sources(now_s),
            "measured_ignored_sources_disagree": self.conflicts,
        }
        if self.pose_rad is not None:
            deviation = np.abs(self.pose_rad - commanded_rad).max()
            values["measured_deviation_rad"] = f"{deviation:.3f}"
            values["measured_off_recent_commands_rad"] = f"{self.tracking.off_rad:.3f}"
        return values
