"""motion_filter_node: raw poses in; smooth, limited commands for naoqi, ros2_control, viewers out.

Subscriptions:
    raw_trajectory (trajectory_msgs/JointTrajectory): poses from inference_node (any joint order),
        read best effort: a pose lost on the way (a flood on another input) holds back none
        after it, and is counted (``raw_messages_lost``).
    voice_activity (std_msgs/Bool): from audio_features_node; silence -> glide to neutral.
    (In single-process mode those two nodes call this one directly instead of these two topics.)
    enable (std_msgs/Bool, latched): False -> glide to neutral and ignore generated motion.
    stop (std_msgs/Bool, latched): True -> emergency stop ('hold': brake and stay; 'neutral').
        Each of the two is read twice where rclpy and the middleware filter content (Kilted's
        rclpy, Fast DDS): by a latched reader of depth 1, and by one of the holds alone
        (``stop: true``, ``enable: false``), from which no flood of releases displaces a hold.
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
pose, every valid joint of it; only with ``start_without_measured_pose``, once none can still
come, the pose it last commanded, saved in ``state_file``, or neutral) is
:mod:`audio2pose_ros.motion.start_pose`'s decision; whether a
measured pose can be believed, :mod:`audio2pose_ros.motion.measured`'s (a joint listed twice, a
stamp too old or ahead: refused, WARN; two publishers that disagree: ERROR, neither used, and
the start holds, commanding nothing, until the conflict has been over for ``SOURCE_WINDOW_S``);
what each measured message means (problems, the start, the commands' check) is
:mod:`audio2pose_ros.motion.measured_states`'s.

Parameter requests: rclpy's parameter services are served by the executor like any other
callback; a request is validated at once and its settings reach the filter at the next tick,
once per tick however many came, and the tick is a paced timer, run after every request when
overdue, so a storm of set_parameters requests delays answers, never commands.

Stop and disable: a stop stays in force across restarts until a ``stop: false`` *published
after the stop* arrives, as does ``enable: false`` until a later ``enable: true``, by the
messages' source timestamps (:mod:`audio2pose_ros.motion.holds`: an older panel's latched
``stop: false`` never releases a stop). Where rclpy passes no source timestamp (Humble, the
EventsExecutor) a release is timed by its arrival, and the first message of its topic cannot
release a stop or a disable kept from before the restart (it may be such a latched value): the
release is asked for again. A hold is never lost to a flood of releases where its topic has a
reader of holds alone: every hold the node takes engages (``stops_engaged``,
``disables_engaged``), each once (:class:`~audio2pose_ros.motion.holds.HoldDeliveries`), and
stays until a release published after it arrives (a release the other reader delivered first
does not end it, unless its own publisher sent it). Without content filters (Jazzy, Humble,
Cyclone DDS) the one latched reader keeps only the newest message: a hold followed by releases
faster than the executor takes them can be replaced unseen (``holds_filtered``: false).
A stop, a disable and the pose are saved when they
change, at most every ``MIN_SAVE_SPACING_S``; a state that cannot be saved is an ERROR on
/diagnostics (the stop stays in force in memory), reported again at every start. The state file
is this node's alone: a second live node with the same file refuses to start (exit 78, naming
the file).

One master: raw poses are taken from one ``raw_trajectory`` publisher at a time (its gid); a
second one is refused and reported as ERROR until it stops, and the first is given up only
after it has been silent for ``watchdog_timeout_s`` (then the filter approaches the new track
gently). Where rclpy does not say which publisher sent a message (Jazzy, Humble, the
EventsExecutor), the graph does how many publish: while there are two or more, every raw pose
is refused, with the same ERROR.

Timing (:mod:`audio2pose_ros.motion.pacing`): the filter ticks when a pose arrives into an empty
buffer (or ``MIN_TICK_SPACING`` periods after the previous tick, if later), so a steady stream is
commanded on arrival; else at ``rate_hz``, and two periods after a tick made for an arrival, as the
input then is missing, not a period late. The tick is a
:class:`~audio2pose_ros.ros.diagnosed_node.PacedTimer` (re-programmed at each such arrival), run
between two messages when a backlog of input holds it back. Each output keeps its own rate on
average, its due times one period apart, published at the first tick at most half a filter period
before one, and never less than its period minus a filter period after the previous one (its
documented minimum spacing: 10 ms for 50 Hz at a 100 Hz filter clock). Header stamps are
the time the command was computed for (the tick), not the publish time. An output nobody subscribes
to is not built nor sent.
"""

