"""``audio2pose run``: start the node graph as processes, play a WAV into it, record its output.

This is what ``ros2 launch audio2pose_ros pepper.launch.py`` does, for machines without a ROS
distro: the same three executables, each its own process, with the same parameter file; or,
with ``single_process``, the same three nodes in one process and one executor
(:mod:`audio2pose_ros.ros.nodes.single_process`). The player
(:mod:`audio2pose_ros.ros.player`) publishes audio_common_msgs AudioInfo (latched) and AudioData
chunks in real time; the recorder writes every command the robot would receive to a rosbag2
(MCAP).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field, replace
from pathlib import Path

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    AUDIO_TOPIC_TYPES,
    BagError,
    BagMessage,
    BagWriter,
    Chunking,
    audio_messages,
    read_checked_messages,
)
from audio2pose_ros.errors import (
    EXIT_CONFIGURATION_ERROR,
    Audio2PoseError,
    ConfigurationError,
    UsageError,
)
from audio2pose_ros.files import load_yaml_text
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.diagnosed_node import (
    HEARTBEAT_FD_ENV,
    HEARTBEAT_PERIOD_S,
    STACK_DUMP_SIGNAL,
    STALE_AFTER_S,
    TERMINAL_FD_ENV,
    status_name,
)
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.player import MessagePlayer, rclpy_session, spin_until, warm_up
from audio2pose_ros.ros.voice_graph import voice_out_processes

NODE_EXECUTABLES = ("audio_features_node", "inference_node", "motion_filter_node")
RECORD_FLUSH_PERIOD_S = 0.5  # a killed recording loses at most about this much (BagWriter.flush)
SIM_NODE = "pepper_sim_node"  # the simulated robot (audio2pose run --sim)
SINGLE_PROCESS = "audio2pose_nodes"  # the process that runs all three nodes (single-process mode)
# As the launch file does: trajectories go to Pepper's ros2_control controller.
NODE_REMAPS = {"motion_filter_node": ("-r", f"{topics.JOINT_TRAJECTORY}:={CONTROLLER_TOPIC}")}
STARTUP_GRACE_S = 30.0  # a node may take this long to publish its first heartbeat (imports)
MAX_BACKOFF_S = 16.0  # longest wait before a restart
# A node silent this long is killed and restarted. Ten heartbeats: a process that a busy machine
# starved for a moment (CI on 2 cores saw a 1.3 s gap from a healthy node) is reported STALE after
# STALE_AFTER_S but not killed, since a restart takes the node away for seconds; a stopped or
# deadlocked one is still replaced within seconds.
RESTART_AFTER_S = 10 * HEARTBEAT_PERIOD_S
WATCH_PERIOD_S = 0.1
STACK_DUMP_WAIT_S = 0.2  # time a silent process gets to write its stacks before SIGKILL
RECORDED_TOPICS = {
    topics.absolute(topics.JOINT_ANGLES): (
        JointAnglesWithSpeed,
        "naoqi_bridge_msgs/msg/JointAnglesWithSpeed",
    ),
    CONTROLLER_TOPIC: (JointTrajectory, "trajectory_msgs/msg/JointTrajectory"),
    topics.absolute(topics.COMMANDED_JOINT_STATES): (JointState, "sensor_msgs/msg/JointState"),
    topics.absolute(topics.RAW_TRAJECTORY): (
        JointTrajectory,
        "trajectory_msgs/msg/JointTrajectory",
    ),
}


class GraphTimeoutError(Audio2PoseError):
    """The node graph did not answer in time (its node logs say why)."""


def executable_command(name: str) -> list[str]:
    """The console script ``name`` next to this interpreter, else ``python -m`` its module."""
    script = Path(sys.executable).parent / name
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    found = shutil.which(name)
    if found:
        return [found]
    return [sys.executable, "-m", f"audio2pose_ros.ros.nodes.{name}"]


class NodeSupervisor:
    """Runs the node processes like a launch file would, and restarts them with a bounded budget.

    - **Crash.** A node that exits is restarted at once the first time (within
      ``restart_window_s``), then after a back-off that doubles from ``respawn_delay_s`` up to
      ``MAX_BACKOFF_S``; one that dies more than ``max_restarts`` times within
      ``restart_window_s`` is given up on, loudly, rather than restarted forever.
    - **Configuration error.** A node that exits with
      :data:`~audio2pose_ros.ros.diagnosed_node.EXIT_CONFIGURATION_ERROR` (a refused parameter, a
      bad model or robot file, a parameters file rcl cannot parse) is never restarted: the same
      configuration would fail the same way. Its one-line reason is in its log and, when the
      log is a file, on this process's stderr too (``TERMINAL_FD_ENV``).
    - **Silence.** A node whose process is alive but has not sent its heartbeat for
      ``restart_after_s`` (stopped with SIGSTOP, deadlocked) is killed and restarted like a
      crashed one. The heartbeat comes from the process itself, never from a topic anyone can
      publish: each process gets the write end of its own pipe (``HEARTBEAT_FD_ENV``), and its
      nodes write a byte there with every /diagnostics heartbeat; another process publishing
      /diagnostics under the node's name and pid keeps nothing alive. A shorter gap
      (``STALE_AFTER_S``) is only reported, by :class:`HeartbeatMonitor`: a node that a busy
      machine starved for a second is not taken away for the seconds a restart lasts.

    ``commands`` are keyed by process; ``members`` maps each node name to the process that runs
    it (default: each process runs the node of its name). A process is heard when any of its
    nodes is: its nodes share one executor, so a stopped process silences them all.
    """

    def __init__(
        self,
        commands: dict[str, list[str]],
        log_dir: Path | None,
        respawn_delay_s: float = 1.0,
        max_restarts: int = 5,
        restart_window_s: float = 60.0,
        startup_grace_s: float = STARTUP_GRACE_S,
        members: dict[str, str] | None = None,
        restart_after_s: float = RESTART_AFTER_S,
    ) -> None:
        """Remember how to start each process; :meth:`start` starts them."""
        if restart_after_s <= STALE_AFTER_S:
            raise ValueError(
                f"restart_after_s must exceed the stale limit ({STALE_AFTER_S} s), "
                f"got {restart_after_s}"
            )
        self.commands = commands
        self.members = members or {name: name for name in commands}
        self.log_dir = log_dir
        self.respawn_delay_s = respawn_delay_s
        self.max_restarts = max_restarts
        self.restart_window_s = restart_window_s
        self.startup_grace_s = startup_grace_s
        self.restart_after_s = restart_after_s
        self.processes: dict[str, subprocess.Popen[bytes]] = {}
        self.restarts: dict[str, list[float]] = {name: [] for name in commands}
        self.given_up: set[str] = set()
        self.silences = dict.fromkeys(commands, 0)
        # per node, the longest time (s) between two heartbeats of one process, as read here
        self.longest_gap_s = dict.fromkeys(commands, 0.0)
        self._started_s: dict[str, float] = {}
        self._heard_s: dict[str, float] = {}  # since the current process started
        self._last_heard_s: dict[str, float] = {}  # by any process of the node
        self._due_s: dict[str, float] = {}  # restart time of a node that is down
        self._pipes: dict[str, int] = {}  # read end of each process's heartbeat pipe
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="node-supervisor", daemon=True)

    def _say(self, message: str) -> None:
        print(f"audio2pose run: {message}", file=sys.stderr, flush=True)

    def _spawn(self, name: str, mode: str) -> None:
        """Start the process of ``name``.

        Raises:
            OSError: it cannot be started (its executable gone, no memory for a process, the
                log unwritable).
        """
        stdout = None
        env = {key: value for key, value in os.environ.items() if key != TERMINAL_FD_ENV}
        if self.log_dir is not None:
            self.log_dir.mkdir(parents=True, exist_ok=True)
            stdout = (self.log_dir / f"{name}.log").open(mode)
        try:
            read_end, write_end = os.pipe()
            os.set_blocking(read_end, False)
            old = self._pipes.pop(name, None)
            if old is not None:
                os.close(old)
            self._pipes[name] = read_end
            passed = [write_end]
            env[HEARTBEAT_FD_ENV] = str(write_end)
            if stdout is not None:  # the user's terminal, for the lines they must see
                passed.append(os.dup(sys.stderr.fileno()))
                env[TERMINAL_FD_ENV] = str(passed[-1])
            try:
                self.processes[name] = subprocess.Popen(
                    self.commands[name],
                    stdout=stdout,
                    stderr=subprocess.STDOUT if stdout else None,
                    pass_fds=passed,
                    env=env,
                )
            finally:
                for fd in passed:
                    os.close(fd)  # the child holds its own
        finally:
            if stdout is not None:
                stdout.close()  # the child holds its own descriptor
        self._started_s[name] = time.monotonic()
        self._heard_s.pop(name, None)

    def start(self) -> None:
        """Start every node and the watchdog thread."""
        for name in self.commands:
            self._spawn(name, "w")
        self._thread.start()

    def heartbeat(self, node: str, pid: int) -> None:
        """Process ``pid`` running node ``node`` is alive now (the pipe reader calls this).

        A heartbeat of another process than the one now running the node is ignored, as is an
        unknown node.
        """
        name = self.members.get(node)
        if name is None:
            return
        process = self.processes.get(name)
        if process is None or process.pid != pid:
            return
        now = time.monotonic()
        with self._lock:
            previous = self._heard_s.get(name)
            if previous is not None:
                self.longest_gap_s[name] = max(self.longest_gap_s[name], now - previous)
            self._heard_s[name] = self._last_heard_s[name] = now

    def silent_s(self, name: str) -> float:
        """How long ``name`` has not been heard from, across restarts (0 before it ever was)."""
        with self._lock:
            heard = self._last_heard_s.get(name)
        return 0.0 if heard is None else time.monotonic() - heard

    def _failed(self, name: str, why: str, now: float) -> None:
        """``name`` is down: schedule its restart, or give up on it."""
        recent = [t for t in self.restarts[name] if now - t < self.restart_window_s]
        if len(recent) >= self.max_restarts:
            self.given_up.add(name)
            self._say(
                f"{name} {why}; it failed {len(recent) + 1} times within "
                f"{self.restart_window_s:.0f} s: giving up on it (see its log)"
            )
            return
        # the first crash restarts at once; back off from the second on
        delay = (
            0.0 if not recent else min(self.respawn_delay_s * 2 ** (len(recent) - 1), MAX_BACKOFF_S)
        )
        self.restarts[name] = [*recent, now]
        self._due_s[name] = now + delay
        self._say(f"{name} {why}; restarting it in {delay:.1f} s")

    def _read_pipe(self, name: str, process: subprocess.Popen[bytes]) -> None:
        """Heartbeat bytes the running process of ``name`` wrote to its pipe: it is alive."""
        fd = self._pipes.get(name)
        if fd is None:
            return
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            return
        if data:
            self.heartbeat(next(n for n, p in self.members.items() if p == name), process.pid)

    def _check(self, name: str, process: subprocess.Popen[bytes], now: float) -> None:
        if name in self.given_up:
            return
        self._read_pipe(name, process)
        due = self._due_s.get(name)
        if due is not None:
            if now >= due:
                del self._due_s[name]
                try:
                    self._spawn(name, "a")
                except OSError as exc:  # a start that fails is a failure like a crash
                    self._failed(name, f"could not be started again ({exc})", now)
            return
        code = process.poll()
        if code == EXIT_CONFIGURATION_ERROR:
            self.given_up.add(name)
            self._say(
                f"{name} refused its configuration (exit status {code}); not restarting it: "
                "fix the parameter or file named in its log"
            )
        elif code is not None:
            self._failed(name, f"exited with status {code}", now)
        else:
            with self._lock:
                heard = self._heard_s.get(name)
            started = self._started_s[name]
            silent = now - heard if heard is not None else now - started - self.startup_grace_s
            if silent > self.restart_after_s:
                process.send_signal(STACK_DUMP_SIGNAL)  # where it was stuck, into its log
                time.sleep(STACK_DUMP_WAIT_S)
                process.kill()  # SIGKILL also ends a stopped (SIGSTOP) process
                process.wait()
                self.silences[name] += 1
                self._failed(
                    name,
                    f"was silent for {silent:.1f} s (no heartbeat; its log has its stacks)",
                    now,
                )

    def _watch(self) -> None:
        """The watchdog thread: check every node each period; nothing ends the supervision."""
        while not self._stopping.wait(WATCH_PERIOD_S):
            now = time.monotonic()
            for name, process in list(self.processes.items()):
                try:
                    self._check(name, process, now)
                except Exception as exc:  # the boundary: the other nodes stay supervised
                    self._say(f"supervising {name} failed, retrying: {exc!r}")

    @property
    def running(self) -> bool:
        """True while at least one node is running or will be restarted."""
        return len(self.given_up) < len(self.commands)

    def stop(self) -> None:
        """Stop the watchdog, then the nodes (SIGINT, then SIGKILL after 5 s)."""
        self._stopping.set()
        if self._thread.is_alive():
            self._thread.join()
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGCONT)  # a stopped process cannot act on SIGINT
                process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for process in self.processes.values():
            try:
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        for fd in self._pipes.values():
            os.close(fd)
        self._pipes.clear()


class HeartbeatMonitor:
    """Reports the supervisor's silent nodes on /diagnostics, from its own rclpy context.

    Node statuses are named ``audio2pose_ros: /<node name>`` (``diagnosed_node.status_name``).
    A node whose process has sent no heartbeat (through its pipe, see :class:`NodeSupervisor`)
    for ``STALE_AFTER_S`` is reported on /diagnostics under its own name with level STALE until
    it is heard again, as diagnostic_aggregator would show it, whatever other processes publish
    under that name; the supervisor restarts it once it has been silent for its
    ``restart_after_s``. Runs its own executor thread, so it works beside a player in the
    default context.
    """

    def __init__(self, supervisor: NodeSupervisor) -> None:
        """Start a context, a node subscribed to /diagnostics and a spinning thread."""
        self.supervisor = supervisor
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node("audio2pose_supervisor", context=self.context)
        self.publisher = self.node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.node.create_timer(WATCH_PERIOD_S * 2, self._report_silent)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name="heartbeat-monitor", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        with suppress(ExternalShutdownException):
            self.executor.spin()

    def _report_silent(self) -> None:
        statuses = []
        for name, process in self.supervisor.members.items():
            silent = self.supervisor.silent_s(process)
            if silent > STALE_AFTER_S:
                statuses.append(
                    DiagnosticStatus(
                        level=DiagnosticStatus.STALE,
                        name=status_name(f"/{name}"),
                        message=(
                            f"no heartbeat for {silent:.1f} s: restarting the node if it "
                            f"stays silent for {self.supervisor.restart_after_s:.0f} s"
                        ),
                        hardware_id="pepper",
                    )
                )
        if statuses:
            array = DiagnosticArray(status=statuses)
            array.header.stamp = self.node.get_clock().now().to_msg()
            self.publisher.publish(array)

    def close(self) -> None:
        """Stop spinning and leave the context."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=2.0)


