"""Run ``ros2 launch audio2pose_ros pepper.launch.py`` for real: how it starts, fails, stops.

Needs the launch stack of ../shared/tools/ros2-launch-stack (``support/launch_check.sh`` builds
it and runs this script). Each scenario starts the real launch file in its own session, looks at
the graph over DDS (node names, topics, parameters) or at the launch's output and exit status,
then stops it, and prints one PASS/FAIL line. Not part of the test suite: the project's tests
must run without this stack.

    support/launch_check.sh [SCENARIO ...]      # default: all of them
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node

NODES = ("audio_features_node", "inference_node", "motion_filter_node")
LOG_DIR = Path(os.environ.get("LAUNCH_CHECK_LOGS", tempfile.mkdtemp(prefix="launch_check_")))
RESULTS: list[tuple[str, bool, str]] = []


def _default_sigint() -> None:
    """A script's background job ignores SIGINT; ros2 launch must get Ctrl-C as a user's does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def stand_in_packages(*executables: str) -> dict[str, str]:
    """Environment with packages whose executable (``package/executable``) only sleeps.

    robot_state_publisher, rviz2 and diagnostic_aggregator are not built here; stand-ins on
    AMENT_PREFIX_PATH show which of them the launch file starts, and with which arguments.
    """
    prefix = LOG_DIR / "stand_ins"
    for package, name in (executable.split("/") for executable in executables):
        index = prefix / "share" / "ament_index" / "resource_index" / "packages"
        index.mkdir(parents=True, exist_ok=True)
        (index / package).touch()
        executable = prefix / "lib" / package / name
        executable.parent.mkdir(parents=True, exist_ok=True)
        executable.write_text(f"#!{sys.executable}\nimport time\ntime.sleep(600)\n")
        executable.chmod(0o755)
    return {**os.environ, "AMENT_PREFIX_PATH": f"{prefix}:{os.environ['AMENT_PREFIX_PATH']}"}


class Launch:
    """One ``ros2 launch`` process in its own session, its output in a log file."""

    def __init__(self, name: str, *arguments: str, env: dict[str, str] | None = None) -> None:
        """Start it."""
        self.log = LOG_DIR / f"{name}.log"
        self.command = ["ros2", "launch", "audio2pose_ros", "pepper.launch.py", *arguments]
        with self.log.open("w") as out:
            self.process = subprocess.Popen(
                self.command,
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                preexec_fn=_default_sigint,
            )
        self.started_s = time.monotonic()

    def children(self) -> dict[int, str]:
        """Map pid -> command of the launch process's children (the nodes)."""
        found = {}
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
                cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if int(fields[1]) == self.process.pid:
                found[int(stat.parent.name)] = cmdline.strip()
        return found

    def wait(self, timeout_s: float) -> int | None:
        """The exit status, or None if it is still running after ``timeout_s``."""
        try:
            return self.process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 15.0) -> tuple[int | None, float]:
        """Send ``sig`` to the launch process alone; (exit status, seconds it took)."""
        start = time.monotonic()
        if self.process.poll() is None:
            self.process.send_signal(sig)
        status = self.wait(timeout_s)
        if status is None:  # leave nothing behind us
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()
        return status, time.monotonic() - start

    def output(self) -> str:
        """Everything it printed so far."""
        return self.log.read_text(errors="replace")


def alive(pids: dict[int, str]) -> list[str]:
    """Those of ``pids`` that still run (zombies do not count)."""
    running = []
    for pid, command in pids.items():
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            running.append(f"{pid} {command[:80]}")
    return running


def check(name: str, ok: bool, detail: str) -> bool:
    """Record and print one result line."""
    RESULTS.append((name, ok, detail))
    print(f"{'PASS' if ok else 'FAIL'} {name}: {detail}", flush=True)
    return ok


