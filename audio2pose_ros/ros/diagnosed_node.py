"""The base of every node: heartbeat, problems that describe the present, a callback boundary.

The QoS profiles are in :mod:`audio2pose_ros.ros.qos`, the supervisor's pipe in
:mod:`audio2pose_ros.ros.supervisor_pipe`, the paced timers in
:mod:`audio2pose_ros.ros.paced_timer`, bounded subscriptions and message info in
:mod:`audio2pose_ros.ros.subscriptions`, message conversions in
:mod:`audio2pose_ros.ros.messages`, the executor and ``main()`` in :mod:`audio2pose_ros.ros.spin`.
"""

from __future__ import annotations

import functools
import math
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError, InputError, short_text
from audio2pose_ros.ros.paced_timer import PacedTimer
from audio2pose_ros.ros.qos import incompatible_publishers, is_best_effort_volatile
from audio2pose_ros.ros.subscriptions import (
    LatestMessage,
    MessageInfo,
    bounded_receiver,
    info_callback,
    quiet_event_callbacks,
)
from audio2pose_ros.ros.supervisor_pipe import beat_to_supervisor

DIAGNOSTICS_PERIOD_S = 1.0
HEARTBEAT_PERIOD_S = 0.5  # every node publishes /diagnostics this often, busy or idle
STALE_AFTER_S = 1.2  # a node not heard from for this long is silent (stopped, frozen or dead)
USE_SIM_TIME = "use_sim_time"  # rclpy's parameter: the nodes keep it false (DiagnosedNode)
# A heartbeat this late is sent at the end of whichever callback runs next (DiagnosedNode).
HEARTBEAT_OVERDUE_S = 1.5 * HEARTBEAT_PERIOD_S
PROBLEM_HOLD_S = 5.0  # a reported problem is shown until this long after its last occurrence
LOG_THROTTLE_S = 5.0  # one log line per problem per this many seconds
MAX_LOGGED_TRACEBACKS = 5  # callback exceptions beyond this are counted, not printed again
# A problem's message, and a diagnostic value, at most this long: they may quote input (a label,
# a joint name) that a message can make hundreds of kilobytes long, on every heartbeat.
MAX_STATUS_TEXT = 400
QOS_CHECK_HEARTBEATS = 4  # the readers' QoS is checked against the graph every 2 s


def status_name(fully_qualified_name: str) -> str:
    """The /diagnostics status name of a node: ``audio2pose_ros: /<namespace>/<node>``.

    The namespace is part of it, so the nodes of two robots (``/pepper1``, ``/pepper2``) on one
    /diagnostics are told apart.
    """
    return f"audio2pose_ros: {fully_qualified_name}"


def diagnostic_array(
    node: Node, level: bytes, message: str, values: dict[str, object]
) -> DiagnosticArray:
    """A DiagnosticArray with one status named after the node (namespace included).

    Each key and value is cut to :data:`MAX_STATUS_TEXT` characters
    (:func:`~audio2pose_ros.errors.short_text`);
    the message holds the node's summary and its problems, each already cut so.
    """
    status = DiagnosticStatus(
        level=level,
        name=status_name(node.get_fully_qualified_name()),
        message=message,
        hardware_id="pepper",
        values=[
            KeyValue(key=short_text(k, MAX_STATUS_TEXT), value=short_text(str(v), MAX_STATUS_TEXT))
            for k, v in values.items()
        ],
    )
    array = DiagnosticArray()
    array.header.stamp = node.get_clock().now().to_msg()
    array.status = [status]
    return array


class StartupError(ConfigurationError):
    """A node cannot start with its parameters (bad model, robot file or settings)."""


@dataclass
class _Problem:
    """One current problem of a node: shown on /diagnostics until ``expires_s`` (monotonic)."""

    level: bytes
    message: str
    expires_s: float
    count: int = 1
    logged_s: float = -math.inf


