"""What the three nodes share: QoS profiles, message <-> numpy conversions, diagnostics, main()."""

from __future__ import annotations

import array
import contextlib
import faulthandler
import functools
import math
import os
import signal
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple, NoReturn

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.subscription import MessageInfo, Subscription
from std_msgs.msg import Float32MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

try:
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
except ImportError:  # Humble: the same classes (with use_default_callbacks) in rclpy.qos_event
    from rclpy.qos_event import PublisherEventCallbacks, SubscriptionEventCallbacks

from audio2pose_ros import topics
from audio2pose_ros.errors import (
    EXIT_CONFIGURATION_ERROR,
    ConfigurationError,
    InputError,
    short_text,
)
from audio2pose_ros.ros.nodes.process import STOP_SIGNALS

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


FRAMES_LABEL = "frames"  # dim[0] of a features message; "frames from N" numbers its first frame


class FeatureBatch(NamedTuple):
    """An unpacked features message."""

    frames: np.ndarray  # (n_frames, n_features) float32
    label: str  # the feature set (dim[1].label)
    first_frame: int | None  # index of the first frame in its stream, if the sender numbers them


def features_to_msg(
    frames: np.ndarray, label: str, first_frame: int | None = None
) -> Float32MultiArray:
    """Pack (n_frames, n_features) features; dim[1].label names the feature set.

    With ``first_frame``, dim[0].label is ``"frames from <first_frame>"``: the receiver counts
    the frames lost between messages (:class:`~audio2pose_ros.timebase.FrameSequence`). A
    receiver that reads only the sizes is unaffected.
    """
    n_frames, n_features = frames.shape
    msg = Float32MultiArray()
    frames_label = FRAMES_LABEL if first_frame is None else f"{FRAMES_LABEL} from {first_frame}"
    msg.layout.dim = [
        MultiArrayDimension(label=frames_label, size=n_frames, stride=n_frames * n_features),
        MultiArrayDimension(label=label, size=n_features, stride=n_features),
    ]
    # An array.array of the right type code is stored as is; a list is checked value by value.
    msg.data = array.array("f", np.ascontiguousarray(frames, dtype=np.float32).tobytes())
    return msg


def msg_to_features(msg: Float32MultiArray) -> FeatureBatch:
    """Unpack a features message; a dim[0].label other than ``"frames from <n>"`` numbers nothing.

    Raises:
        InputError: the layout does not describe the data (2 dims, frames x features, at least
            one feature per frame: a count of frames without data would be a claim, not data).
    """
    dims = msg.layout.dim
    if len(dims) != 2:
        raise InputError(f"features message needs 2 layout dims, got {len(dims)}")
    n_frames, n_features = dims[0].size, dims[1].size
    if n_features == 0:
        raise InputError(f"features message of {n_frames} frames of 0 features")
    data = np.frombuffer(msg.data, dtype=np.float32) if msg.data else np.zeros(0, np.float32)
    if data.size != n_frames * n_features:
        raise InputError(
            f"features message holds {data.size} values, layout says {n_frames}x{n_features}"
        )
    number = dims[0].label.removeprefix(f"{FRAMES_LABEL} from ")
    numbered = number != dims[0].label and number.isascii() and number.isdigit()
    first = int(number) if numbered and len(number) <= 18 else None  # within int64
    return FeatureBatch(data.reshape(n_frames, n_features), dims[1].label, first)


def duration_msg(seconds: float) -> Duration:
    """A builtin_interfaces/Duration of ``seconds``."""
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def trajectory_msg(
    joint_names: Sequence[str],
    positions_rad: np.ndarray,
    period_s: float,
    velocities_rad_s: np.ndarray | None = None,
) -> JointTrajectory:
    """A JointTrajectory with one point per row of ``positions_rad``, ``period_s`` apart.

    The first point is due one period after the header stamp.
    """
    msg = JointTrajectory()
    msg.joint_names = list(joint_names)
    positions = np.ascontiguousarray(np.atleast_2d(positions_rad), dtype=np.float64)
    velocities = (
        None
        if velocities_rad_s is None
        else np.ascontiguousarray(np.atleast_2d(velocities_rad_s), dtype=np.float64)
    )
    for i, row in enumerate(positions):
        point = JointTrajectoryPoint()
        point.positions = array.array("d", row.tobytes())  # stored as is, unlike a list
        if velocities is not None:
            point.velocities = array.array("d", velocities[i].tobytes())
        point.time_from_start = duration_msg((i + 1) * period_s)
        msg.points.append(point)
    return msg