class GraphProbe(Node):
    """Looks at the running graph: nodes, their topics, their parameters."""

    def __init__(self) -> None:
        """A plain participant on the current domain."""
        super().__init__("launch_check_probe")

    def wait_for(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``condition()`` or the timeout."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if condition():
                return True
            rclpy.spin_once(self, timeout_sec=0.1)
        return condition()

    def nodes(self) -> set[str]:
        """Names of the nodes in the graph (other than this one)."""
        return {name for name, _ in self.get_node_names_and_namespaces()} - {self.get_name()}

    def topics_of(self, node: str, publishers: bool) -> set[str]:
        """Topics ``node`` publishes (or subscribes to), without ROS's own."""
        by_node = (
            self.get_publisher_names_and_types_by_node
            if publishers
            else self.get_subscriber_names_and_types_by_node
        )
        topics = {topic for topic, _ in by_node(node, "/")}
        return {t for t in topics if not t.startswith(("/parameter_events", "/rosout"))}

    def parameter(self, node: str, name: str) -> str | None:
        """A string parameter of ``node`` through its get_parameters service."""
        client = self.create_client(GetParameters, f"/{node}/get_parameters")
        try:
            if not client.wait_for_service(timeout_sec=10.0):
                return None
            future = client.call_async(GetParameters.Request(names=[name]))
            rclpy.spin_until_future_complete(self, future, timeout_sec=10.0)
            result = future.result()
            return result.values[0].string_value if result and result.values else None
        finally:
            self.destroy_client(client)


def graph_up(probe: GraphProbe, launch: Launch, timeout_s: float = 40.0) -> bool:
    """The three nodes are in the graph and the launch still runs."""
    return (
        probe.wait_for(
            lambda: set(NODES) <= probe.nodes() or launch.process.poll() is not None, timeout_s
        )
        and set(NODES) <= probe.nodes()
    )


def write(path: Path, text: str) -> Path:
    """Write a fixture file."""
    path.write_text(text, encoding="utf-8")
    return path


def scenario_defaults(probe: GraphProbe) -> None:
    """Defaults: three nodes, topics as documented, Ctrl-C ends all in a few seconds."""
    launch = Launch("defaults")
    if not check("defaults: graph up", graph_up(probe, launch), f"nodes {sorted(probe.nodes())}"):
        launch.stop()
        return
    # A node is in the graph a moment before its endpoints are: wait for its controller output.
    controller = "/pepper_joint_trajectory_controller/joint_trajectory"
    probe.wait_for(lambda: controller in probe.topics_of("motion_filter_node", True), 10.0)
    filter_pubs = probe.topics_of("motion_filter_node", publishers=True)
    check(
        "controller topic default",
        controller in filter_pubs,
        f"motion_filter_node publishes {sorted(filter_pubs)}",
    )
    check(
        "no commanded /joint_states",
        "/joint_states" not in filter_pubs,
        "motion_filter_node does not publish /joint_states"
        if "/joint_states" not in filter_pubs
        else "motion_filter_node still publishes /joint_states (node rename pending)",
    )
    model = probe.parameter("inference_node", "model_path")
    check("model_path: package default", model == "", f"inference_node model_path={model!r}")
    children = launch.children()
    status, took_s = launch.stop(signal.SIGINT)
    left = alive(children)
    check(
        "SIGINT",
        status is not None and not left,
        f"ros2 launch exit status {status} after {took_s:.1f} s; nodes left: {left or 'none'}",
    )


def scenario_model_path(probe: GraphProbe, checkpoint: Path) -> None:
    """Launch argument > parameters file > package default (two usable copies)."""
    in_file, in_argument = LOG_DIR / "file.safetensors", LOG_DIR / "argument.safetensors"
    for copy in (in_file, in_argument):
        copy.write_bytes(checkpoint.read_bytes())
    params = write(
        LOG_DIR / "model_path.yaml", f'/**:\n  ros__parameters:\n    model_path: "{in_file}"\n'
    )
    for label, arguments, expected in (
        ("parameters file over default", [f"params_file:={params}"], in_file),
        (
            "argument over parameters file",
            [f"params_file:={params}", f"model_path:={in_argument}"],
            in_argument,
        ),
    ):
        launch = Launch(f"model_path_{len(RESULTS)}", *arguments)
        probe.wait_for(lambda: "inference_node" in probe.nodes(), 40.0)
        value = probe.parameter("inference_node", "model_path")
        check(f"model_path: {label}", value == str(expected), f"{' '.join(arguments)} -> {value!r}")
        launch.stop()


def scenario_booleans_and_namespaces(probe: GraphProbe) -> None:
    """Items 2, 3, 9: accepted booleans, a trailing-slash namespace, one-line refusals."""
    env = stand_in_packages(
        "robot_state_publisher/robot_state_publisher",
        "rviz2/rviz2",
        "diagnostic_aggregator/aggregator_node",
    )
    for arguments, rsp_expected, rviz_expected in (
        (["rviz:=True"], True, True),
        (["rviz:=1", "robot_state_publisher:=FALSE"], False, True),
        (["robot_state_publisher:=1"], True, False),
        (["rviz:=0", "robot_state_publisher:= true"], True, False),
        ([], False, False),
    ):
        launch = Launch("bool_" + "_".join(arguments), *arguments, env=env)
        graph_up(probe, launch)
        commands = list(launch.children().values())
        rsp = [c for c in commands if "robot_state_publisher/robot_state_publisher" in c]
        rviz = [c for c in commands if "rviz2/rviz2" in c]
        remapped = all("joint_states:=commanded_joint_states" in c for c in rsp)
        check(
            f"items 2, 9: {' '.join(arguments) or 'no arguments'}",
            bool(rsp) == rsp_expected and bool(rviz) == rviz_expected and remapped,
            f"robot_state_publisher {'started' if rsp else 'not started'}"
            f"{' on commanded_joint_states' if rsp and remapped else ''}, "
            f"rviz2 {'started' if rviz else 'not started'}",
        )
        launch.stop()
    launch = Launch("aggregator", "diagnostic_aggregator:=TRUE", env=env)
    graph_up(probe, launch)
    aggregator = [c for c in launch.children().values() if "aggregator_node" in c]
    check(
        "diagnostic_aggregator:=TRUE starts the aggregator with our analyzers",
        len(aggregator) == 1 and "config/diagnostic_analyzers.yaml" in aggregator[0],
        f"started: {aggregator}",
    )
    launch.stop()
    launch = Launch("bool_yes", "rviz:=yes")
    status = launch.wait(15.0)
    errors = [line for line in launch.output().splitlines() if "ERROR" in line]
    check("rviz:=yes refused", status == 1 and len(errors) == 1, f"status {status}, {errors}")

    launch = Launch("audio_ns", "audio_ns:=/mic/")
    up = graph_up(probe, launch)
    audio = {"/mic/audio", "/mic/audio_info"}
    if up:  # the node is in the graph a moment before its subscriptions are
        probe.wait_for(lambda: audio <= probe.topics_of("audio_features_node", False), 10.0)
    subs = probe.topics_of("audio_features_node", publishers=False) if up else set()
    check(
        "audio_ns:=/mic/",
        audio <= subs,
        f"audio_features_node subscribes {sorted(subs)}",
    )
    launch.stop()
    launch = Launch("audio_ns_bad", "audio_ns:=/mic/2nd")
    status = launch.wait(15.0)
    errors = [line for line in launch.output().splitlines() if "ERROR" in line]
    check("audio_ns:=/mic/2nd refused", status == 1 and len(errors) == 1, f"{status} {errors}")


def scenario_configuration_errors(probe: GraphProbe) -> None:
    """Items 4 and 7: one line, exit status 1, no restart loop."""
    bad_yaml = write(LOG_DIR / "syntax.yaml", "motion_filter_node:\n  ros__parameters: [1,\n")
    wrong_type = write(
        LOG_DIR / "wrong_type.yaml",
        "motion_filter_node:\n  ros__parameters:\n    arms_gain: fast\n",
    )
    for label, arguments in (
        ("YAML syntax error", [f"params_file:={bad_yaml}"]),
        ("missing params_file", [f"params_file:={LOG_DIR / 'missing.yaml'}"]),
        ("wrong parameter type", [f"params_file:={wrong_type}"]),
    ):
        launch = Launch(label.replace(" ", "_"), *arguments)
        status = launch.wait(90.0)
        text = launch.output()
        starts = text.count("process started")
        reasons = [
            line
            for line in text.splitlines()
            if "[ERROR] [launch]" in line or "configuration error" in line
        ]
        check(
            label,
            status == 1 and starts <= 3 * len(NODES),
            f"status {status}, {starts} node starts, lines: {reasons}",
        )
        if status is None:
            launch.stop()


def scenario_respawn(probe: GraphProbe) -> None:
    """A killed node comes back after 2 s; a crash loop gives up after 5 restarts."""
    launch = Launch("respawn")
    if not graph_up(probe, launch):
        check("respawn: graph up", False, launch.output()[-500:])
        launch.stop()
        return
    pid = next(p for p, c in launch.children().items() if "motion_filter_node" in c)
    os.kill(pid, signal.SIGKILL)
    killed_s = time.monotonic()
    back = probe.wait_for(
        lambda: any("motion_filter_node" in c and p != pid for p, c in launch.children().items()),
        10.0,
    )
    check(
        "SIGKILL -> restart",
        back,
        f"new motion_filter_node process after {time.monotonic() - killed_s:.1f} s",
    )
    kills = 1
    while launch.process.poll() is None and kills < 10:
        for p, c in launch.children().items():
            if "motion_filter_node" in c:
                os.kill(p, signal.SIGKILL)
                kills += 1
        time.sleep(0.2)
    status = launch.wait(60.0)
    lines = [line for line in launch.output().splitlines() if "audio2pose_ros]" in line]
    check(
        "crash loop bounded",
        status == 1 and kills == 6,
        f"{kills} kills, launch status {status}, last: {lines[-1] if lines else None}",
    )
    if status is None:
        launch.stop()


def gone_after(pids: dict[int, str], timeout_s: float) -> tuple[float, list[str]]:
    """Seconds until none of ``pids`` runs (or the timeout), and those still running then."""
    start = time.monotonic()
    while alive(pids) and time.monotonic() - start < timeout_s:
        time.sleep(0.05)
    return time.monotonic() - start, alive(pids)


def scenario_signals(probe: GraphProbe) -> None:
    """SIGTERM and SIGINT to ros2 launch, at start-up (nodes importing) and when up."""
    for sig in (signal.SIGTERM, signal.SIGINT):
        for delay_s in (0.5, 1.5, 3.0, None):
            launch = Launch(f"{sig.name}_{delay_s}")
            if delay_s is None:  # this launch's own nodes: the graph may still list the last's
                probe.wait_for(lambda up=launch: len(up.children()) >= len(NODES), 40.0)
                graph_up(probe, launch)
            else:
                time.sleep(delay_s)
            children = launch.children()
            status, took_s = launch.stop(sig)
            after_s, left = gone_after(children, 10.0)
            when = "when up" if delay_s is None else f"{delay_s} s after start"
            check(
                f"{sig.name} {when}",
                not left and (delay_s is not None or len(children) == len(NODES)),
                f"{len(children)} node processes; ros2 launch ended in {took_s:.1f} s with "
                f"status {status}; nodes gone {after_s:.1f} s later; left: {left or 'none'}",
            )


def main(selected: list[str]) -> int:
    """Run the scenarios (all, or those named) and print a summary."""
    from audio2pose_ros.resources import default_checkpoint_path

    scenarios = {
        "defaults": scenario_defaults,
        "model_path": lambda probe: scenario_model_path(probe, default_checkpoint_path()),
        "names": scenario_booleans_and_namespaces,
        "errors": scenario_configuration_errors,
        "respawn": scenario_respawn,
        "signals": scenario_signals,
    }
    print(f"logs: {LOG_DIR}; ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID')}", flush=True)
    rclpy.init()
    try:
        probe = GraphProbe()
        for name in selected or scenarios:
            scenarios[name](probe)
    finally:
        rclpy.try_shutdown()
    failed = [name for name, ok, _ in RESULTS if not ok]
    print(
        f"{len(RESULTS) - len(failed)} of {len(RESULTS)} checks passed"
        + (f"; failed: {failed}" if failed else "")
    )
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
