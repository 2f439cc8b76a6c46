"""What the nodes share: QoS profiles, the diagnosed node (heartbeat, problems, callback boundary).

Message conversions live in :mod:`audio2pose_ros.ros.messages`, the executor and ``main()`` in
:mod:`audio2pose_ros.ros.spin`.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
import signal
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.service import Service
from rclpy.subscription import MessageInfo, Subscription
from rclpy.timer import Timer

try:
    from rclpy.type_support import check_is_valid_msg_type
except ImportError:  # Humble
    from rclpy.type_support import check_for_type_support as check_is_valid_msg_type  # type: ignore[assignment]
try:
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
except ImportError:  # Humble: the same classes (with use_default_callbacks) in rclpy.qos_event
    from rclpy.qos_event import PublisherEventCallbacks, SubscriptionEventCallbacks

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError, InputError, short_text

# Audio: best effort matches both reliable and best-effort publishers (audio_capture is reliable);
# a deep queue absorbs bursts from GStreamer without dropping chunks.
AUDIO_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT
)
# AudioInfo is latched (transient local) by audio_capture and republished every 5 s.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Between our own nodes: reliable, so no feature frame or pose is lost silently.
STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE
)
DIAGNOSTICS_PERIOD_S = 1.0
HEARTBEAT_PERIOD_S = 0.5  # every node publishes /diagnostics this often, busy or idle
# A supervisor passes the write end of a pipe in this variable: each heartbeat also writes a byte
# there. Only the supervised process holds that descriptor, so no other process can fake it.
HEARTBEAT_FD_ENV = "AUDIO2POSE_HEARTBEAT_FD"
# A supervisor that writes a node's output to a log file passes its own stderr (the user's
# terminal) in this variable: what the user must act on is written there too (to_terminal).
TERMINAL_FD_ENV = "AUDIO2POSE_TERMINAL_FD"
# A node process given this signal writes every thread's Python stack to stderr and runs on.
STACK_DUMP_SIGNAL = signal.SIGUSR1
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


class PacedTimer:
    """A periodic callback that a backlog of messages cannot delay by more than one message.

    rclpy's EventsExecutor serves its events first come, first served: a timer that falls due
    while messages arrive faster than the node serves them waits behind every message queued
    before it, which under a flood is all of them (a flooded simulated Pepper sent 0-2
    joint_states a second, and no heartbeat for seconds). The executor is therefore spun one
    event at a time (:func:`~audio2pose_ros.ros.spin.spin_executor`) and, between two events
    and after every guarded callback (:meth:`DiagnosedNode.run_overdue_timers`), a paced timer
    more than ``OVERDUE_GRACE`` of its period past its due time runs there
    (:meth:`run_if_overdue`, counted in ``runs_between_events``); when the executor's own timer
    event comes later, it finds the run done and skips it (:meth:`on_timer`). Due times keep
    their phase: a timer served between events keeps its rate, never bursts to make up for a
    missed period, and an idle node runs it from the executor's timer as before.

    The schedule may change while the node runs: :meth:`schedule` moves the next run (and the
    executor's timer, ``timer``, with it) and may give a new period, after which the runs
    follow that period again; :meth:`cancel` stops the runs until the next :meth:`schedule`.
    A run never starts inside the callback's own run (where a request served from the motion
    filter's tick runs the overdue timers, which would otherwise tick again within the tick).
    """

    OVERDUE_GRACE = 0.25  # of the period: a timer this late is run between events

    def __init__(
        self,
        period_s: float,
        callback: Callable[[], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Due first one period from now (``clock``), like rclpy's timer created beside it."""
        self.period_s = period_s
        self.callback = callback
        self.clock = clock
        self.next_due_s = clock() + period_s
        self.runs_between_events = 0
        self.cancelled = False
        self.timer: Timer | None = None  # the executor's timer (create_paced_timer), if any
        self._timer_ns = _period_ns(period_s)  # the executor's timer's period now
        self._running = False  # within the callback

    def schedule(self, delay_s: float, period_s: float | None = None) -> None:
        """Run next ``delay_s`` from now, then every ``period_s`` (None: the period in force).

        The executor's timer is re-programmed to fire then (a cancelled timer restarts).
        """
        if period_s is not None:
            self.period_s = period_s
        self.next_due_s = self.clock() + delay_s
        self.cancelled = False
        self._program(delay_s)

    def cancel(self) -> None:
        """No more runs until the next :meth:`schedule` (the executor's timer is cancelled)."""
        self.cancelled = True
        if self.timer is not None:
            self.timer.cancel()

    def on_timer(self) -> None:
        """The executor's timer event: run unless the last run already served this period."""
        now = self.clock()
        if not (self.cancelled or self._running) and now >= self.next_due_s - 0.5 * self.period_s:
            self._run(now)

    def run_if_overdue(self, now: float) -> None:
        """Run now if the executor's timer event is overdue (it waits behind messages)."""
        overdue = now >= self.next_due_s + self.OVERDUE_GRACE * self.period_s
        if overdue and not (self.cancelled or self._running):
            self.runs_between_events += 1
            self._run(now)

    def _run(self, now: float) -> None:
        self.next_due_s += self.period_s
        if self.next_due_s <= now:  # a whole period missed (a slow callback): no catch-up burst
            self.next_due_s = now + self.period_s
        if self._timer_ns != _period_ns(self.period_s):  # programmed for a scheduled delay
            self._program(self.period_s)
        self._running = True
        try:
            self.callback()
        finally:
            self._running = False

    def _program(self, delay_s: float) -> None:
        """The executor's timer fires ``delay_s`` from now, then every ``delay_s``."""
        if self.timer is None:
            return
        period_ns = _period_ns(delay_s)
        if period_ns != self._timer_ns:
            self.timer.timer_period_ns = self._timer_ns = period_ns
        self.timer.reset()


def _period_ns(period_s: float) -> int:
    """A timer period in whole nanoseconds, at least 1 (rcl refuses 0 for a periodic timer)."""
    return max(round(period_s * 1e9), 1)


MAX_PUBLISHERS_TRACKED = 64  # per polled input: publishers whose sequence numbers are followed


class LatestMessage:
    """A subscription the executor never serves: the timer that uses it takes the newest message.

    For inputs where the newest message replaces the ones before it (a robot's command). The
    rcl subscription is not registered with the node, so no executor takes its messages one by
    one: the middleware keeps the newest ``depth`` of them and :meth:`serve` (called from the
    timer that uses the input) takes them all, decodes only the newest and passes it to the
    callback. A flood therefore costs the node no Python work per message, and no event queued
    before its timers. Every message replaced unserved is counted: those taken and passed over,
    and those the middleware dropped, from each publisher's sequence numbers.
    """

    def __init__(
        self,
        node: DiagnosedNode,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        max_bytes: int,
    ) -> None:
        """Create the rcl subscription on ``node`` (``topic`` resolved as any of its topics)."""
        self.node = node
        self.msg_type = msg_type
        self.topic = topic
        self.callback = callback
        self.max_bytes = max_bytes
        self.depth = qos.depth
        self.last_sequence: dict[bytes, int] = {}  # publisher gid -> last sequence number seen
        check_is_valid_msg_type(msg_type)  # loads its type support, as create_subscription does
        with node.handle:
            try:  # rclpy 9 takes content filter options; older ones do not
                self.handle: Any = rclpy_implementation.Subscription(
                    node.handle, msg_type, topic, qos.get_c_qos_profile(), None
                )
            except TypeError:
                self.handle = rclpy_implementation.Subscription(
                    node.handle, msg_type, topic, qos.get_c_qos_profile()
                )

    def serve(self) -> None:
        """Take every waiting message, count the superseded ones, pass on the newest."""
        newest: bytes | None = None
        for _ in range(self.depth):  # the middleware holds at most this many
            taken = self.handle.take_message(self.msg_type, True)
            if taken is None:
                break
            data, info = taken
            self._count_dropped_before(info)
            if len(data) > self.max_bytes:
                self.node.drop_oversized(self.topic, len(data), self.max_bytes)
                continue
            if newest is not None:
                self.node.messages_superseded += 1
            newest = data
        if newest is not None:
            self.callback(deserialize_message(newest, self.msg_type))

    def _count_dropped_before(self, info: MessageInfo) -> None:
        sequence = info.get("publication_sequence_number")
        gid = info.get("publisher_gid")
        if not isinstance(sequence, int) or not isinstance(gid, dict):
            return
        key = bytes(gid.get("data", b""))
        last = self.last_sequence.pop(key, None)
        if last is not None and sequence > last + 1:
            self.node.messages_superseded += sequence - last - 1
        if len(self.last_sequence) >= MAX_PUBLISHERS_TRACKED:
            del self.last_sequence[next(iter(self.last_sequence))]  # the longest unheard
        self.last_sequence[key] = sequence

    def destroy(self) -> None:
        """Destroy the rcl subscription (before its node)."""
        self.handle.destroy_when_not_in_use()


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
    - **A heartbeat behind a backlog.** rclpy's EventsExecutor serves events in arrival order, so
      while messages arrive faster than the node serves them, its heartbeat timer waits behind
      the whole backlog: flooded with features, inference_node went 10 s without one, and a
      supervisor killed a node that was working. A guarded callback that ends with the heartbeat
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
        super().__init__(node_name)
        self._problems: dict[str, _Problem] = {}
        self.callback_errors = 0
        self.input_messages_refused = 0  # InputError at the boundary: bad input, not a bug
        self.oversized_messages = 0
        self.late_heartbeats = 0
        self.messages_superseded = 0  # replaced unserved by a newer one (LatestMessage)
        self.heartbeats = 0
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
        self._polled: list[LatestMessage] = []  # subscriptions served by a timer's serve()
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

    @property
    def services(self) -> Iterator[Service[Any, Any]]:
        """The services the executor serves: all but those withheld (:meth:`withhold_services`)."""
        withheld = getattr(self, "_withheld_services", ())
        return (service for service in super().services if service not in withheld)

    def withhold_services(self, services: Sequence[Service[Any, Any]]) -> None:
        """Keep ``services`` from the executor: the node takes their requests itself.

        Either executor serves only the services a node lists (:attr:`services`); the requests
        of a withheld one wait in the middleware's queue until the node takes them
        (:class:`~audio2pose_ros.ros.request_budget.RequestBudget`). They are still destroyed
        with the node.
        """
        self._withheld_services = frozenset(services)

    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **kwargs: Any
    ) -> Publisher[Any]:
        """A publisher without rclpy's default QoS event handlers.

        The SingleThreadedExecutor (Humble's, or ``AUDIO2POSE_EXECUTOR=single_threaded``) polls
        every event handler in Python at each wait; with the default two per publisher and
        subscription they were a tenth of the motion filter's CPU. A publisher's incompatible-QoS
        warning repeats what the subscriber's node logs, so it is left out.
        """
        kwargs.setdefault("event_callbacks", PublisherEventCallbacks(use_default_callbacks=False))
        return super().create_publisher(msg_type, topic, qos_profile, **kwargs)

    def create_subscription(
        self,
        msg_type: Any,
        topic: str,
        callback: Callable[..., None],
        qos_profile: QoSProfile | int,
        **kwargs: Any,
    ) -> Subscription[Any]:
        """A subscription; a best-effort one without rclpy's default QoS event handlers.

        Every publisher is compatible with a best-effort, volatile reader, so its
        incompatible-QoS warning can never come; a reliable or latched reader keeps it (a
        best-effort ``stop`` publisher is refused with that warning).
        """
        best_effort = (
            isinstance(qos_profile, QoSProfile)
            and qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
            and qos_profile.durability != DurabilityPolicy.TRANSIENT_LOCAL
        )
        if best_effort:
            kwargs.setdefault(
                "event_callbacks", SubscriptionEventCallbacks(use_default_callbacks=False)
            )
        return super().create_subscription(msg_type, topic, callback, qos_profile, **kwargs)

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
                self.input_messages_refused += 1
                self.report_problem(
                    f"bad input to {name}",
                    DiagnosticStatus.WARN,
                    f"{name}: input refused and dropped: {exc}",
                )
            except Exception as exc:  # the boundary: a bug or bad input must not kill the node
                self.callback_errors += 1
                self.report_problem(
                    f"exception in {name}",
                    DiagnosticStatus.ERROR,
                    f"{name} failed and was skipped: {type(exc).__name__}: {exc}",
                )
                if self.callback_errors <= MAX_LOGGED_TRACEBACKS:
                    self.get_logger().error(traceback.format_exc())
            now = time.monotonic()
            late_s = now - self.last_heartbeat_s
            if late_s > HEARTBEAT_OVERDUE_S:
                self.send_late_heartbeat(late_s)
            self.run_overdue_timers(now)

        return boundary

    def _then_overdue_timers(self, serve: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """A service callback after which the overdue paced timers run."""

        @functools.wraps(serve)
        def then(request: Any, response: Any) -> Any:
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
        decode: Callable[[bytes], Any] | None = None,
    ) -> Subscription[Any]:
        """A guarded subscription that drops a message larger than ``max_bytes`` before decoding.

        rclpy turns every element of a message into a Python object before a callback sees it:
        a JointTrajectory of 100,000 points takes about a second to decode, during which the node
        serves nothing (no commands, no heartbeat). Here the message arrives serialized; one
        above ``max_bytes`` (an int, or a function giving the current cap) is dropped, counted in
        ``oversized_messages`` and reported, and only messages within the cap are decoded.
        With ``with_info`` the callback also gets rclpy's MessageInfo (publisher gid, source
        and reception timestamps), under either executor: the SingleThreadedExecutor passes
        the message and its info as two arguments, rclpy 9's EventsExecutor as one tuple.
        ``decode`` reads the bytes instead of rclpy's deserializer (e.g.
        :func:`~audio2pose_ros.ros.cdr.read_joint_trajectory`); the callback gets what it returns.
        """
        read = decode or (lambda data: deserialize_message(data, msg_type))

        def receive(data: bytes, *info: MessageInfo) -> None:
            cap = max_bytes() if callable(max_bytes) else max_bytes
            if len(data) > cap:
                self.drop_oversized(topic, len(data), cap)
                return
            callback(read(data), *info)  # within the boundary below

        def receive_with_info(
            data: bytes | tuple[bytes, MessageInfo], info: MessageInfo | None = None
        ) -> None:
            if isinstance(data, tuple):  # the EventsExecutor: (message, info) as one argument
                data, info = data
            assert info is not None
            receive(data, info)

        entry = receive_with_info if with_info else receive
        entry.__name__ = getattr(callback, "__name__", "callback")
        subscription = self.create_subscription(msg_type, topic, self.guarded(entry), qos, raw=True)
        if with_info:  # rclpy takes a callback with a default second parameter for message-only
            subscription._callback_type = Subscription.CallbackType.WithMessageInfo
        return subscription

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
        joint_states a second instead of 49), and only the newest is used anyway; a message
        lost on the way shows in the publisher's sequence numbers and is counted too.
        """
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)
        latest = LatestMessage(self, msg_type, topic, self.guarded(callback), qos, max_bytes)
        self._polled.append(latest)
        return latest

    def drop_oversized(self, topic: str, n_bytes: int, cap: int) -> None:
        """Count and report a message on ``topic`` of ``n_bytes`` over ``cap``, not decoded."""
        self.oversized_messages += 1
        self.report_problem(
            f"oversized message on {topic}",
            DiagnosticStatus.WARN,
            f"dropped a {n_bytes}-byte message on {topic} before decoding it (at most {cap} bytes)",
        )

    def destroy_node(self) -> None:
        """Destroy the polled subscriptions, then the node."""
        for latest in self._polled:
            latest.destroy()
        self._polled.clear()
        super().destroy_node()

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
        level, message = self.diagnostic_summary()
        problems = self.current_problems()
        values = dict(self.diagnostic_values())
        values["pid"] = os.getpid()  # tells a supervisor which process of the node is alive
        values["callback_errors"] = self.callback_errors
        values["input_messages_refused"] = self.input_messages_refused
        values["oversized_messages_dropped"] = self.oversized_messages
        values["late_heartbeats"] = self.late_heartbeats
        values["messages_superseded"] = self.messages_superseded
        values["timer_runs_between_messages"] = sum(
            timer.runs_between_events for timer in self.paced_timers
        )
        for key, (problem_level, problem_message, count) in problems.items():
            level = max(level, problem_level)
            message += f"; {problem_message}" + (f" ({count}x)" if count > 1 else "")
            values[f"problem: {key}"] = count
        self.diagnostics_pub.publish(diagnostic_array(self, level, message, values))
        beat_to_supervisor()


def beat_to_supervisor() -> None:
    """Write one heartbeat byte to the supervisor's pipe (``HEARTBEAT_FD_ENV``), if there is one.

    Never blocks: a full pipe (a supervisor that does not read) or a closed one is ignored.
    """
    fd = os.environ.get(HEARTBEAT_FD_ENV, "")
    if fd.isdigit():
        try:
            os.set_blocking(int(fd), False)
            os.write(int(fd), b".")
        except OSError:
            pass


def to_terminal(line: str) -> None:
    """Write ``line`` to the user's terminal as well, when the node's output goes to a log file.

    ``audio2pose run``, ``console`` and ``demo`` with a log directory send each node's stdout and
    stderr to ``<dir>/<node>.log`` and pass their own stderr in ``TERMINAL_FD_ENV``: the lines a
    user must see (the console's address with its token, a refused configuration) are written
    there too. Without it (output on a terminal already, or ``ros2 launch``) nothing is written.
    A terminal that is gone is ignored: the line is in the log either way.
    """
    fd = os.environ.get(TERMINAL_FD_ENV, "")
    if fd.isdigit():
        with contextlib.suppress(OSError):
            os.write(int(fd), (line.rstrip("\n") + "\n").encode("utf-8", "replace"))