def trajectory_positions(msg: JointTrajectory, joint_names: Sequence[str]) -> np.ndarray:
    """(n_points, n_joints) positions reordered to ``joint_names``.

    Raises:
        ValueError: a joint is missing, or a point has the wrong number of positions.

    """
    index = {name: i for i, name in enumerate(msg.joint_names)}
    missing = [n for n in joint_names if n not in index]
    if missing:
        raise ValueError(f"trajectory lacks joints {missing}")
    order = [index[n] for n in joint_names]
    rows = []
    for k, point in enumerate(msg.points):
        if len(point.positions) != len(msg.joint_names):
            raise ValueError(
                f"point {k} has {len(point.positions)} positions for {len(msg.joint_names)} joints"
            )
        rows.append(np.asarray(point.positions, dtype=np.float64)[order])
    return np.array(rows).reshape(-1, len(joint_names))


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
        self.heartbeats = 0
        self.last_heartbeat_s = time.monotonic()
        if self.get_parameter(USE_SIM_TIME).value is True:
            self.set_parameters([Parameter(USE_SIM_TIME, Parameter.Type.BOOL, False)])
            self.get_logger().warning(
                f"{USE_SIM_TIME} ignored: this node runs on the wall clock (it paces the robot "
                "and its heartbeat); stamps are wall-clock times"
            )
        self.add_on_set_parameters_callback(self._keep_wall_clock)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_timer(HEARTBEAT_PERIOD_S, self.guarded(self.publish_diagnostics))

    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **kwargs: Any
    ) -> Publisher[Any]:
        """A publisher without rclpy's default QoS event handlers.

        The SingleThreadedExecutor (the motion filter's) polls every event handler in Python at
        each wait; with the default two per publisher and subscription they were a tenth of the
        filter's CPU. A publisher's incompatible-QoS warning repeats what the subscriber's node
        logs, so it is left out.
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
            late_s = time.monotonic() - self.last_heartbeat_s
            if late_s > HEARTBEAT_OVERDUE_S:
                self.send_late_heartbeat(late_s)

        return boundary

    def create_bounded_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[..., None],
        qos: QoSProfile | int,
        max_bytes: int | Callable[[], int],
        with_info: bool = False,
    ) -> Subscription[Any]:
        """A guarded subscription that drops a message larger than ``max_bytes`` before decoding.

        rclpy turns every element of a message into a Python object before a callback sees it:
        a JointTrajectory of 100,000 points takes about a second to decode, during which the node
        serves nothing (no commands, no heartbeat). Here the message arrives serialized; one
        above ``max_bytes`` (an int, or a function giving the current cap) is dropped, counted in
        ``oversized_messages`` and reported, and only messages within the cap are decoded.
        With ``with_info`` the callback also gets rclpy's MessageInfo (publisher gid, source
        timestamp).
        """
        handler = self.guarded(callback)

        def receive(data: bytes, *info: MessageInfo) -> None:
            cap = max_bytes() if callable(max_bytes) else max_bytes
            if len(data) > cap:
                self.oversized_messages += 1
                self.report_problem(
                    f"oversized message on {topic}",
                    DiagnosticStatus.WARN,
                    f"dropped a {len(data)}-byte message on {topic} before decoding it "
                    f"(at most {cap} bytes)",
                )
                return
            handler(deserialize_message(data, msg_type), *info)

        def receive_with_info(data: bytes, info: MessageInfo) -> None:
            receive(data, info)

        entry = receive_with_info if with_info else receive  # rclpy counts the parameters
        entry.__name__ = getattr(callback, "__name__", "callback")
        return self.create_subscription(msg_type, topic, self.guarded(entry), qos, raw=True)

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


SPIN_ONCE_TIMEOUT_S = 0.5  # an idle EventsExecutor checks for shutdown this often
EXECUTOR_ENV = "AUDIO2POSE_EXECUTOR"  # "events" (default where available) or "single_threaded"


def create_executor(events: bool = True) -> Executor:
    """The executor the nodes spin in: rclpy's EventsExecutor where available, else single-threaded.

    The EventsExecutor (``rclpy.experimental``, Jazzy and later) is driven by middleware events
    instead of rebuilding a wait set in Python for every callback, which was the largest single
    item of the nodes' CPU (20-40 % of each node's samples under traffic); with it the
    three nodes used 2.9 instead of 4.2 ms CPU per 10 ms frame. Humble has none and gets the
    SingleThreadedExecutor; ``AUDIO2POSE_EXECUTOR=single_threaded`` forces it (for comparison,
    or should a distro's EventsExecutor misbehave). Spin it with :func:`spin_executor`.

    ``events=False`` asks for the SingleThreadedExecutor: the motion filter needs it, because the
    EventsExecutor (rclpy 9) hands no MessageInfo to a callback (the filter reads the publisher
    gid and the source timestamp of its inputs) and serves events first come, first served, so a
    flood on one topic delays the command timer by the whole backlog; the SingleThreadedExecutor
    serves every ready timer and subscription once per round, so the tick keeps its rate.
    """
    if events and os.environ.get(EXECUTOR_ENV, "events") != "single_threaded":
        try:
            from rclpy.experimental.events_executor import EventsExecutor
        except ImportError:  # Humble
            pass
        else:
            return EventsExecutor()
    return SingleThreadedExecutor()


def spin_executor(executor: Executor) -> None:
    """Spin until the context shuts down (Ctrl-C, SIGTERM, ``rclpy.shutdown``).

    The EventsExecutor is spun one event at a time: its ``spin()`` (rclpy 9.1) never ran a
    callback here, while ``spin_once`` serves timers and subscriptions as expected.
    """
    if isinstance(executor, SingleThreadedExecutor):
        executor.spin()
        return
    while executor.context.ok():
        executor.spin_once(timeout_sec=SPIN_ONCE_TIMEOUT_S)


def _refused(line: str) -> NoReturn:
    """End the process for a refused configuration: ``line`` on stderr and the terminal, exit 78."""
    print(line, file=sys.stderr, flush=True)
    to_terminal(line)
    raise SystemExit(EXIT_CONFIGURATION_ERROR) from None


def run_node(
    factory: Callable[[], Node],
    node_name: str,
    args: list[str] | None = None,
    events: bool = True,
) -> None:
    """The ros2/examples main for one node: see :func:`run_nodes`."""
    run_nodes([factory], node_name, args, events=events)


def run_nodes(
    factories: Sequence[Callable[[], Node]],
    process_name: str,
    args: list[str] | None = None,
    connect: Callable[[list[Node]], None] | None = None,
    events: bool = True,
) -> None:
    """Init, build the nodes, spin them in one executor until Ctrl-C / SIGTERM, clean up.

    One factory is the usual one node per process; several put nodes in one process and one
    executor (``audio2pose run --single-process``), where ``connect`` (called with the built
    nodes, in order, before spinning) wires them to each other; ``events`` goes to
    :func:`create_executor`. A
    :class:`~audio2pose_ros.errors.ConfigurationError` while a node is built (a refused
    parameter, a bad model or robot file), or arguments rcl cannot parse (a parameters file with
    a YAML syntax error, a missing file), end the process with one line on stderr (and on the
    user's terminal when stderr goes to a log: :func:`to_terminal`) and exit status
    :data:`EXIT_CONFIGURATION_ERROR`, which ``audio2pose run`` and the launch file never respawn.
    """
    try:
        # Ctrl-C or SIGTERM while rcl initialises or the nodes are built would shut the context
        # down under them: the signals wait until the nodes are ready (the node executables
        # block them from their first line, nodes.process), then rclpy's handler ends the spin.
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        # A supervisor about to kill a silent process first asks for every thread's stack
        # (written to stderr, the node's log), so a silent node says where it was stuck.
        faulthandler.register(STACK_DUMP_SIGNAL, all_threads=True)
        try:
            rclpy.init(args=args)  # not `with rclpy.init()`: Humble's init is no context manager
            executor = create_executor(events)
            nodes = [factory() for factory in factories]
            if connect is not None:
                connect(nodes)
            for node in nodes:
                executor.add_node(node)
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
            spin_executor(executor)
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
            rclpy.try_shutdown()
    except ConfigurationError as exc:
        _refused(f"[{process_name}] configuration error: {exc}")
    except rclpy_implementation.RCLError as exc:
        refused = " ".join(str(exc).split())
        _refused(f"[{process_name}] configuration error: ROS arguments refused: {refused}")
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
