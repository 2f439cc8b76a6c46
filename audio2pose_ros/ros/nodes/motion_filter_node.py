"""motion_filter_node: raw poses in; smooth, limited commands for naoqi, ros2_control, viewers out.

Subscriptions:
    raw_trajectory (trajectory_msgs/JointTrajectory): poses from inference_node (any joint order).
    voice_activity (std_msgs/Bool): from audio_features_node; silence -> glide to neutral.
    (In single-process mode those two nodes call this one directly instead of these two topics.)
    enable (std_msgs/Bool, latched): False -> glide to neutral and ignore generated motion.
    stop (std_msgs/Bool, latched): True -> emergency stop ('hold': brake and stay; 'neutral').
    head_target (sensor_msgs/JointState): absolute HeadYaw/HeadPitch targets, e.g. a look-at.
    head_offset (sensor_msgs/JointState): HeadYaw/HeadPitch offsets added to the head motion.
    joint_states (sensor_msgs/JointState, parameter measured_joint_states_topic): the robot's
        measured joint states (naoqi_driver publishes them); the filter starts from them, and a
        robot that does not follow its commands is reported (``motion.tracking``).
Publications:
    joint_angles (naoqi_bridge_msgs/JointAnglesWithSpeed): for naoqi_driver (absolute angles).
    joint_trajectory_controller/joint_trajectory (trajectory_msgs/JointTrajectory): one point,
        for ros2_control's joint_trajectory_controller.
    commanded_joint_states (sensor_msgs/JointState): the commanded pose, for
        robot_state_publisher / RViz in simulation (never ``joint_states``: on a robot that topic
        carries the driver's measured states).
    /diagnostics (diagnostic_msgs/DiagnosticArray): heartbeat, counters, problems.
Parameters: the fields of MotionFilterSettings, StyleSettings (the style: per part a size and a
    tempo, the arms' rest and height), LimitSettings and MotionFilterNodeSettings
    (``ros2 param describe`` shows each one's description and range).

Safety: every command passes the input gate first and the joint limiter last; the node
publishes nothing until it knows where the robot is. Which pose it starts from (the measured
pose, every valid joint of it; else, once none can still come, the pose it last commanded, saved
in ``state_file``, or neutral) is :mod:`audio2pose_ros.motion.start_pose`'s decision; whether a
measured pose can be believed, :mod:`audio2pose_ros.motion.measured`'s (a joint listed twice, a
stamp too old or ahead: refused, WARN; two publishers that disagree: ERROR, neither used, and
the start holds, commanding nothing, until the conflict has been over for ``SOURCE_WINDOW_S``).

Parameter requests: the node's services (rclpy's parameter services) are served at most
``REQUESTS_PER_TICK`` per tick (:class:`~audio2pose_ros.ros.request_budget.RequestBudget`); a
request is validated at once and its settings reach the filter at the next tick, once per tick
however many came, so a storm of set_parameters requests delays answers, never commands.

Stop and disable: a stop stays in force across restarts until a ``stop: false`` *published
after the stop* arrives, as does ``enable: false`` until a later ``enable: true``. "After" is
judged by the message's source timestamp (the publisher's wall clock, which DDS carries with
every sample; std_msgs/Bool has no stamp) against the time the stop came into force (saved in
the state file), so a ``stop: false`` an older panel latched before the stop never releases it,
whatever the restart timing and delivery order. The machines' clocks must agree (NTP), as ROS 2
needs for tf anyway. A stop, a disable and the pose are saved when they change, at most every
``MIN_SAVE_SPACING_S``; a state that cannot be saved is an ERROR on /diagnostics (the stop stays
in force in memory), reported again at every start. The state file is this node's alone: a
second live node with the same file refuses to start (exit 78, naming the file).

One master: raw poses are taken from one ``raw_trajectory`` publisher at a time (its gid); a
second one is refused and reported as ERROR until it stops, and the first is given up only
after it has been silent for ``watchdog_timeout_s`` (then the filter approaches the new track
gently).

Timing: the filter ticks at ``rate_hz``, at the latest one period after the
previous tick and early when a pose arrives into an empty buffer (at most ``MIN_TICK_SPACING``
periods after the previous tick), so a steady stream is commanded on arrival. Each output is
published at the tick nearest to its own period, never less than its period minus half a filter
period after the previous one (its documented minimum spacing: 15 ms for 50 Hz at a 100 Hz
filter clock). Header stamps are the time the command was computed for (the tick), not the
publish time. An output nobody subscribes to is not built nor sent.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.exceptions import InvalidTopicNameException
from rclpy.qos import qos_profile_sensor_data
from rclpy.subscription import MessageInfo
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.body_guard import GuardStatus
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_settings import MotionFilterNodeSettings, MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.motion.measured import SOURCE_WINDOW_S, MeasuredPoseCheck
from audio2pose_ros.motion.sources import SingleSource
from audio2pose_ros.motion.start_pose import HOLD, WAIT, StartPose, repaired_start_pose
from audio2pose_ros.motion.state_file import (
    MIN_SAVE_SPACING_S,
    FilterMemory,
    StateFileInUseError,
    StateStore,
    default_state_path,
)
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.motion.timing import StampCheck
from audio2pose_ros.motion.tracking import TrackingWatch
from audio2pose_ros.parameters import ParameterValue, settings_from, settings_with, specs_of
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.diagnosed_node import LATCHED_QOS, STREAM_QOS, DiagnosedNode
from audio2pose_ros.ros.messages import trajectory_msg, trajectory_positions
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.request_budget import RequestBudget
from audio2pose_ros.ros.spin import run_node

MIN_TICK_SPACING = 0.5  # of a period: an arriving pose is commanded at once if the last tick
# is at least this long ago (so ticks are never closer than half a period: no bursts)
STALLED_PERIODS = 10  # no tick for this many periods while started: ERROR (commands stalled)
STARTUP_CHECK_NS = 100_000_000  # while the start waits, it is decided again this often (0.1 s)
REQUESTS_PER_TICK = 1  # service requests (set_parameters, ...) served per tick at most


SETTINGS_CLASSES = (MotionFilterSettings, StyleSettings, LimitSettings, MotionFilterNodeSettings)
# A JointState of a whole humanoid (names, positions, velocities, efforts) is a few KiB.
MAX_JOINT_STATE_BYTES = 65536


def trajectory_bytes_cap(max_points: int, n_joints: int) -> int:
    """Largest raw_trajectory decoded: ``max_points`` points carrying all four arrays (bytes).

    A point of CDR holds four float64 arrays (positions, velocities, accelerations, efforts;
    4-byte length each) and a Duration; beyond the cap the message is dropped before decoding,
    so the work of one message stays bounded (decoding costs about 9 us per point in rclpy).
    """
    per_point = 4 * (4 + 8 * n_joints) + 8
    return 1024 + 64 * n_joints + max_points * per_point


PARAMETERS = tuple(spec for cls in SETTINGS_CLASSES for spec in specs_of(cls))
OUTPUT_RATES = ("joint_angles_rate_hz", "joint_trajectory_rate_hz", "joint_states_rate_hz")


def _stamp_s(stamp: object) -> float:
    return stamp.sec + stamp.nanosec * 1e-9  # type: ignore[attr-defined]


def _published_s(info: MessageInfo) -> float:
    """When a message was published (publisher's wall clock); its arrival when not carried."""
    source_ns = info.get("source_timestamp") or info.get("received_timestamp") or 0
    return source_ns * 1e-9 if source_ns else time.time()


def _publisher_of(info: MessageInfo) -> bytes | str:
    """The identity of a message's publisher (its DDS gid)."""
    gid = info.get("publisher_gid") or {}
    return bytes(gid.get("data", b"")) if isinstance(gid, dict) else repr(gid)


class MotionFilterNode(DiagnosedNode):
    """Gate, pace, smooth and limit poses; publish them in three message types."""

    def __init__(self, subscribe_graph: bool = True) -> None:
        """Declare parameters, build the filter, wire topics and timers (nothing is commanded yet).

        Args:
            subscribe_graph: take raw poses and voice activity from the ``raw_trajectory`` and
                ``voice_activity`` topics; False in single-process mode, where the other two
                nodes call :meth:`on_poses` and :meth:`on_voice_active` directly.

        Raises:
            ConfigurationError: a parameter or the robot description is refused.
        """
        super().__init__("motion_filter_node")
        # settings validated at a set_parameters request, for the filter's next tick
        self.pending_settings: tuple[MotionFilterSettings, LimitSettings, StyleSettings] | None = (
            None
        )
        self.parameters = NodeParameters(self, PARAMETERS, apply=self.apply_parameters)
        values = self.parameters.values
        self.settings: MotionFilterNodeSettings = settings_from(MotionFilterNodeSettings, values)
        settings: MotionFilterSettings = settings_from(MotionFilterSettings, values)
        for name in OUTPUT_RATES:
            rate = getattr(self.settings, name)
            if rate > settings.rate_hz:
                raise ConfigurationError(
                    f"parameter {name}: value {rate!r} is out of range; allowed: 0 (off) to "
                    f"rate_hz = {settings.rate_hz:g}"
                )
        try:
            self.robot = load_robot(self.settings.robot_description or None)
        except (OSError, ValueError) as exc:
            raise ConfigurationError(f"parameter robot_description: {exc}") from None
        self.filter = MotionFilter(
            self.robot,
            settings,
            settings_from(LimitSettings, values),
            style=settings_from(StyleSettings, values),
        )
        self.stamps = StampCheck(self.settings.max_stamp_future_s, self.settings.max_stamp_age_s)
        self.input_messages = 0
        self.dropped_messages = 0
        self.poses_at_last_report = 0
        self.last_report_s = time.monotonic()
        self.faults_seen = 0
        self.ticks = 0  # filter ticks since start (each may serve one service request)
        self.lead_outs_seen = 0
        self.started_from = ""
        self.measured_rad: np.ndarray | None = None
        self.measured_partial = 0  # joint states without every joint of the robot: not used
        self.measured_check = MeasuredPoseCheck(self.robot.names, self.robot.max_velocity_rad_s)
        self.measured_conflicts = 0  # poses ignored because two sources disagreed
        self.tracking = TrackingWatch()

        self.state_path = (
            Path(self.settings.state_file).expanduser()
            if self.settings.state_file
            else default_state_path(self.get_fully_qualified_name())
        )
        try:
            self.state = StateStore(self.state_path, self.robot)
        except StateFileInUseError as exc:
            raise ConfigurationError(f"parameter state_file: {exc}") from None
        self._report_state_file()
        self.memory = self.state.memory
        self.start_pose = StartPose(
            time.monotonic(), self.memory is not None and self.memory.measured
        )
        # wall-clock times the stop and the disable in force came into force (None: not in force)
        self.stop_since_s: float | None = None
        self.disable_since_s: float | None = None
        memory = self.memory
        if memory is not None and memory.stopped:
            self.stop_since_s = memory.stopped_at_s or memory.saved_at_s
            self.filter.set_stop(True)
            self.get_logger().warning(
                f"STOP in force from before the restart ({self.state_path}); publish "
                "stop: false to release it"
            )
        if memory is not None and not memory.enabled:
            self.disable_since_s = memory.disabled_at_s or memory.saved_at_s
            self.filter.set_enabled(False)
            self.get_logger().warning(
                f"disabled from before the restart ({self.state_path}): generated motion is "
                "ignored; publish enable: true to enable it"
            )
        self.sources = SingleSource(settings.watchdog_timeout_s)

        guarded, bounded = self.guarded, self.create_bounded_subscription
        if subscribe_graph:
            bounded(
                JointTrajectory,
                topics.RAW_TRAJECTORY,
                self.on_raw,
                STREAM_QOS,
                lambda: trajectory_bytes_cap(
                    int(self.parameters["max_points_per_message"]), self.robot.n_joints
                ),
                with_info=True,
            )
            self.create_subscription(
                Bool, topics.VOICE_ACTIVITY, guarded(self.on_voice), STREAM_QOS
            )
        self.create_subscription(Bool, topics.ENABLE, guarded(self.on_enable), LATCHED_QOS)
        self.create_subscription(Bool, topics.STOP, guarded(self.on_stop), LATCHED_QOS)
        bounded(JointState, topics.HEAD_TARGET, self.on_head_target, 10, MAX_JOINT_STATE_BYTES)
        bounded(JointState, topics.HEAD_OFFSET, self.on_head_offset, 10, MAX_JOINT_STATE_BYTES)
        try:
            bounded(
                JointState,
                self.settings.measured_joint_states_topic,
                self.on_measured,
                qos_profile_sensor_data,
                MAX_JOINT_STATE_BYTES,
                with_info=True,  # the publisher's gid (sources) and source stamp (unstamped)
            )
        except (InvalidTopicNameException, ValueError):
            raise ConfigurationError(
                f"parameter measured_joint_states_topic: value "
                f"{self.settings.measured_joint_states_topic!r} is not a valid topic name"
            ) from None
        # rclpy's parameter services (all the node's services): a few requests per tick at most
        self.request_budget = RequestBudget(REQUESTS_PER_TICK)
        self.request_budget.adopt_services(self)
        self.period_ns = round(self.filter.period_s * 1e9)
        self.tick_timer = self.create_timer(self.filter.period_s, guarded(self.on_timer))
        self.startup_timer = self.create_timer(
            max(self.settings.startup_timeout_s, 1e-3), guarded(self.on_startup_timeout)
        )
        self.create_timer(self.settings.state_save_period_s, guarded(self.save_state))
        self.create_timer(MIN_SAVE_SPACING_S, guarded(self._save_if_due))
        self.last_tick_s = -math.inf
        self.tick_stamp = self.get_clock().now()
        outputs = {
            "joint_angles": (JointAnglesWithSpeed, topics.JOINT_ANGLES, self.publish_joint_angles),
            "joint_trajectory": (
                JointTrajectory,
                topics.JOINT_TRAJECTORY,
                self.publish_joint_trajectory,
            ),
            "joint_states": (JointState, topics.COMMANDED_JOINT_STATES, self.publish_joint_states),
        }
        self.publishers_by_output = {}
        # (minimum spacing in s, time of the last publication, publish callback, publisher);
        # an output is built and sent only while something subscribes to it
        self.outputs: list[list[Any]] = []
        for key, (msg_type, topic, callback) in outputs.items():
            rate_hz = getattr(self.settings, f"{key}_rate_hz")
            if rate_hz > 0:
                publisher = self.create_publisher(msg_type, topic, 10)
                self.publishers_by_output[key] = publisher
                spacing = max(1.0 / rate_hz - 0.5 * self.filter.period_s, 0.0)
                self.outputs.append([spacing, -math.inf, callback, publisher])
        self.get_logger().info(
            f"{self.robot.n_joints} joints at {settings.rate_hz:g} Hz, {settings.smoothing} "
            f"smoothing, outputs: {', '.join(self.publishers_by_output) or 'none'}; waiting up "
            f"to {self.settings.startup_timeout_s:g} s for the measured pose on "
            f"{self.settings.measured_joint_states_topic}"
        )

    # --- parameters ---------------------------------------------------------------------------

    def apply_parameters(self, changes: Mapping[str, ParameterValue]) -> None:
        """Validate a run-time change as a whole now; the filter takes it at the next tick.

        A request costs a validation (no filter, limiter or body model is built here); the
        filter's settings change once per tick, however many requests came since the last one
        (the newest wins), so a storm of set_parameters requests never holds up a command.

        Raises:
            ConfigurationError: the new combination is refused (nothing changes then).
        """
        node_settings = settings_with(self.settings, changes)
        filter_settings, limit_settings, style_settings = self.pending_settings or (
            self.filter.settings,
            self.filter.limiter.settings,
            self.filter.style.settings,
        )
        filter_settings = settings_with(filter_settings, changes)
        limit_settings = settings_with(limit_settings, changes)
        style_settings = settings_with(style_settings, changes)
        self.filter.check_settings(filter_settings, limit_settings)
        if (filter_settings, limit_settings, style_settings) != (
            self.filter.settings,
            self.filter.limiter.settings,
            self.filter.style.settings,
        ):
            self.pending_settings = (filter_settings, limit_settings, style_settings)
        else:
            self.pending_settings = None
        self.settings = node_settings
        self.stamps.max_future_s = node_settings.max_stamp_future_s
        self.stamps.max_age_s = node_settings.max_stamp_age_s

    def _take_pending_settings(self) -> None:
        """Hand the filter the settings requested since the last tick (once per tick)."""
        if self.pending_settings is not None:
            pending, self.pending_settings = self.pending_settings, None
            self.filter.update_settings(*pending)

    # --- start-up -----------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        """Whether the filter knows where the robot is (and commands are published)."""
        return bool(self.started_from)

    def _report_state_file(self) -> None:
        """WARN about a state file that cannot be used; ERROR when it cannot be locked."""
        if self.state.lock_problem:
            self._unsaved(self.state.lock_problem)
        if self.state.read_problem:
            ignored = f"state file ignored: {self.state.read_problem}"
            self.report_problem("state_file", DiagnosticStatus.WARN, ignored)
        if self.state.pose_refused:
            self.report_problem(
                "saved_pose_refused",
                DiagnosticStatus.WARN,
                f"the pose saved in {self.state_path} lies outside the joint ranges: refused "
                "(its stop and enable are kept)",
                hold_s=10.0,
            )

    def _saved_pose(self) -> np.ndarray | None:
        """The saved pose, when there is one inside the joint ranges."""
        return self.state.saved_pose()

    def _unsaved(self, reason: str) -> None:
        """The state cannot be saved: an ERROR until a save succeeds (the stop stays in memory)."""
        stopped = " The STOP in force" if self.filter.status.stopped else " A stop"
        self.report_problem(
            "state_file_unsaved",
            DiagnosticStatus.ERROR,
            f"state file {self.state_path}: {reason}.{stopped} stays in force in this process "
            "but will NOT survive a restart",
            hold_s=math.inf,
        )

    def _start(self, pose_rad: np.ndarray, source: str) -> None:
        self.filter.start_from(pose_rad)
        self.started_from = source
        self.last_tick_s = time.monotonic()  # the stall check counts from here
        self.startup_timer.cancel()
        self.save_state()

    def _measured_start_pose(self, pose: np.ndarray) -> np.ndarray:
        """Every valid joint of a measured pose (:func:`repaired_start_pose`), repairs as WARNs."""
        saved = self._saved_pose()
        start, repairs = repaired_start_pose(
            pose,
            self.robot.names,
            self.robot.lower_rad,
            self.robot.upper_rad,
            self.robot.neutral_rad if saved is None else saved,
            "neutral pose" if saved is None else "saved pose",
        )
        for repair in repairs:
            self.report_problem(
                "measured_invalid",
                DiagnosticStatus.WARN,
                f"measured joint states of {', '.join(repair.joints)} {repair.how}",
                hold_s=10.0,
            )
        return start

    def on_measured(self, msg: JointState, info: MessageInfo | None = None) -> None:
        """The robot's measured joint states: the start pose, then checked against the commands.

        Only a believable reading counts (:mod:`audio2pose_ros.motion.measured`): a joint listed
        twice, or a stamp too old or ahead, is refused and reported (WARN); two publishers whose
        poses disagree are an ERROR, and no pose of either is used while they do. With more
        than one publisher on the topic, the start waits until the pose's publisher has been
        heard for a while (:meth:`StartPose.listening`), so a second source shows first. Every
        message that arrived is told to the start (:meth:`StartPose.heard`).
        """
        arrival_s = time.monotonic()
        source: bytes | str = b""  # called directly (tests): no publisher to tell apart
        published_ns = 0
        if info is not None:
            source, published_ns = _publisher_of(info), info.get("source_timestamp") or 0
        try:
            reading = self.measured_check.read(
                msg.name,
                msg.position,
                _stamp_s(msg.header.stamp),
                published_ns * 1e-9 if published_ns else None,
                self.now_s(),
                source,
                arrival_s,
            )
        except InputError:
            self.start_pose.heard(source, "broken", arrival_s)
            raise
        pose = reading.pose_rad
        usable = pose is not None and bool(np.isfinite(pose).any())
        kind = reading.kind if pose is None or usable else "non-finite"
        self.start_pose.heard(source, kind, arrival_s)
        if reading.kind == "partial":
            self.measured_partial += 1  # another robot's, or a partial message: not a pose
            return
        if pose is None:
            self.report_problem("measured_refused", DiagnosticStatus.WARN, reading.reason)
            if not self.started:
                self._hold_start(f"cannot tell where the robot is: {reading.reason}")
            return
        if not usable:
            self.report_problem(
                "measured_invalid", DiagnosticStatus.WARN, "measured joint states all non-finite"
            )
            return
        topic = self.settings.measured_joint_states_topic
        if self.measured_check.conflict(arrival_s):
            self.measured_conflicts += 1
            held = (
                "measured poses ignored until one stops"
                if self.started
                else "cannot tell which is the robot: commanding nothing until one stops"
            )
            self.report_problem(
                "measured_sources",
                DiagnosticStatus.ERROR,
                f"{self.measured_check.live_sources(arrival_s)} publishers send the robot's "
                f"pose on {topic} and disagree by "
                f"{self.measured_check.disagreement_rad(arrival_s):.2f} rad (another robot's "
                f"driver, a replay, a simulator?): {held}",
                hold_s=SOURCE_WINDOW_S,
            )
            return
        if not self.started:
            listening = self.start_pose.listening(
                self.count_publishers(topic),
                self.measured_check.heard_for_s(source, arrival_s),
                topic,
            )
            if listening:
                self.report_problem(
                    "start_pose", DiagnosticStatus.WARN, listening, hold_s=SOURCE_WINDOW_S
                )
                return
        assert pose is not None
        self.measured_rad = pose
        if not self.started:
            self.clear_problem("start_pose")
            self._start(self._measured_start_pose(pose), "measured pose")
            self.get_logger().info("starting from the robot's measured pose")
            return
        lagging = self.tracking.measure(pose, time.monotonic())
        if lagging is None:
            self.clear_problem("not_following")
            return
        self.report_problem(
            "not_following",
            DiagnosticStatus.WARN,
            f"the robot does not follow its commands: {self.robot.names[lagging.joint]} is "
            f"{lagging.off_rad:.2f} rad from what it was commanded over the last "
            f"{self.tracking.lag_s:g} s, for {lagging.for_s:.1f} s (motors off or resting, a "
            "joint blocked, or another controller moving it)",
        )

    def on_startup_timeout(self) -> None:
        """No measured pose started the filter in time: decide (:class:`StartPose`) what now.

        Called when ``startup_timeout_s`` has passed, then every 0.1 s while the start waits:
        it waits (WARN) while a usable measured pose may still come, holds (ERROR) while the
        published pose cannot be believed, and otherwise starts from the saved pose or neutral
        (WARN, saying why no measured pose was used).
        """
        if self.started:
            self.startup_timer.cancel()
            return
        topic = self.settings.measured_joint_states_topic
        now = time.monotonic()
        self.start_pose.discovered(self.count_publishers(topic), now)
        saved = self._saved_pose()
        step = self.start_pose.decide(
            now, self._measured_doubt(now), topic, "" if saved is None else str(self.state_path)
        )
        if step.action in (WAIT, HOLD):
            if step.action == HOLD:
                self._hold_start(step.reason)
            else:
                self.report_problem("start_pose", DiagnosticStatus.WARN, step.reason)
            if self.startup_timer.timer_period_ns != STARTUP_CHECK_NS:
                self.startup_timer.timer_period_ns = STARTUP_CHECK_NS  # discovery is polled
            return
        self.startup_timer.cancel()
        self._start(self.robot.neutral_rad if saved is None else saved, step.action)
        self.report_problem("start_pose", DiagnosticStatus.WARN, step.reason, hold_s=10.0)

    def _hold_start(self, doubt: str) -> None:
        """ERROR: the start waits, commanding nothing, because of ``doubt``."""
        self.report_problem(
            "start_pose",
            DiagnosticStatus.ERROR,
            f"{doubt}; commanding nothing until a believable pose arrives on "
            f"{self.settings.measured_joint_states_topic}",
            hold_s=SOURCE_WINDOW_S,
        )

    def _measured_doubt(self, now_s: float) -> str:
        """Why the measured joint states cannot be believed now ('' when nothing says so).

        Measured messages refused within ``SOURCE_WINDOW_S`` (a joint listed twice, an old or a
        future stamp), or live sources that disagree: the robot's pose is being published but
        cannot be known, so neither the saved pose nor neutral may stand in for it.
        """
        check = self.measured_check
        if check.conflict(now_s):
            return f"{check.live_sources(now_s)} publishers send poses that disagree"
        if check.refusing(now_s):
            return check.last_reason
        return ""

    def save_state(self) -> None:
        """Rewrite the state file when the pose, the stop or enable changed (atomically).

        Nothing is written when nothing changed; a failure is an ERROR until a save succeeds.
        """
        if not self.started:
            return
        status = self.filter.status
        memory = FilterMemory(
            tuple(self.robot.names),
            tuple(float(v) for v in self.filter.position_rad),
            status.stopped,
            time.time(),
            status.enabled,
            self.stop_since_s,
            self.disable_since_s,
            self.measured_rad is not None,
        )
        try:
            written = self.state.save(memory, time.monotonic())
        except OSError as exc:
            self._unsaved(f"cannot be written: {exc}")
            return
        if written and self.state.lock is not None:
            self.clear_problem("state_file_unsaved")

    def _save_if_due(self) -> None:
        if self.state.due:
            self.save_state()

    # --- inputs -------------------------------------------------------------------------------

    def _admit(self, stamp_s: float, n_points: int) -> int | None:
        """How many of a raw message's ``n_points`` poses to use (None: drop the message).

        None before the start and for a rejected stamp (counted and reported); else at most
        ``max_points_per_message`` (the rest is counted and reported as truncated).
        """
        self.input_messages += 1
        if not self.started:
            return None  # the start pose is not known yet: generated motion waits
        steps_back = self.stamps.counts.clock_steps_back
        problem = self.stamps.check(stamp_s, self.now_s())
        if self.stamps.counts.clock_steps_back > steps_back:
            self.report_problem(
                "clock_step",
                DiagnosticStatus.WARN,
                "the clock stepped back behind the newest raw trajectory stamp: ordering "
                "restarted from the next message",
                hold_s=10.0,
            )
        if problem:
            self.dropped_messages += 1
            self.report_problem(
                "raw_stamp", DiagnosticStatus.WARN, f"raw trajectory dropped: {problem}"
            )
            return None
        take = self.filter.points_to_take(n_points)
        if take < n_points:
            self.report_problem(
                "raw_truncated",
                DiagnosticStatus.WARN,
                f"raw trajectory longer than max_points_per_message "
                f"({self.filter.settings.max_points_per_message}): the rest dropped",
            )
        return take

    def on_raw(self, msg: JointTrajectory, info: MessageInfo) -> None:
        """Check and queue the poses of one raw trajectory message (of the one source in use)."""
        now = time.monotonic()
        if not self.sources.admit(_publisher_of(info), now):
            self.dropped_messages += 1
            self.report_problem(
                "raw_second_source",
                DiagnosticStatus.ERROR,
                "a second publisher sends raw_trajectory: its poses are refused; only the first "
                "drives the robot (stop the other one)",
                hold_s=1.0,
            )
            return
        take = self._admit(_stamp_s(msg.header.stamp), len(msg.points))
        if take is None:
            return
        msg.points = msg.points[:take]
        try:
            poses = trajectory_positions(msg, self.robot.names)
        except ValueError as exc:
            self.dropped_messages += 1
            self.report_problem(
                "raw_malformed", DiagnosticStatus.WARN, f"raw trajectory dropped: {exc}"
            )
            return
        self._queue(poses)

    def on_poses(self, poses_rad: np.ndarray, stamp_s: float) -> None:
        """Raw poses (n, n_joints) in this robot's joint order, stamped ``stamp_s`` (node clock).

        What inference_node hands over directly in single-process mode: the same checks as a
        raw_trajectory message (start, stamp, points per message, then the filter's gate).
        """
        take = self._admit(stamp_s, len(poses_rad))
        if take is not None:
            self._queue(poses_rad[:take])

    def _queue(self, poses: np.ndarray) -> None:
        """Push admitted raw poses into the filter; command at once when the stream is steady."""
        status = self.filter.status
        before = (status.rejected, status.out_of_range, status.implausible)
        was_waiting = self.filter.buffered == 0
        arrival_s = time.monotonic()
        self.filter.push(poses, arrival_s)
        if (status.rejected, status.out_of_range, status.implausible) != before:
            self.report_problem(
                "raw_rejected",
                DiagnosticStatus.WARN,
                f"raw poses rejected before the filter: {status.rejected} non-finite, "
                f"{status.out_of_range} out of range, {status.implausible} unreachable (total)",
            )
        # The clock follows the input: a pose that finds the buffer empty is commanded at once,
        # or MIN_TICK_SPACING periods after the last tick if that is later, and the timer then
        # waits 1.5 periods, or one if poses remain queued. A steady stream is served on arrival;
        # the timer ticks when input is late or comes several poses at a time; no two ticks are
        # closer than MIN_TICK_SPACING periods.
        if not (was_waiting and self.filter.buffered):
            return
        wait_s = self.last_tick_s + MIN_TICK_SPACING * self.filter.period_s - arrival_s
        if wait_s <= 0:
            self.on_tick()
            queued = self.filter.buffered > 0
            self.tick_timer.timer_period_ns = self.period_ns if queued else self.period_ns * 3 // 2
        else:  # too soon after the last tick: tick as soon as the spacing allows
            self.tick_timer.timer_period_ns = max(round(wait_s * 1e9), 1)
        self.tick_timer.reset()

    def on_voice(self, msg: Bool) -> None:
        """Voice activity from the features node."""
        self.on_voice_active(msg.data)

    def on_voice_active(self, active: bool) -> None:
        """Voice activity (from voice_activity, or directly in single-process mode)."""
        self.filter.set_voice_active(active, time.monotonic())

    def _release_is_older(
        self, info: MessageInfo, since_s: float | None, key: str, release: str, held: str
    ) -> bool:
        """True, and reported, when a release was published before the hold it would end.

        ``since_s`` is when the stop (or disable) in force came into force; a ``release``
        published no later than that (an older panel's latched value, delivered again after a
        restart or after a newer stop) is ignored with a WARN.
        """
        published_s = _published_s(info)
        if since_s is None or published_s > since_s:
            return False
        self.report_problem(
            key,
            DiagnosticStatus.WARN,
            f"{release} published {since_s - published_s:.1f} s before the {held} in force: "
            f"ignored; publish {release} again to release it",
        )
        return True

    def _save_now(self) -> None:
        """Save a changed stop or enable now, or within ``MIN_SAVE_SPACING_S`` (bounded rate)."""
        if self.state.save_soon(time.monotonic()):
            self.save_state()

    def on_enable(self, msg: Bool, info: MessageInfo) -> None:
        """Enable or disable generated motion (only a later enable ends a disable)."""
        if msg.data and self._release_is_older(
            info, self.disable_since_s, "enable_ignored", "enable: true", "disable"
        ):
            return
        published_s = min(_published_s(info), time.time())
        if not msg.data:
            since = self.disable_since_s
            self.disable_since_s = published_s if since is None else max(since, published_s)
        else:
            self.disable_since_s = None
        changed = self.filter.status.enabled != msg.data
        self.filter.set_enabled(msg.data)
        if changed or not msg.data:  # a later disable moves disable_since_s
            self._save_now()
        if changed:
            self.get_logger().info("enabled" if msg.data else "disabled: gliding to neutral")

    def on_stop(self, msg: Bool, info: MessageInfo) -> None:
        """Emergency stop on / off (only a release published after the stop ends it)."""
        if not msg.data and self._release_is_older(
            info, self.stop_since_s, "stop_release_ignored", "stop: false", "stop"
        ):
            return
        published_s = min(_published_s(info), time.time())  # a clock ahead cannot pin a stop
        if msg.data:
            since = self.stop_since_s
            self.stop_since_s = published_s if since is None else max(since, published_s)
        else:
            self.stop_since_s = None
        changed = self.filter.status.stopped != msg.data
        self.filter.set_stop(msg.data)
        if changed or msg.data:  # a later stop moves stop_since_s
            self._save_now()
        if changed and msg.data:
            self.get_logger().warning(f"STOP ({self.filter.settings.stop_behaviour})")
        elif changed:
            self.get_logger().info("stop released")

    def _head_values(self, msg: JointState) -> dict[str, float]:
        if len(msg.name) != len(msg.position):
            raise InputError(f"{len(msg.name)} names for {len(msg.position)} positions")
        return dict(zip(msg.name, (float(p) for p in msg.position), strict=True))

    def _external(
        self, msg: JointState, setter: Callable[[dict[str, float], float], None], key: str
    ) -> None:
        try:
            setter(self._head_values(msg), time.monotonic())
        except InputError as exc:
            self.report_problem(key, DiagnosticStatus.WARN, f"{key} rejected: {exc}")

    def on_head_target(self, msg: JointState) -> None:
        """Absolute head target (e.g. a face tracker's look-at)."""
        self._external(msg, self.filter.set_head_target, "head_target")

    def on_head_offset(self, msg: JointState) -> None:
        """Head offset added to the generated head motion."""
        self._external(msg, self.filter.set_head_offset, "head_offset")

    # --- clock and outputs --------------------------------------------------------------------

    def now_s(self) -> float:
        """Node clock in seconds."""
        return self.get_clock().now().nanoseconds * 1e-9

    def on_timer(self) -> None:
        """The fallback clock: tick, and return to the nominal period."""
        if self.tick_timer.timer_period_ns != self.period_ns:
            self.tick_timer.timer_period_ns = self.period_ns
        self.request_budget.renew()
        if self.started:
            self.on_tick()
        else:
            self._take_pending_settings()

    def on_tick(self) -> None:
        """Advance the filter by one period and publish the outputs due at this tick."""
        self._take_pending_settings()
        self.request_budget.renew()
        self.ticks += 1
        self.last_tick_s = time.monotonic()
        self.tick_stamp = self.get_clock().now()
        status = self.filter.status
        self.filter.tick(self.last_tick_s)
        self.tracking.command(self.filter.position_rad, self.last_tick_s)
        if status.faults > self.faults_seen:
            self.faults_seen = status.faults
            self.report_problem("filter_fault", DiagnosticStatus.ERROR, status.last_fault)
        guard = self.filter.body_guard.status
        if guard.active:
            self.report_body_guard(guard)
        for output in self.outputs:
            spacing, last_s, publish, publisher = output
            if self.last_tick_s - last_s >= spacing:
                output[1] = self.last_tick_s
                if publisher.get_subscription_count():  # no message for nobody
                    publish()

    def report_body_guard(self, guard: GuardStatus) -> None:
        """WARN naming the links while the self-collision guard changes commands."""
        link_a, link_b = guard.links
        margin_cm = self.filter.body_guard.margin_m * 100.0
        action = "leading the arm out of" if guard.lead_out_steps > self.lead_outs_seen else "at"
        self.lead_outs_seen = guard.lead_out_steps
        self.report_problem(
            "body_guard",
            DiagnosticStatus.WARN,
            f"self-collision guard acting: {link_a} {action} the {margin_cm:.1f} cm margin of "
            f"{link_b} ({guard.clearance_m * 100.0:.1f} cm); the arm is slowed or held there "
            f"(last-resort holds so far: {guard.holds})",
        )

    def _stamp(self) -> object:
        return self.tick_stamp.to_msg()

    def publish_joint_angles(self) -> None:
        """naoqi_driver command: absolute angles at ``speed`` fraction of max velocity."""
        msg = JointAnglesWithSpeed()
        msg.header.stamp = self._stamp()
        msg.joint_names = list(self.robot.names)
        msg.joint_angles = [float(v) for v in self.filter.position_rad]
        speed = self.settings.joint_angles_speed
        msg.speed = float(speed if speed >= 0 else self.filter.limiter.settings.velocity_fraction)
        msg.relative = 0
        self.publishers_by_output["joint_angles"].publish(msg)

    def publish_joint_trajectory(self) -> None:
        """ros2_control command: one point, one filter period after the tick it was computed at."""
        msg = trajectory_msg(
            self.robot.names,
            self.filter.position_rad[None, :],
            self.filter.period_s,
            self.filter.velocity_rad_s[None, :],
        )
        msg.header.stamp = self._stamp()
        self.publishers_by_output["joint_trajectory"].publish(msg)

    def publish_joint_states(self) -> None:
        """The commanded pose as a JointState (for robot_state_publisher and viewers)."""
        msg = JointState()
        msg.header.stamp = self._stamp()
        msg.name = list(self.robot.names)
        msg.position = [float(v) for v in self.filter.position_rad]
        msg.velocity = [float(v) for v in self.filter.velocity_rad_s]
        self.publishers_by_output["joint_states"].publish(msg)

    # --- diagnostics --------------------------------------------------------------------------

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """Mode and where the filter started; WARN while waiting or stopped."""
        status = self.filter.status
        if not self.started:
            return DiagnosticStatus.WARN, "waiting for the robot's pose: commanding nothing"
        silent_s = time.monotonic() - self.last_tick_s
        if silent_s > STALLED_PERIODS * self.filter.period_s:
            return DiagnosticStatus.ERROR, f"no command computed for {silent_s * 1e3:.0f} ms"
        if status.stopped:
            return DiagnosticStatus.WARN, f"STOPPED ({self.filter.settings.stop_behaviour})"
        return DiagnosticStatus.OK, f"{status.mode} (started from the {self.started_from})"

    def diagnostic_values(self) -> dict[str, object]:
        """Input and filter counters, latency, mode, limiter activity, health."""
        status, counts, stamps = self.filter.status, self.filter.limiter.counts, self.stamps
        now = time.monotonic()
        input_rate_hz = (status.received - self.poses_at_last_report) / max(
            now - self.last_report_s, 1e-3
        )
        self.poses_at_last_report, self.last_report_s = status.received, now
        values: dict[str, object] = {
            "started_from": self.started_from or "waiting",
            "input_messages": self.input_messages,
            "dropped_messages": self.dropped_messages,
            "stale_messages_dropped": stamps.counts.out_of_order,
            "future_stamps_rejected": stamps.counts.future,
            "old_stamps_rejected": stamps.counts.too_old,
            "clock_steps_back": stamps.counts.clock_steps_back,
            "poses_received": status.received,
            "poses_rejected": status.rejected,
            "poses_out_of_range": status.out_of_range,
            "poses_unreachable": status.implausible,
            "poses_truncated": status.truncated,
            "poses_dropped": status.dropped,
            "raw_messages_of_a_second_source": self.sources.refused,
            "approaches": self.filter.approach.count,
            "head_inputs_rejected": status.external_rejected,
            "buffer_underruns": status.underruns,
            "poses_skipped_backlog": status.skipped,
            "buffered_poses": status.buffered,
            "input_latency_ms": f"{stamps.latency_s * 1e3:.2f}",
            "mode": status.mode,
            "enabled": status.enabled,
            "stopped": status.stopped,
            "voice_active": status.voice_active,
            "head_target_active": status.head_target_active,
            "input_rate_hz": f"{input_rate_hz:.1f}",
            "position_limit_hits": counts.position,
            "velocity_limit_hits": counts.velocity,
            "acceleration_limit_hits": counts.acceleration,
            "gaps": status.gaps,
            "filter_faults": status.faults,
            "ticks": self.ticks,
            "service_requests_served": self.request_budget.served_total,
            "most_service_requests_in_a_tick": self.request_budget.most_in_a_tick,
            "body_guard_interventions": self.filter.body_guard.status.interventions,
            "body_guard_lead_out_steps": self.filter.body_guard.status.lead_out_steps,
            "body_guard_holds": self.filter.body_guard.status.holds,
            "body_clearance_cm": f"{self.filter.body_guard.status.clearance_m * 100.0:.1f}",
            "body_closest_links": " / ".join(self.filter.body_guard.status.links),
            "command_finite_and_in_limits": bool(
                np.isfinite(self.filter.position_rad).all()
                and np.all(self.filter.position_rad >= self.robot.lower_rad)
                and np.all(self.filter.position_rad <= self.robot.upper_rad)
            ),
            "last_command_age_ms": (
                f"{(now - self.last_tick_s) * 1e3:.0f}" if self.started else "none"
            ),
        }
        values["measured_partial_messages"] = self.measured_partial
        check = self.measured_check
        values["measured_refused_duplicate_names"] = check.counts.duplicate
        values["measured_refused_old_stamps"] = check.counts.old
        values["measured_refused_future_stamps"] = check.counts.future
        values["measured_unstamped"] = check.counts.unstamped
        values["measured_sources"] = check.live_sources(now)
        values["measured_ignored_sources_disagree"] = self.measured_conflicts
        if self.measured_rad is not None:
            deviation = np.abs(self.measured_rad - self.filter.position_rad).max()
            values["measured_deviation_rad"] = f"{deviation:.3f}"
            values["measured_off_recent_commands_rad"] = f"{self.tracking.off_rad:.3f}"
        return values


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(MotionFilterNode, "motion_filter_node", args, events=False)  # see create_executor


if __name__ == "__main__":
    main()
