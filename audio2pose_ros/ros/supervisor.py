"""The supervisor of ``audio2pose run``: the node processes, restarted as ``ros2 launch`` does.

This is what ``ros2 launch audio2pose_ros pepper.launch.py`` does, for machines without a ROS
distro: the same three executables, each its own process, with the same parameter file and the
same restart policy (:class:`~audio2pose_ros.ros.launch_support.RespawnBudget`); or, with
``single_process``, the same three nodes in one process and one executor
(:mod:`audio2pose_ros.ros.nodes.single_process`). :func:`node_graph` runs them for the duration
of a context; :class:`NodeSupervisor` restarts a crashed or silent one; :class:`HeartbeatMonitor`
reports silent ones on /diagnostics.
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
from collections.abc import Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager, suppress
from pathlib import Path

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from audio2pose_ros import topics
from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, Audio2PoseError, UsageError
from audio2pose_ros.files import load_yaml_text
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_PERIOD_S, STALE_AFTER_S, status_name
from audio2pose_ros.ros.executor import shutdown
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC, RespawnBudget
from audio2pose_ros.ros.supervisor_pipe import HEARTBEAT_FD_ENV, STACK_DUMP_SIGNAL, TERMINAL_FD_ENV

NODE_EXECUTABLES = ("audio_features_node", "inference_node", "motion_filter_node")
SIM_NODE = "pepper_sim_node"  # the simulated robot (audio2pose run --sim)
# a graph that drives no robot: the motion filter starts without a measured pose
NO_ROBOT = "start_without_measured_pose:=true"
SINGLE_PROCESS = "audio2pose_nodes"  # the process that runs all three nodes (single-process mode)
# As the launch file does: trajectories go to Pepper's ros2_control controller.
NODE_REMAPS = {"motion_filter_node": ("-r", f"{topics.JOINT_TRAJECTORY}:={CONTROLLER_TOPIC}")}
STARTUP_GRACE_S = 30.0  # a node may take this long to publish its first heartbeat (imports)
# A node silent this long is killed and restarted. Ten heartbeats: a process that a busy machine
# starved for a moment (CI on 2 cores saw a 1.3 s gap from a healthy node) is reported STALE after
# STALE_AFTER_S but not killed, since a restart takes the node away for seconds; a stopped or
# deadlocked one is still replaced within seconds.
RESTART_AFTER_S = 10 * HEARTBEAT_PERIOD_S
WATCH_PERIOD_S = 0.1
STACK_DUMP_WAIT_S = 0.2  # time a silent process gets to write its stacks before SIGKILL


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

    - **Crash.** A node that exits is restarted as ``ros2 launch`` restarts it: by the one
      restart policy, :class:`~audio2pose_ros.ros.launch_support.RespawnBudget` (at once the
      first time in a row, then after a back-off that doubles up to its cap; one that keeps
      dying is given up on, loudly, rather than restarted forever).
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
        budget: RespawnBudget | None = None,
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
        self.budget = budget if budget is not None else RespawnBudget()
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

    def _failed(self, name: str, why: str, now: float, returncode: int) -> None:
        """``name`` is down (``returncode``): schedule its restart, or give up on it."""
        ran_s = now - self._started_s.get(name, now)
        decision = self.budget.on_exit(name, returncode, ran_s)
        if not decision.restart:
            self.given_up.add(name)
            self._say(f"{name} {why}; {decision.message} (see its log)")
            return
        self.restarts[name].append(now)
        self._due_s[name] = now + decision.delay_s
        self._say(f"{name} {why}; restarting it in {decision.delay_s:.1f} s")

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
                    self._started_s[name] = now  # it did not run: a crash at once
                    self._failed(name, f"could not be started again ({exc})", now, 1)
            return
        code = process.poll()
        if code == EXIT_CONFIGURATION_ERROR:
            self.given_up.add(name)
            self._say(
                f"{name} refused its configuration (exit status {code}); not restarting it: "
                "fix the parameter or file named in its log"
            )
        elif code is not None:
            self._failed(name, f"exited with status {code}", now, code)
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
                    -signal.SIGKILL,
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
        shutdown(context=self.context)
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
    no_robot: bool = False,
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
        no_robot: no robot publishes ``joint_states`` (nothing but the recorder or a viewer
            takes the commands): the motion filter starts from its saved pose or neutral
            (``start_without_measured_pose``) instead of waiting for a measured pose.
        sim_args: more ROS arguments of the simulated Pepper (``-p name:=value``).
    """
    params = params_file or share_path("config", "pepper.yaml")
    if no_robot:
        overrides = [NO_ROBOT, *overrides]
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