def overrides_file(overrides: Sequence[str], directory: Path) -> Path:
    """Write ``name:=value`` overrides as a parameters file that targets each node by name.

    rcl applies node-specific entries after ``/**`` ones, so a plain ``-p name:=value`` (a
    wildcard) loses against the same name in a node's section of the parameters file. Entries
    for every node, passed after the parameters file, win: command line over file over defaults.

    Raises:
        UsageError: an override is not ``name:=value``.
    """
    values: dict[str, object] = {}
    for override in overrides:
        name, sep, text = override.partition(":=")
        if not sep or not name.strip():
            raise UsageError(f"parameter override {override!r} is not name:=value")
        try:
            values[name.strip()] = load_yaml_text(text) if text else ""
        except yaml.YAMLError:
            values[name.strip()] = text
    path = directory / "overrides.yaml"
    document = {node: {"ros__parameters": dict(values)} for node in NODE_EXECUTABLES}
    path.write_text(yaml.safe_dump(document), encoding="utf-8")
    return path


@contextmanager
def node_graph(
    params_file: Path | None = None,
    overrides: Sequence[str] = (),
    log_dir: Path | None = None,
    monitor: bool = True,
    single_process: bool = False,
    sim: bool = False,
    more_nodes: Mapping[str, list[str]] | None = None,
    restart_after_s: float = RESTART_AFTER_S,
    sim_args: Sequence[str] = (),
) -> Iterator[NodeSupervisor]:
    """Run the three nodes as supervised processes for the duration of the context.

    Args:
        params_file: ROS parameter YAML (default: the package's config/pepper.yaml).
        overrides: ``name:=value`` parameters for every node; they win over the file.
        log_dir: where each process's output goes (``<process>.log``); ``None`` inherits the
            terminal.
        monitor: watch the nodes' heartbeats and restart a silent node.
        single_process: run the three nodes in one process and one executor
            (``audio2pose_nodes``) instead of one process each.
        sim: also run ``pepper_sim_node``, a simulated Pepper that follows ``joint_angles`` and
            reports the measured ``joint_states`` the motion filter starts from.
        more_nodes: more node processes supervised with the graph, by node name: the command of
            each (``audio2pose console`` adds ``console_node``).
        restart_after_s: how long a node may be silent before it is restarted (see
            :class:`NodeSupervisor`).
        sim_args: more ROS arguments of the simulated Pepper (``-p name:=value``).
    """
    params = params_file or share_path("config", "pepper.yaml")
    with ExitStack() as stack:
        extra: list[str] = []
        if overrides:
            tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="audio2pose_")))
            extra = ["--params-file", str(overrides_file(overrides, tmp))]
        ros_args = ["--ros-args", "--params-file", str(params), *extra]
        if single_process:
            remaps = [arg for name in NODE_EXECUTABLES for arg in NODE_REMAPS.get(name, ())]
            module = [sys.executable, "-m", "audio2pose_ros.ros.nodes.single_process"]
            commands = {SINGLE_PROCESS: [*module, *ros_args, *remaps]}
            members = dict.fromkeys(NODE_EXECUTABLES, SINGLE_PROCESS)
        else:
            commands = {
                name: [*executable_command(name), *ros_args, *NODE_REMAPS.get(name, ())]
                for name in NODE_EXECUTABLES
            }
            members = None
        if sim:
            commands[SIM_NODE] = [*executable_command(SIM_NODE), "--ros-args", *sim_args]
            if members is not None:
                members[SIM_NODE] = SIM_NODE
        if more_nodes:
            commands.update(more_nodes)
            if members is not None:
                members.update({name: name for name in more_nodes})
        supervisor = NodeSupervisor(
            commands, log_dir, members=members, restart_after_s=restart_after_s
        )
        stack.callback(supervisor.stop)
        supervisor.start()
        if monitor:
            stack.callback(HeartbeatMonitor(supervisor).close)
        yield supervisor