from __future__ import annotations

import array
import math
import time
from collections.abc import Callable, Hashable, Mapping
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.exceptions import InvalidTopicNameException
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.motion.body_guard import GuardStatus
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.filter_report import FilterReport
from audio2pose_ros.motion.filter_settings import MotionFilterNodeSettings, MotionFilterSettings
from audio2pose_ros.motion.holds import Hold, HoldDeliveries
from audio2pose_ros.motion.limits import LimitSettings
from audio2pose_ros.motion.measured_states import MeasuredStates, start_held
from audio2pose_ros.motion.pacing import OutputPacing, arrival_wait_s, next_timer_s
from audio2pose_ros.motion.problems import Problem
from audio2pose_ros.motion.raw_intake import RawIntake
from audio2pose_ros.motion.start_pose import HOLD, UNKNOWN, WAIT, identity
from audio2pose_ros.motion.state_file import (
    FilterMemory,
    StateFileInUseError,
    StateStore,
    StateWriter,
    default_state_path,
)
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.parameters import ParameterValue, settings_from, settings_with, specs_of
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.messages import (
    RawTrajectory,
    published_s,
    publisher_of,
    sequence_of,
    stamp_s,
    trajectory_bytes_cap,
    trajectory_msg,
)
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.qos import LATCHED_QOS, RAW_POSE_READER_QOS, STREAM_QOS
from audio2pose_ros.ros.spin import run_node
from audio2pose_ros.ros.subscriptions import MessageInfo, SequenceGaps, content_filter_options

STALLED_PERIODS = 10  # no tick for this many periods while started: ERROR (commands stalled)
STARTUP_CHECK_S = 0.1  # while the start waits, it is decided again this often
SECOND_SOURCE_HOLD_S = 1.0  # a refusal of raw poses from several publishers is shown this long


SETTINGS_CLASSES = (MotionFilterSettings, StyleSettings, LimitSettings, MotionFilterNodeSettings)
# A JointState of a whole humanoid (names, positions, velocities, efforts) is a few KiB.
MAX_JOINT_STATE_BYTES = 65536
MAX_BOOL_BYTES = 64  # a serialized std_msgs/Bool is 5 bytes