class DiagnosedNode(Node):
    """Base of the three nodes: heartbeat, problems that describe the present, a callback boundary.

    - **Heartbeat.** /diagnostics is published every ``HEARTBEAT_PERIOD_S`` (0.5 s) whether or not
      anything happens, so a supervisor or diagnostic_aggregator notices a silent (stopped,
      frozen, dead) node within about a second (``STALE_AFTER_S``).
    - **The present.** :meth:`report_problem` records a problem under a key; it is shown, with how
      often it happened, until ``hold_s`` after its last report, then it disappears by itself,
      so a WARN never outlives its cause by more than ``hold_s``; :meth:`clear_problem` ends it.
    - **Boundary.** :meth:`guarded` wraps a callback: any exception is caught, logged with its
      traceback (throttled per callback), counted and reported as ERROR; the node keeps serving.
    - **A heartbeat behind a backlog.** No node depends on the order in which its executor
      serves callbacks: rclpy's EventsExecutor (opt-in) serves events in arrival order, so while
      messages arrive faster than the node serves them, a plain heartbeat timer waits behind the
      whole backlog (flooded with features, inference_node went 10 s without one, and a
      supervisor killed a node that was working). The heartbeat is a paced timer
      (:class:`~audio2pose_ros.ros.paced_timer.PacedTimer`), and a guarded callback that ends
      with the heartbeat
      ``HEARTBEAT_OVERDUE_S`` late therefore sends it, with the WARN ``falling behind`` (not
      before the first heartbeat: building a node may take longer than that). A node stuck
      inside a callback still sends nothing.
    - **Wall clock.** The nodes pace a real robot and their own heartbeat, so they run on the
      wall clock. With ``use_sim_time`` true (set globally to replay a bag with ``--clock``) and
      no /clock, every timer stopped: no command, no heartbeat, and a supervisor restarted the
      nodes again and again; a paused or looped bag would stop or rewind them. The node sets it
      back to false at start-up with a logged warning, and refuses to set it true while it runs.

    Subclasses add their figures with :meth:`diagnostic_values` and their own state with
    :meth:`diagnostic_summary`.
    """

    def __init__(self, node_name: str) -> None:
        """Create the /diagnostics publisher and the heartbeat timer."""
        # set before rclpy's Node subscribes to anything (its /clock, with use_sim_time)
        self.checked_readers: list[tuple[str, QoSProfile]] = []  # check_publishers_qos
        super().__init__(node_name)
        self._problems: dict[str, _Problem] = {}
        self.callback_errors = 0
        self.input_messages_refused = 0  # InputError at the boundary: bad input, not a bug
        self.oversized_messages = 0
        self.late_heartbeats = 0
        self.heartbeats = 0
        self.service_requests = 0  # requests the node's services served (parameter services)
        self.last_heartbeat_s = time.monotonic()
        if self.get_parameter(USE_SIM_TIME).value is True:
            self.set_parameters([Parameter(USE_SIM_TIME, Parameter.Type.BOOL, False)])
            self.get_logger().warning(
                f"{USE_SIM_TIME} ignored: this node runs on the wall clock (it paces the robot "
                "and its heartbeat); stamps are wall-clock times"
            )
        self.add_on_set_parameters_callback(self._keep_wall_clock)
        self.paced_timers: list[PacedTimer] = []  # run between callbacks when overdue
        self._running_overdue = False
        self.latest_inputs: list[LatestMessage] = []  # inputs whose newest message a timer takes
        for service in self.services:  # rclpy's parameter services: a storm is a flood too
            service.callback = self._then_overdue_timers(service.callback)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_paced_timer(HEARTBEAT_PERIOD_S, self.publish_diagnostics)

    def create_paced_timer(self, period_s: float, callback: Callable[[], None]) -> PacedTimer:
        """A guarded timer that keeps its rate behind any backlog of messages (:class:`PacedTimer`).

        For the timers safety depends on: the heartbeat, a robot's joint_states, a command tick.
        """
        timer = PacedTimer(period_s, self.guarded(callback))
        timer.timer = self.create_timer(period_s, timer.on_timer)
        self.paced_timers.append(timer)
        return timer

    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **kwargs: Any
    ) -> Publisher[Any]:
        """A publisher without rclpy's default QoS event handlers.

        The SingleThreadedExecutor polls every event handler in Python at each wait; with the
        default two per publisher and subscription they were a tenth of the motion filter's CPU.
        A publisher's incompatible-QoS warning repeats what the subscriber's node logs, so it is
        left out.
        """
        kwargs.setdefault("event_callbacks", quiet_event_callbacks("Publisher"))
        return super().create_publisher(msg_type, topic, qos_profile, **kwargs)

    def create_subscription(
        self,
        msg_type: Any,
        topic: str,
        callback: Callable[..., None],
        qos_profile: QoSProfile | int,
        **kwargs: Any,
    ) -> Subscription[Any]:
        """A subscription without rclpy's default QoS event handlers (polled at every wait).

        A reliable or latched reader is checked against its topic's publishers from the graph
        instead, every ``QOS_CHECK_HEARTBEATS`` heartbeats (:meth:`check_publishers_qos`): a
        publisher it cannot match (a best-effort ``stop``) is a WARN on /diagnostics. Every
        publisher is compatible with a best-effort, volatile reader: it is not checked.
        """
        kwargs.setdefault("event_callbacks", quiet_event_callbacks("Subscription"))
        subscription = super().create_subscription(msg_type, topic, callback, qos_profile, **kwargs)
        qos = qos_profile if isinstance(qos_profile, QoSProfile) else QoSProfile(depth=qos_profile)
        if not is_best_effort_volatile(qos):
            self.checked_readers.append((subscription.topic_name, qos))
        return subscription

    def check_publishers_qos(self) -> None:
        """WARN about each publisher a reader of this node cannot match (from the graph)."""
        for topic, qos in self.checked_readers:
            publishers = incompatible_publishers(self, topic, qos)
            if publishers:
                self.report_problem(
                    f"incompatible QoS on {topic}",
                    DiagnosticStatus.WARN,
                    f"{', '.join(publishers)} publishes {topic} with a QoS this node's reader "
                    "cannot match: none of its messages arrive (publish reliable, and "
                    "transient local where the topic is latched)",
                    hold_s=QOS_CHECK_HEARTBEATS * HEARTBEAT_PERIOD_S + PROBLEM_HOLD_S,
                )

    def _keep_wall_clock(self, parameters: list[Parameter[Any]]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == USE_SIM_TIME and parameter.value is True:
                return SetParametersResult(
                    successful=False,
                    reason=f"{USE_SIM_TIME} cannot be true: this node runs on the wall clock",
                )
        return SetParametersResult(successful=True)

    # --- problems -----------------------------------------------------------------------------

    def report_problem(
        self, key: str, level: bytes, message: str, hold_s: float = PROBLEM_HOLD_S
    ) -> None:
        """Record (or renew) the problem ``key`` and log it, at most once per ``LOG_THROTTLE_S``.

        Args:
            key: what went wrong, as a stable identifier (e.g. ``"audio_info_rejected"``).
            level: DiagnosticStatus.WARN or DiagnosticStatus.ERROR.
            message: one line saying what happened and what was done about it (cut to
                :data:`MAX_STATUS_TEXT` characters: it may quote input).
            hold_s: the problem is reported until this long after its last report (s).
        """
        now = time.monotonic()
        message = short_text(message, MAX_STATUS_TEXT)  # it may quote input of any length
        problem = self._problems.get(key)
        if problem is None or problem.expires_s < now:
            problem = self._problems[key] = _Problem(level, message, now + hold_s, count=0)
        problem.level, problem.message, problem.expires_s = level, message, now + hold_s
        problem.count += 1
        if now - problem.logged_s >= LOG_THROTTLE_S:
            problem.logged_s = now
            repeats = f" ({problem.count} times)" if problem.count > 1 else ""
            if level == DiagnosticStatus.ERROR:
                self.get_logger().error(message + repeats)
            else:
                self.get_logger().warning(message + repeats)

    def clear_problem(self, key: str) -> None:
        """The problem ``key`` is over (no-op when it is not reported)."""
        self._problems.pop(key, None)

    def current_problems(self) -> dict[str, tuple[bytes, str, int]]:
        """Problems reported now: key -> (level, message, occurrences)."""
        now = time.monotonic()
        for key in [k for k, p in self._problems.items() if p.expires_s < now]:
            del self._problems[key]
        return {k: (p.level, p.message, p.count) for k, p in self._problems.items()}

    # --- exception boundary -------------------------------------------------------------------

    def guarded(self, callback: Callable[..., None]) -> Callable[..., None]:
        """``callback`` behind the node boundary: an exception is reported, never fatal.

        An :class:`~audio2pose_ros.errors.InputError` is bad input, not a bug: the message is
        dropped, counted (``input_messages_refused``) and reported as a WARN naming the
        callback, without a traceback. Any other exception is a bug: counted in
        ``callback_errors``, reported as an ERROR, its traceback logged.
        """
        name = getattr(callback, "__name__", "callback")

        @functools.wraps(callback)
        def boundary(*args: object) -> None:
            try:
                callback(*args)
            except InputError as exc:
                self.report_failure(name, str(exc), refused=True)
            except Exception as exc:  # the boundary: a bug or bad input must not kill the node
                message = f"{type(exc).__name__}: {exc}"
                self.report_failure(name, message, refused=False, trace=traceback.format_exc())
            now = time.monotonic()
            late_s = now - self.last_heartbeat_s
            if late_s > HEARTBEAT_OVERDUE_S:
                self.send_late_heartbeat(late_s)
            self.run_overdue_timers(now)

        return boundary

    def report_failure(self, name: str, message: str, refused: bool, trace: str = "") -> None:
        """Count and report what the callback ``name`` met, as :meth:`guarded` does.

        Bad input (``refused``): counted in ``input_messages_refused``, a WARN. Otherwise a bug:
        counted in ``callback_errors``, an ERROR, its ``trace`` logged (the first few only).
        Also for work a node does outside its executor's callbacks (a thread of its own).
        """
        if refused:
            self.input_messages_refused += 1
            self.report_problem(
                f"bad input to {name}",
                DiagnosticStatus.WARN,
                f"{name}: input refused and dropped: {message}",
            )
            return
        self.callback_errors += 1
        self.report_problem(
            f"exception in {name}",
            DiagnosticStatus.ERROR,
            f"{name} failed and was skipped: {message}",
        )
        if trace and self.callback_errors <= MAX_LOGGED_TRACEBACKS:
            self.get_logger().error(trace)

    def _then_overdue_timers(self, serve: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """A service callback, counted, after which the overdue paced timers run."""

        @functools.wraps(serve)
        def then(request: Any, response: Any) -> Any:
            self.service_requests += 1
            try:
                return serve(request, response)
            finally:
                self.run_overdue_timers(time.monotonic())

        return then

    def run_overdue_timers(self, now: float) -> None:
        """Run the paced timers overdue at ``now`` (monotonic), between two callbacks.

        Called at the end of every guarded callback and service request (the parameter
        services: a storm of set_parameters requests is a flood too) and by
        :func:`~audio2pose_ros.ros.spin.spin_executor` between two events: the executor may serve
        many messages in one event (the middleware reports several at once), so a timer waits behind
        at most one callback. Not nested: a paced timer's own callback ends here too.
        """
        if self._running_overdue:
            return
        self._running_overdue = True
        try:
            for timer in self.paced_timers:
                timer.run_if_overdue(now)
        finally:
            self._running_overdue = False

    def create_bounded_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[..., None],
        qos: QoSProfile | int,
        max_bytes: int | Callable[[], int],
        with_info: bool = False,
        content_filter: Any | None = None,
    ) -> Subscription[Any]:
        """A guarded subscription that drops a message larger than ``max_bytes`` before decoding.

        The message arrives serialized; one above ``max_bytes`` (an int, or a function giving the
        current cap) is dropped, counted in ``oversized_messages`` and reported, and only
        messages within the cap are decoded
        (:func:`~audio2pose_ros.ros.subscriptions.bounded_receiver`). With ``with_info`` the
        callback also gets the message's info (publisher, source and reception timestamps), or
        None where rclpy gives none (Humble, the EventsExecutor:
        :func:`~audio2pose_ros.ros.subscriptions.info_callback`). ``content_filter`` (from
        :func:`~audio2pose_ros.ros.subscriptions.content_filter_options`, Kilted's rclpy only)
        has the middleware deliver only the messages it matches, where it filters content.
        """

        def deliver(message: Any, info: MessageInfo | None) -> None:
            if with_info:
                callback(message, info)
            else:
                callback(message)

        receive = bounded_receiver(
            msg_type, max_bytes, deliver, lambda n, cap: self.drop_oversized(topic, n, cap)
        )
        receive.__name__ = getattr(callback, "__name__", "callback")
        options = {} if content_filter is None else {"content_filter_options": content_filter}
        return self.create_subscription(
            msg_type, topic, info_callback(self.guarded(receive)), qos, raw=True, **options
        )

    def create_latest_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        depth: int,
        max_bytes: int,
    ) -> LatestMessage:
        """A best-effort subscription of ``depth`` whose messages coalesce (:class:`LatestMessage`).

        Call its ``serve()`` from the timer that uses the input: ``callback`` (guarded) gets the
        newest message; those it replaced unserved are counted in ``messages_superseded``, one
        over ``max_bytes`` is dropped and counted as by :meth:`create_bounded_subscription`.
        Best effort, which every publisher matches: a reliable reader acknowledges each message
        in the middleware's threads, which under a flood took the CPU the timers needed (27
        joint_states a second instead of 49), and only the newest is used anyway.
        """
        latest = LatestMessage(
            msg_type,
            self.guarded(callback),
            max_bytes,
            lambda n, cap: self.drop_oversized(topic, n, cap),
        )
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(
            msg_type, topic, info_callback(self.guarded(latest.receive)), qos, raw=True
        )
        self.latest_inputs.append(latest)
        return latest

    def drop_oversized(self, topic: str, n_bytes: int, cap: int) -> None:
        """Count and report a message on ``topic`` of ``n_bytes`` over ``cap``, not decoded."""
        self.oversized_messages += 1
        self.report_problem(
            f"oversized message on {topic}",
            DiagnosticStatus.WARN,
            f"dropped a {n_bytes}-byte message on {topic} before decoding it (at most {cap} bytes)",
        )

    # --- publication --------------------------------------------------------------------------

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """The node's own level and one-line state (override; problems are added to it)."""
        return DiagnosticStatus.OK, "ok"

    def diagnostic_values(self) -> dict[str, object]:
        """Figures shown as key/values (override)."""
        return {}

    def send_late_heartbeat(self, late_s: float) -> None:
        """Send a heartbeat the timer has not sent for ``late_s``, and say the node is behind.

        Before the first heartbeat the lateness is the node's start-up, not a backlog: the
        heartbeat is sent without a warning.
        """
        if self.heartbeats:
            self.late_heartbeats += 1
            self.report_problem(
                "falling behind",
                DiagnosticStatus.WARN,
                f"heartbeat timer {late_s:.1f} s late: callbacks kept the node busy (messages "
                "arriving faster than it serves them, whose subscription queues keep only the "
                "newest, or a slow callback); heartbeat sent between callbacks",
            )
        try:
            self.publish_diagnostics()
        except Exception:  # as the timer's heartbeat would be: counted, never fatal
            self.callback_errors += 1

    def publish_diagnostics(self) -> None:
        """Publish the heartbeat: the worst of the summary and the current problems."""
        self.last_heartbeat_s = time.monotonic()
        self.heartbeats += 1
        if self.heartbeats % QOS_CHECK_HEARTBEATS == 1:
            self.check_publishers_qos()
        level, message = self.diagnostic_summary()
        problems = self.current_problems()
        values = dict(self.diagnostic_values())
        values["pid"] = os.getpid()  # tells a supervisor which process of the node is alive
        values["callback_errors"] = self.callback_errors
        values["input_messages_refused"] = self.input_messages_refused
        values["oversized_messages_dropped"] = self.oversized_messages
        values["late_heartbeats"] = self.late_heartbeats
        values["service_requests_served"] = self.service_requests
        values["messages_superseded"] = sum(latest.dropped for latest in self.latest_inputs)
        values["timer_runs_between_messages"] = sum(
            timer.runs_between_events for timer in self.paced_timers
        )
        for key, (problem_level, problem_message, count) in problems.items():
            level = max(level, problem_level)
            message += f"; {problem_message}" + (f" ({count}x)" if count > 1 else "")
            values[f"problem: {key}"] = count
        self.diagnostics_pub.publish(diagnostic_array(self, level, message, values))
        beat_to_supervisor()