@dataclass
class PlaybackResult:
    """What a run recorded."""

    audio_s: float
    chunks_sent: int
    recorded_s: float
    counts: dict[str, int] = field(default_factory=dict)
    bag: Path | None = None


class PlayerRecorder(Node):
    """Publishes a WAV as audio_common_msgs in real time and records the graph's commands."""

    def __init__(self, bag: BagWriter | None) -> None:
        """Create the audio publishers and one recording subscription per command topic."""
        super().__init__("audio2pose_player")
        self.bag = bag
        self.recording = False
        self.counts = dict.fromkeys(RECORDED_TOPICS, 0)
        self.poses_seen = 0
        self.heard: set[str] = set()  # recorded topics that ever delivered a message
        self.player = MessagePlayer(
            self, [(AUDIO_TOPIC, AUDIO_DATA_TYPE), (AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE)]
        )
        self.create_subscription(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), self._on_pose, 100
        )
        for topic, (msg_type, type_name) in RECORDED_TOPICS.items():
            self.create_subscription(
                msg_type, topic, self._recorder(topic, type_name), 100, raw=True
            )

    def _on_pose(self, msg: JointTrajectory) -> None:
        self.poses_seen += len(msg.points)

    def _recorder(self, topic: str, type_name: str) -> Callable[[bytes], None]:
        def record(data: bytes) -> None:
            self.heard.add(topic)
            if not self.recording:
                return
            self.counts[topic] += 1
            if self.bag is not None:
                self.bag.write(topic, type_name, self.get_clock().now().nanoseconds, data)

        return record

    def record_sent(self, message: BagMessage) -> None:
        """Record a message the player just published, while recording."""
        if self.recording and self.bag is not None:
            self.bag.write(
                message.topic, message.msgtype, self.get_clock().now().nanoseconds, message.data
            )

    def warm_up(self, timeout_s: float) -> None:
        """Send silence until poses and every recorded command come back: each link has matched.

        Raises:
            GraphTimeoutError: the graph did not answer within ``timeout_s``.
        """
        if not warm_up(
            self.player,
            AUDIO_TOPIC,
            lambda: self.poses_seen > 0 and self.heard >= set(RECORDED_TOPICS),
            timeout_s,
        ):
            raise GraphTimeoutError(
                f"the node graph did not answer within {timeout_s} s (see the node logs)"
            )
        spin_until(self, time.monotonic() + 0.3)