PARAMETERS = tuple(spec for cls in SETTINGS_CLASSES for spec in specs_of(cls))
# output -> (message type, topic); each published at its own ``<output>_rate_hz``
OUTPUTS = {
    "joint_angles": (JointAnglesWithSpeed, topics.JOINT_ANGLES),
    "joint_trajectory": (JointTrajectory, topics.JOINT_TRAJECTORY),
    "joint_states": (JointState, topics.COMMANDED_JOINT_STATES),
}


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
        self.parameters = NodeParameters(self, PARAMETERS, apply=self.apply_parameters)
        values = self.parameters.values
        self.settings: MotionFilterNodeSettings = settings_from(MotionFilterNodeSettings, values)
        settings: MotionFilterSettings = settings_from(MotionFilterSettings, values)
        rates = {key: getattr(self.settings, f"{key}_rate_hz") for key in OUTPUTS}
        self.pacing = OutputPacing(rates, settings.rate_hz)
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
        self.intake = RawIntake(
            self.filter,
            settings.watchdog_timeout_s,
            self.settings.max_stamp_future_s,
            self.settings.max_stamp_age_s,
        )
        self.report = FilterReport(self.filter, time.monotonic())
        # raw messages lost on the way (best-effort reader), by the one source's sequence numbers
        self.raw_lost = SequenceGaps(one_source=True)
        self.faults_seen = 0
        self.ticks = 0  # filter ticks since start
        self.lead_outs_seen = 0
        self.started_from = ""

        self.state_path = (
            Path(self.settings.state_file).expanduser()
            if self.settings.state_file
            else default_state_path(self.get_fully_qualified_name())
        )
        try:
            self.state = StateStore(self.state_path, self.robot)
        except StateFileInUseError as exc:
            raise ConfigurationError(f"parameter state_file: {exc}") from None
        self.state_writer = StateWriter(self.state)  # writes off the tick (a thread)
        for problem in self.state.problems():  # the file cannot be locked, read or used
            self._report(problem)
        self.memory = self.state.memory
        self.measured = MeasuredStates(
            self.robot,
            time.monotonic(),
            self.memory is not None and self.memory.measured,
            self.settings.start_without_measured_pose,
        )
        # the stop and the disable in force, each since a wall-clock time (motion.holds)
        self.stop_hold, self.disable_hold = Hold.kept(self.memory)
        if self.stop_hold.in_force:
            self.filter.set_stop(True)
            self.get_logger().warning(
                f"STOP in force from before the restart ({self.state_path}); publish "
                "stop: false to release it"
            )
        if self.disable_hold.in_force:
            self.filter.set_enabled(False)
            self.get_logger().warning(
                f"disabled from before the restart ({self.state_path}): generated motion is "
                "ignored; publish enable: true to enable it"
            )

        guarded, bounded = self.guarded, self.create_bounded_subscription
        if subscribe_graph:
            bounded(
                JointTrajectory,
                topics.RAW_TRAJECTORY,
                self.on_raw,
                RAW_POSE_READER_QOS,  # best effort: a lost pose holds back none after it
                lambda: trajectory_bytes_cap(
                    int(self.parameters["max_points_per_message"]), self.robot.n_joints
                ),
                with_info=True,
            )
            self.create_subscription(
                Bool, topics.VOICE_ACTIVITY, guarded(self.on_voice), STREAM_QOS
            )
        # Holds (a stop, a disable) each taken once from either reader of their topic; the
        # readers of holds alone first: served before the latched ones in a round, a hold is in
        # force before the releases that came with it are judged against it
        self.stop_deliveries, self.disable_deliveries = HoldDeliveries(), HoldDeliveries()
        self.holds_filtered = self._hold_reader(topics.ENABLE, self.on_enable, "FALSE")
        self.holds_filtered &= self._hold_reader(topics.STOP, self.on_stop, "TRUE")
        # with their MessageInfo (the publication time) under either executor
        bounded(Bool, topics.ENABLE, self.on_enable, LATCHED_QOS, MAX_BOOL_BYTES, with_info=True)
        bounded(Bool, topics.STOP, self.on_stop, LATCHED_QOS, MAX_BOOL_BYTES, with_info=True)
        # and holds asked for by a service, which a topic's flood of releases cannot reach
        self._hold_service(topics.EMERGENCY_STOP, self._stop, self.stop_hold, "stop: false")
        self._hold_service(topics.DISABLE_MOTION, self._disable, self.disable_hold, "enable: true")
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
        # the first message of each hold's topic (release_unsure): none yet
        self.held_topics_heard: set[str] = set()
        # the command clock and the start's decision keep their rate behind any backlog
        self.tick_timer = self.create_paced_timer(self.filter.period_s, self.on_timer)
        self.startup_timer = self.create_paced_timer(
            max(self.settings.startup_timeout_s, 1e-3), self.on_startup_timeout
        )
        # the state file is saved from the tick (no timer of its own wakes an idle node)
        self.next_save_s = time.monotonic() + self.settings.state_save_period_s
        self.last_tick_s = -math.inf
        self.arrival_tick_due = False  # the tick timer's next run is for a pose that arrived
        self.tick_stamp = self.get_clock().now()
        self.publish_output = {
            "joint_angles": self.publish_joint_angles,
            "joint_trajectory": self.publish_joint_trajectory,
            "joint_states": self.publish_joint_states,
        }
        self.publishers_by_output = {
            key: self.create_publisher(msg_type, topic, 10)
            for key, (msg_type, topic) in OUTPUTS.items()
            if key in self.pacing.spacing_s
        }
        self.get_logger().info(
            f"{self.robot.n_joints} joints at {settings.rate_hz:g} Hz, {settings.smoothing} "
            f"smoothing, outputs: {', '.join(self.publishers_by_output) or 'none'}; waiting for "
            f"the measured pose on {self.settings.measured_joint_states_topic}"
            + (
                f" (without it, starting from the saved pose or neutral after at least "
                f"{self.settings.startup_timeout_s:g} s: start_without_measured_pose)"
                if self.settings.start_without_measured_pose
                else ", commanding nothing until it comes"
            )
        )
        if not self.holds_filtered:  # said once the node is up (a refused parameter says only that)
            self.get_logger().info(
                "this rclpy or middleware filters no content: stop and enable are read by one "
                "latched reader, from which a flood of releases can displace a hold unseen"
            )

    def destroy_node(self) -> None:
        """Write the state still pending (the writer thread ends), then destroy the node.

        rclpy also destroys a node whose construction failed (a refused parameter), at shutdown:
        it may have no writer yet.
        """
        writer: StateWriter | None = getattr(self, "state_writer", None)
        if writer is not None:
            writer.close()
        super().destroy_node()

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
        self.filter.request_settings(changes)
        self.settings = node_settings
        self.intake.stamps.max_future_s = node_settings.max_stamp_future_s
        self.intake.stamps.max_age_s = node_settings.max_stamp_age_s

    # --- start-up -----------------------------------------------------------------------------

    @property
    def started(self) -> bool:
        """Whether the filter knows where the robot is (and commands are published)."""
        return bool(self.started_from)

    def _saved_pose(self) -> np.ndarray | None:
        """The saved pose, when there is one inside the joint ranges."""
        return self.state.saved_pose()

    def _unsaved(self, reason: str) -> None:
        """The state cannot be saved: an ERROR until a save succeeds (the stop stays in memory)."""
        self._report(self.state.unsaved(reason, self.filter.status.stopped))

    def _start(self, pose_rad: np.ndarray, source: str) -> None:
        self.filter.start_from(pose_rad)
        self.started_from = source
        self.last_tick_s = time.monotonic()  # the stall check counts from here
        self.startup_timer.cancel()
        self.save_state()

    def on_measured(self, msg: JointState, info: MessageInfo | None = None) -> None:
        """The robot's measured joint states: the start pose, then checked against the commands.

        What a message means is :class:`MeasuredStates`'s to say (:meth:`MeasuredStates.take`);
        this reports its problems and starts the filter from the pose it gives.
        """
        arrival_s = time.monotonic()
        source: Hashable = UNKNOWN  # called directly, or an rclpy that gives no gid
        published_ns = 0
        if info is not None:
            gid = publisher_of(info)
            source = UNKNOWN if gid is None else identity(gid)
            published_ns = info.get("source_timestamp") or 0
        topic = self.settings.measured_joint_states_topic
        use = self.measured.take(
            msg.name,
            msg.position,
            stamp_s(msg.header.stamp),
            published_ns * 1e-9 if published_ns else None,
            self.now_s(),
            source,
            arrival_s,
            self.started,
            topic,
            lambda: self.publisher_ids(topic),
            self._saved_pose,
        )
        for key in use.cleared:
            self.clear_problem(key)
        for problem in use.problems:
            self._report(problem)
        if use.start_rad is not None:
            self._start(use.start_rad, "measured pose")
            self.get_logger().info("starting from the robot's measured pose")

    def publisher_ids(self, topic: str) -> list[Hashable]:
        """The identities of ``topic``'s publishers, as the graph shows them now."""
        return [identity(info.endpoint_gid) for info in self.get_publishers_info_by_topic(topic)]

    def _report(self, problem: Problem) -> None:
        """Report a problem of the core on /diagnostics."""
        level = DiagnosticStatus.ERROR if problem.error else DiagnosticStatus.WARN
        if problem.hold_s is None:
            self.report_problem(problem.key, level, problem.text)
        else:
            self.report_problem(problem.key, level, problem.text, hold_s=problem.hold_s)

    def on_startup_timeout(self) -> None:
        """No measured pose started the filter in time: decide (:class:`StartPose`) what now.

        Called when ``startup_timeout_s`` has passed, then every 0.1 s while the start waits:
        it waits (WARN, saying why) for a usable measured pose, holds (ERROR) while the
        published pose cannot be believed, and, only with ``start_without_measured_pose``,
        starts from the saved pose or neutral once no measured pose can still come (WARN,
        saying why no measured pose was used).
        """
        if self.started:
            self.startup_timer.cancel()
            return
        topic = self.settings.measured_joint_states_topic
        now = time.monotonic()
        self.measured.start.discovered(self.publisher_ids(topic), now)
        saved = self._saved_pose()
        step = self.measured.start.decide(
            now, self.measured.doubt(now), topic, "" if saved is None else str(self.state_path)
        )
        if step.action in (WAIT, HOLD):
            if step.action == HOLD:
                self._report(start_held(step.reason, topic))
            else:
                self.report_problem("start_pose", DiagnosticStatus.WARN, step.reason)
            if self.startup_timer.period_s != STARTUP_CHECK_S:  # discovery is polled
                self.startup_timer.schedule(STARTUP_CHECK_S, STARTUP_CHECK_S)
            return
        self.startup_timer.cancel()
        self._start(self.robot.neutral_rad if saved is None else saved, step.action)
        self.report_problem("start_pose", DiagnosticStatus.WARN, step.reason, hold_s=10.0)

    def save_state(self, now: bool = False) -> None:
        """Rewrite the state file when the pose, the stop or enable changed (atomically).

        By the writer thread (:class:`~audio2pose_ros.motion.state_file.StateWriter`): the
        caller (the tick) never waits on the disk; with ``now`` in this thread, before the
        caller goes on (a stop, a disable: written before the node acknowledges it). Nothing is
        written when nothing changed; a failure is an ERROR until a save succeeds.
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
            self.stop_hold.since_s,
            self.disable_hold.since_s,
            self.measured.pose_rad is not None,
        )
        if not now:
            self.state_writer.submit(memory, time.monotonic())
            return
        try:
            written = self.state_writer.write_now(memory, time.monotonic())
        except OSError as exc:
            self._saved(False, exc)
            return
        self._saved(written, None)

    def _saved(self, written: bool, error: OSError | None) -> None:
        """Report the outcome of a write: an ERROR for a failure, cleared by a success."""
        if error is not None:
            self._unsaved(f"cannot be written: {error}")
        elif written and self.state.lock is not None:
            self.clear_problem("state_file_unsaved")

    def _save_if_due(self, now_s: float) -> None:
        """At a tick: save a change waiting for its spacing, or the pose every save period.

        A stop or an enable that :meth:`_save_now` could not write at once is written at the
        first tick the state file's spacing allows
        (:meth:`~audio2pose_ros.motion.state_file.StateStore.spaced`); the pose every
        ``state_save_period_s`` (written only when it changed). The tick runs at ``rate_hz``
        whenever the filter has started, and nothing is saved before: no timer of its own.
        The writes are the writer thread's; here the outcome of its last one is reported.
        """
        outcome = self.state_writer.take_outcome()
        if outcome is not None:
            self._saved(*outcome)
        if now_s >= self.next_save_s:
            self.next_save_s = now_s + self.settings.state_save_period_s
            self.save_state()
        elif self.state.due and self.state.spaced(now_s):
            self.save_state()

    # --- inputs -------------------------------------------------------------------------------

    @property
    def input_messages(self) -> int:
        """Raw messages (or single-process hand-overs) that came since start."""
        return self.intake.messages

    def on_raw(self, message: JointTrajectory, info: MessageInfo | None) -> None:
        """Check and queue the poses of one raw trajectory message (of the one source in use).

        A message listing a joint twice or naming one the robot lacks is refused whole
        (:meth:`RawIntake.joint_names`).
        """
        refused = self._refused_source(info)
        if refused is None:
            self._count_lost(info)
            refused = self.intake.joint_names(message.joint_names)
        if refused is not None:
            self._report(refused)
            return
        msg = RawTrajectory.of(message)
        take = self._admit(msg.stamp_s, len(msg.positions))
        if take is None:
            return
        try:
            poses = msg.poses(self.robot.names, take)
        except ValueError as exc:
            self._report(self.intake.malformed(str(exc)))
            return
        self._queue(poses)

    def _count_lost(self, info: MessageInfo | None) -> None:
        """Count the raw messages of the source in use lost before this one: a WARN if any.

        The reader is best effort (:data:`~audio2pose_ros.ros.qos.RAW_POSE_READER_QOS`): a
        message lost on the way is gone, and the filter bridges the missing poses. Counted from
        the publisher's sequence numbers where rclpy gives them (Jazzy, Kilted, the stock
        executor); elsewhere ``buffer_underruns`` shows what it cost.
        """
        lost = self.raw_lost.lost
        self.raw_lost.observe(info)
        if self.raw_lost.lost > lost:
            self.report_problem(
                "raw_lost",
                DiagnosticStatus.WARN,
                f"{self.raw_lost.lost} raw_trajectory messages lost on the way since start (a "
                "flood on another input, or a congested network): the filter bridged each gap",
            )

    def _refused_source(self, info: MessageInfo | None) -> Problem | None:
        """Why a raw message is refused for its publisher (None: it may be used).

        By the publisher's gid where rclpy gives it (:meth:`RawIntake.from_source`); else by
        the graph: a message is refused while two or more publishers send raw_trajectory.
        """
        gid = publisher_of(info)
        if gid is not None:
            return self.intake.from_source(gid, time.monotonic())
        publishers = self.count_publishers(topics.RAW_TRAJECTORY)
        if publishers <= 1:
            return None
        self.intake.dropped += 1
        return Problem(
            "raw_second_source",
            True,
            f"{publishers} publishers send raw_trajectory and this rclpy does not say which "
            "message is whose: every raw pose is refused until one is left (stop the others)",
            SECOND_SOURCE_HOLD_S,
        )

    def on_poses(self, poses_rad: np.ndarray, stamp_s: float) -> None:
        """Raw poses (n, n_joints) in this robot's joint order, stamped ``stamp_s`` (node clock).

        What inference_node hands over directly in single-process mode: the same checks as a
        raw_trajectory message (start, stamp, points per message, then the filter's gate).
        """
        take = self._admit(stamp_s, len(poses_rad))
        if take is not None:
            self._queue(poses_rad[:take])

    def _admit(self, stamp_s: float, n_points: int) -> int | None:
        """How many of a message's poses to use (None: none): :meth:`RawIntake.admit`."""
        take, problems = self.intake.admit(stamp_s, n_points, self.now_s(), self.started)
        for problem in problems:
            self._report(problem)
        return take

    def _queue(self, poses: np.ndarray) -> None:
        """Push admitted raw poses into the filter; command at once when the stream is steady."""
        was_waiting = self.filter.buffered == 0
        arrival_s = time.monotonic()
        rejected = self.intake.push(poses, arrival_s)
        if rejected is not None:
            self._report(rejected)
        if not (was_waiting and self.filter.buffered):
            return
        # the clock follows the input (motion.pacing): at once, or when the spacing allows
        wait_s = arrival_wait_s(self.last_tick_s, arrival_s, self.filter.period_s)
        if wait_s <= 0:
            self._tick_for_arrival()
        else:
            self.arrival_tick_due = True
            self.tick_timer.schedule(wait_s)

    def _tick_for_arrival(self) -> None:
        """Tick for a pose that arrived; the timer then waits for the next (``next_timer_s``)."""
        self.arrival_tick_due = False
        self.on_tick()
        self.tick_timer.schedule(next_timer_s(self.filter.period_s, self.filter.buffered > 0))

    def on_voice(self, msg: Bool) -> None:
        """Voice activity from the features node."""
        self.on_voice_active(msg.data)

    def on_voice_active(self, active: bool) -> None:
        """Voice activity (from voice_activity, or directly in single-process mode)."""
        self.filter.set_voice_active(active, time.monotonic())

    def _hold_reader(
        self, topic: str, callback: Callable[[Bool, MessageInfo | None], None], value: str
    ) -> bool:
        """Read ``topic``'s messages of ``value`` (its holds) alone; False where none filters.

        A latched reader of depth 1 keeps one message of its topic: a hold followed by releases
        faster than the executor takes them was replaced unseen, and the robot never stopped.
        The middleware delivers only holds to this reader (DDS content filter), so releases,
        however many, never displace one; the callback is the latched reader's, which takes a
        hold delivered by both once. Where rclpy has no content filters (Jazzy, Humble) there
        is no such reader; where the middleware does not filter (Cyclone DDS) it is destroyed
        (it would be a second copy of every message).
        """
        options = content_filter_options("data = %0", [value])
        if options is None:
            return False
        reader = self.create_bounded_subscription(
            Bool,
            topic,
            callback,
            LATCHED_QOS,
            MAX_BOOL_BYTES,
            with_info=True,
            content_filter=options,
        )
        if reader.is_cft_enabled:
            return True
        self.destroy_subscription(reader)
        return False

    def _engages(self, deliveries: HoldDeliveries, info: MessageInfo | None, at_s: float) -> bool:
        """Whether a hold published at ``at_s`` engages (not taken yet, nor since released)."""
        return deliveries.take(publisher_of(info), sequence_of(info), at_s)

    def _released(
        self, hold: Hold, info: MessageInfo | None, topic: str, key: str, release: str, held: str
    ) -> bool:
        """Whether a ``release`` ends ``hold`` (:meth:`Hold.release`); if not, a WARN.

        Without the release's publication time (no message info), it is timed by its arrival,
        except the first message of ``topic``: it may be an older panel's latched value, so it
        cannot end a hold kept from before the restart.
        """
        since_s, at_s = hold.since_s, published_s(info)
        deliveries = self.stop_deliveries if topic == topics.STOP else self.disable_deliveries
        if at_s is not None:
            deliveries.released(publisher_of(info), at_s)
        first = topic not in self.held_topics_heard
        self.held_topics_heard.add(topic)
        if at_s is None:
            if first and since_s is not None:
                self.report_problem(
                    key,
                    DiagnosticStatus.WARN,
                    f"{release} ignored: the first message on {topic}, whose publication time "
                    f"this rclpy does not give, may be older than the {held} in force; publish "
                    f"{release} again to release it",
                )
                return False
            at_s = time.time()
        if hold.release(at_s):
            return True
        assert since_s is not None
        self.report_problem(
            key,
            DiagnosticStatus.WARN,
            f"{release} published {since_s - at_s:.1f} s before the {held} in force: "
            f"ignored; publish {release} again to release it",
        )
        return False

    def _held_at_s(self, info: MessageInfo | None, topic: str) -> float:
        """When a hold was published: its info's time, else its arrival (wall clock)."""
        self.held_topics_heard.add(topic)
        at_s = published_s(info)
        return time.time() if at_s is None else at_s

    def _save_now(self) -> None:
        """Save a changed stop or enable now, or within ``MIN_SAVE_SPACING_S`` (bounded rate)."""
        if self.state.save_soon(time.monotonic()):
            self.save_state(now=True)

    def on_enable(self, msg: Bool, info: MessageInfo | None) -> None:
        """Enable or disable generated motion (only a later enable ends a disable)."""
        if not msg.data:
            self._disable(self._held_at_s(info, topics.ENABLE), info)
        elif self._released(
            self.disable_hold, info, topics.ENABLE, "enable_ignored", "enable: true", "disable"
        ):
            self._set_enabled(True)

    def _disable(self, at_s: float, info: MessageInfo | None) -> None:
        """A disable published at ``at_s`` (wall clock): in force, unless taken before."""
        if self._engages(self.disable_deliveries, info, at_s):
            self.disable_hold.engage(at_s, time.time())
            self._set_enabled(False)

    def _set_enabled(self, on: bool) -> None:
        changed = self.filter.status.enabled != on
        self.filter.set_enabled(on)
        if changed or not on:  # a later disable moves the disable's time
            self._save_now()
        if changed:
            self.get_logger().info("enabled" if on else "disabled: gliding to neutral")

    def _hold_service(
        self, name: str, hold: Callable[[float, None], None], in_force: Hold, release: str
    ) -> None:
        """Serve ``name`` (std_srvs/Trigger): a request puts ``hold`` in force at once.

        A request is a hold and nothing else, read by a reader of its own: no flood of
        releases on the hold's topic can displace it, on any rclpy and middleware (the topic's
        reader of holds alone needs content filters). Its time is the node's when it serves the
        request (a request carries no publication time): only a ``release`` published after
        that ends it. The answer says whether the hold is in force (a failure: why, on
        /diagnostics).
        """
        guarded = self.guarded(hold)

        def serve(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            guarded(time.time(), None)
            response.success = in_force.in_force
            response.message = (
                f"in force until {release} is published after now"
                if response.success
                else "not in force: see /diagnostics"
            )
            return response

        self.create_service(Trigger, name, serve)

    def on_stop(self, msg: Bool, info: MessageInfo | None) -> None:
        """Emergency stop on / off (only a release published after the stop ends it)."""
        if msg.data:
            self._stop(self._held_at_s(info, topics.STOP), info)
        elif self._released(
            self.stop_hold, info, topics.STOP, "stop_release_ignored", "stop: false", "stop"
        ):
            self._set_stop(False)

    def _stop(self, at_s: float, info: MessageInfo | None) -> None:
        """A stop published at ``at_s`` (wall clock): in force, unless taken before."""
        if self._engages(self.stop_deliveries, info, at_s):
            self.stop_hold.engage(at_s, time.time())
            self._set_stop(True)

    def _set_stop(self, on: bool) -> None:
        changed = self.filter.status.stopped != on
        self.filter.set_stop(on)
        if changed or on:  # a later stop moves the stop's time
            self._save_now()
        if changed and on:
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
        """The tick timer: a tick put off for an arrival, or the fallback tick.

        Before the start, only the requested settings are taken.
        """
        if not self.started:
            self.filter.take_requested_settings()
        elif self.arrival_tick_due:
            self._tick_for_arrival()
        else:
            self.on_tick()

    def on_tick(self) -> None:
        """Advance the filter by one period and publish the outputs due at this tick."""
        self.filter.take_requested_settings()
        self.ticks += 1
        self.last_tick_s = time.monotonic()
        self.tick_stamp = self.get_clock().now()
        status = self.filter.status
        self.filter.tick(self.last_tick_s)
        self.measured.tracking.command(self.filter.position_rad, self.last_tick_s)
        if status.faults > self.faults_seen:
            self.faults_seen = status.faults
            self.report_problem("filter_fault", DiagnosticStatus.ERROR, status.last_fault)
        guard = self.filter.body_guard.status
        if guard.active:
            self.report_body_guard(guard)
        for key in self.pacing.due(self.last_tick_s):
            if self.publishers_by_output[key].get_subscription_count():  # no message for nobody
                self.publish_output[key]()
        self._save_if_due(self.last_tick_s)

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
        speed = self.settings.joint_angles_speed
        speed = speed if speed >= 0 else self.filter.limiter.settings.velocity_fraction
        msg = JointAnglesWithSpeed()
        msg.header.stamp = self._stamp()
        msg.joint_names = list(self.robot.names)
        # an array.array of the field's type is stored as is, a list checked value by value
        angles = np.ascontiguousarray(self.filter.position_rad, dtype=np.float32)
        msg.joint_angles = array.array("f", angles.tobytes())
        msg.speed = float(speed)
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
        """The node's input counters, ticks and requests beside the filter's figures."""
        now = time.monotonic()
        return {
            "started_from": self.started_from or "waiting",
            **self.intake.values(),
            "raw_messages_lost": self.raw_lost.lost,
            **self.report.values(now),
            "ticks": self.ticks,
            "last_command_age_ms": (
                f"{(now - self.last_tick_s) * 1e3:.0f}" if self.started else "none"
            ),
            **self.measured.values(now, self.filter.position_rad),
            "stops_engaged": self.stop_deliveries.engaged,
            "disables_engaged": self.disable_deliveries.engaged,
            "holds_filtered": self.holds_filtered,
        }


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(MotionFilterNode, "motion_filter_node", args)


if __name__ == "__main__":
    main()