def audio_source(path: Path, chunking: Chunking | None = None) -> list[BagMessage]:
    """The audio messages to play: a WAV cut like a live capture, or a bag's audio topics."""
    if path.suffix.lower() == ".wav":
        samples, _ = read_wav(path)
        return audio_messages(samples, chunking)
    messages = read_checked_messages(path, AUDIO_TOPIC_TYPES, AUDIO_TOPIC_TYPES)
    if not any(m.topic == AUDIO_TOPIC for m in messages):
        raise BagError(f"{path}: no {AUDIO_TOPIC} messages to play")
    start = messages[0].timestamp_ns
    return [replace(m, timestamp_ns=m.timestamp_ns - start) for m in messages]


def play_and_record(
    messages: Sequence[BagMessage],
    bag_path: Path | None,
    rate: float = 1.0,
    tail_s: float = 2.0,
    startup_timeout_s: float = 60.0,
) -> PlaybackResult:
    """Publish audio messages with their timing (``rate`` x faster); record what the graph sends.

    Must run while :func:`node_graph` is up, inside an initialised rclpy context. Recording
    starts with the first message and ends ``tail_s`` after the last one, so the bag also shows
    the glide back to the neutral pose.

    Raises:
        GraphTimeoutError: the graph did not come up within ``startup_timeout_s``.
    """
    first_info = next((m for m in messages if m.topic == AUDIO_INFO_TOPIC), None)
    with ExitStack() as stack:
        bag = (
            stack.enter_context(BagWriter(bag_path, flush_period_s=RECORD_FLUSH_PERIOD_S))
            if bag_path
            else None
        )
        node = PlayerRecorder(bag)
        stack.callback(node.destroy_node)
        if first_info is not None:
            node.player.publish(first_info)
        node.warm_up(startup_timeout_s)
        node.recording = True
        start = node.player.play(messages, rate, on_publish=node.record_sent)
        spin_until(node, time.monotonic() + tail_s)
        return PlaybackResult(
            audio_s=messages[-1].timestamp_ns * 1e-9 if messages else 0.0,
            chunks_sent=sum(m.topic == AUDIO_TOPIC for m in messages),
            recorded_s=time.monotonic() - start,
            counts=dict(node.counts),
            bag=bag_path,
        )


def run_graph(
    play: Path | None,
    record: Path | None,
    params_file: Path | None,
    overrides: Sequence[str],
    log_dir: Path | None,
    rate: float = 1.0,
    single_process: bool = False,
    sim: bool = False,
    voice_out: str = "",
) -> PlaybackResult | None:
    """Start the graph; with ``play`` (a WAV or a bag) play it and return what was recorded.

    Without ``play`` the graph runs until Ctrl-C. ``single_process`` runs the three nodes in one
    process, ``sim`` adds the simulated Pepper (:func:`node_graph`), ``voice_out`` the voice
    node (:func:`~audio2pose_ros.ros.voice_graph.voice_out_processes`).

    Raises:
        ConfigurationError: the supervisor gave up on a node (it refused its configuration, or
            failed again and again): the graph cannot command the robot, so it is stopped and
            the command fails instead of running on without that node.
    """
    messages = audio_source(play) if play is not None else None
    voice_nodes, sim_args = (
        voice_out_processes(voice_out, sim, executable_command) if voice_out else ({}, [])
    )
    with node_graph(
        params_file, overrides, log_dir, single_process=single_process, sim=sim,
        more_nodes=voice_nodes, sim_args=sim_args,
    ) as supervisor:  # fmt: skip
        if messages is None:
            try:
                while not supervisor.given_up:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                return None
            raise _stopped(supervisor)
        with rclpy_session():
            result = play_and_record(messages, record, rate=rate)
        if supervisor.given_up:
            raise _stopped(supervisor)
        return result


def _stopped(supervisor: NodeSupervisor) -> ConfigurationError:
    """The error of a graph whose supervisor gave up on some nodes (named, sorted)."""
    names = ", ".join(sorted(supervisor.given_up))
    return ConfigurationError(f"the graph stopped: gave up on {names}: see the lines above")


def summarize(result: PlaybackResult) -> str:
    """Human-readable summary of a playback."""
    lines = [
        f"played {result.audio_s:.2f} s of audio in {result.chunks_sent} messages; recorded "
        f"{result.recorded_s:.2f} s (speech and {result.recorded_s - result.audio_s:.1f} s after)"
    ]
    for topic, count in result.counts.items():
        lines.append(f"  {topic}: {count} messages ({count / result.recorded_s:.0f} Hz)")
    if result.bag is not None:
        lines.append(f"recorded to {result.bag}")
    return "\n".join(lines)
