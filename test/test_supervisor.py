"""The node supervisor of `audio2pose run`: bounded restarts, no respawn of configuration errors,
silent nodes restarted, command-line overrides over the parameters file (real processes)."""

from __future__ import annotations

import itertools
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR, UsageError
from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_PERIOD_S, STALE_AFTER_S
from audio2pose_ros.ros.launch_support import RespawnBudget
from audio2pose_ros.ros.supervisor import (
    RESTART_AFTER_S,
    NodeSupervisor,
    executable_command,
    overrides_file,
)
from audio2pose_ros.ros.supervisor_pipe import STACK_DUMP_SIGNAL


def _python(code: str) -> list[str]:
    return [sys.executable, "-c", code]


HANG_S = 60.0  # waits end here only when what they wait for never comes (a loaded machine is slow)


def _wait(predicate, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def test_when_node_exits_with_configuration_error_expect_no_restart(tmp_path: Path):
    supervisor = NodeSupervisor(
        {"bad": _python(f"import sys; sys.exit({EXIT_CONFIGURATION_ERROR})")},
        tmp_path,
        budget=RespawnBudget(first_delay_s=0.05),
    )
    supervisor.start()
    try:
        assert _wait(lambda: "bad" in supervisor.given_up, 10.0)
        time.sleep(0.5)
        assert supervisor.restarts["bad"] == []
        assert not supervisor.running
    finally:
        supervisor.stop()


def test_when_node_keeps_crashing_expect_backoff_then_give_up(tmp_path: Path):
    supervisor = NodeSupervisor(
        {"crash": _python("import sys; sys.exit(1)")},
        tmp_path,
        budget=RespawnBudget(max_restarts=3, first_delay_s=0.3),
    )
    supervisor.start()
    try:
        assert _wait(lambda: "crash" in supervisor.given_up, 20.0)
        times = supervisor.restarts["crash"]
        assert len(times) == 3
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert all(later > earlier for earlier, later in itertools.pairwise(gaps))
    finally:
        supervisor.stop()


STUCK_CHILD = (  # registers the stack dump as node processes do, then hangs in a "callback"
    "import faulthandler, signal, time\n"
    f"faulthandler.register({int(STACK_DUMP_SIGNAL)}, all_threads=True)\n"
    "def stuck_in_a_callback():\n"
    "    time.sleep(60)\n"
    "stuck_in_a_callback()\n"
)


def test_when_node_goes_silent_expect_its_stacks_logged_then_killed_and_restarted(tmp_path: Path):
    supervisor = NodeSupervisor(
        {"quiet": _python(STUCK_CHILD)},
        tmp_path,
        budget=RespawnBudget(first_delay_s=0.05),
        startup_grace_s=30.0,
    )
    supervisor.start()
    try:
        first = supervisor.processes["quiet"]
        supervisor.heartbeat("quiet", first.pid)  # heard once, then never again (like SIGSTOP)
        heard = time.monotonic()
        assert _wait(lambda: supervisor.silences["quiet"] == 1, HANG_S)
        assert time.monotonic() - heard >= RESTART_AFTER_S
        assert first.poll() is not None
        assert _wait(lambda: supervisor.processes["quiet"] is not first, HANG_S)
        assert supervisor.processes["quiet"].poll() is None
    finally:
        supervisor.stop()
    assert "stuck_in_a_callback" in (tmp_path / "quiet.log").read_text()


def test_when_node_is_starved_for_a_moment_expect_it_kept_running(tmp_path: Path):
    """A gap of a few heartbeats (a busy machine; CI saw 1.3 s) is STALE, not a reason to kill."""
    supervisor = NodeSupervisor(
        {"busy": _python("import time; time.sleep(60)")},
        tmp_path,
        budget=RespawnBudget(first_delay_s=0.05),
    )
    supervisor.start()
    try:
        process = supervisor.processes["busy"]
        gap_s = (STALE_AFTER_S + RESTART_AFTER_S) / 2
        for _ in range(2):
            supervisor.heartbeat("busy", process.pid)
            time.sleep(gap_s)
            assert supervisor.silent_s("busy") > STALE_AFTER_S
        supervisor.heartbeat("busy", process.pid)
        time.sleep(2 * HEARTBEAT_PERIOD_S)
        assert supervisor.silences["busy"] == 0
        assert supervisor.restarts["busy"] == []
        assert supervisor.processes["busy"] is process
        assert process.poll() is None
        assert gap_s <= supervisor.longest_gap_s["busy"] < gap_s + 1.0  # the gap is on record
    finally:
        supervisor.stop()


def test_when_restart_limit_is_not_above_stale_limit_expect_value_error(tmp_path: Path):
    with pytest.raises(ValueError, match="must exceed the stale limit"):
        NodeSupervisor({"x": _python("pass")}, tmp_path, restart_after_s=STALE_AFTER_S)


def test_when_override_is_not_name_value_expect_usage_error(tmp_path: Path):
    with pytest.raises(UsageError, match="not name:=value"):
        overrides_file(["rate_hz=50"], tmp_path)


def test_overrides_target_each_node_by_name(tmp_path: Path):
    document = yaml.safe_load(
        overrides_file(["rate_hz:=50", "smoothing:=none"], tmp_path).read_text()
    )
    assert document["motion_filter_node"]["ros__parameters"] == {"rate_hz": 50, "smoothing": "none"}
    assert set(document) == {"audio_features_node", "inference_node", "motion_filter_node"}


@pytest.mark.ros
def test_when_command_line_and_params_file_disagree_expect_command_line_to_win(tmp_path: Path):
    """A node-specific model_path in the file is a missing file: the node exits 78 unless the
    command-line override (the packaged model) wins."""
    params = tmp_path / "params.yaml"
    params.write_text(
        yaml.safe_dump({"inference_node": {"ros__parameters": {"model_path": "/nonexistent.st"}}})
    )
    base = [*executable_command("inference_node"), "--ros-args", "--params-file", str(params)]
    from audio2pose_ros.resources import default_checkpoint_path

    override = overrides_file([f"model_path:={default_checkpoint_path()}"], tmp_path)
    file_only = subprocess.run(base, capture_output=True, text=True, timeout=60)
    assert file_only.returncode == EXIT_CONFIGURATION_ERROR
    assert "/nonexistent.st" in file_only.stderr
    process = subprocess.Popen(
        [*base, "--params-file", str(override)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        time.sleep(6.0)
        alive = process.poll() is None
    finally:
        process.terminate()
        output = process.communicate(timeout=10)[0]
    assert alive, output
    assert f"from {default_checkpoint_path()}" in output


def test_when_a_node_crashes_once_expect_restart_at_once_then_back_off(tmp_path: Path, capfd):
    supervisor = NodeSupervisor(
        {"crash": _python("import time, sys; time.sleep(0.3); sys.exit(1)")},
        tmp_path,
        budget=RespawnBudget(first_delay_s=1.0),
    )
    supervisor.start()
    try:
        assert _wait(lambda: len(supervisor.restarts["crash"]) >= 3, HANG_S)
        second, third = supervisor.restarts["crash"][1:3]  # times of the 2nd and 3rd exits
        assert third - second >= 0.3 + 1.0  # the second restart waited the back-off
    finally:
        supervisor.stop()
    said = [line for line in capfd.readouterr().err.splitlines() if "restarting it in" in line]
    assert said[0].endswith("restarting it in 0.0 s")  # at once
    assert said[1].endswith("restarting it in 1.0 s")  # then the back-off
    assert said[2].endswith("restarting it in 2.0 s")


BEATING_CHILD = (  # a node's heartbeat, through the supervisor's pipe when it gives one
    "import os, time\n"
    "fd = os.environ.get('AUDIO2POSE_HEARTBEAT_FD')\n"
    "while True:\n"
    "    if fd: os.write(int(fd), b'.')\n"
    "    time.sleep(0.2)\n"
)


@pytest.mark.ros
def test_when_a_stopped_node_is_impersonated_on_diagnostics_expect_stale_and_replaced(
    tmp_path: Path,
):
    """Liveness comes from the supervised process itself: another process publishing the node's
    status name and pid on /diagnostics does not keep a SIGSTOPped node from being replaced."""
    import os
    import signal

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from audio2pose_ros.ros.supervisor import HeartbeatMonitor

    supervisor = NodeSupervisor(
        {"motion_filter_node": _python(BEATING_CHILD)}, tmp_path, startup_grace_s=1.0
    )
    supervisor.start()
    monitor = HeartbeatMonitor(supervisor)
    rclpy.init()
    impostor = rclpy.create_node("impostor")
    stale: list[tuple[str, int]] = []  # each STALE report, with the kills so far (the order)
    impostor.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda msg: stale.extend(
            (s.name, supervisor.silences["motion_filter_node"])
            for s in msg.status
            if s.level == DiagnosticStatus.STALE
        ),
        10,
    )
    publisher = impostor.create_publisher(DiagnosticArray, "/diagnostics", 10)
    try:
        child = supervisor.processes["motion_filter_node"]
        assert _wait(lambda: supervisor.longest_gap_s["motion_filter_node"] > 0, HANG_S)
        assert supervisor.silences["motion_filter_node"] == 0  # beating through its pipe
        os.kill(child.pid, signal.SIGSTOP)
        # Until the kill (or until only a hung supervisor would not have killed it), the
        # impostor speaks for the stopped node: its status does not keep it alive.
        deadline = time.monotonic() + HANG_S
        while time.monotonic() < deadline and supervisor.silences["motion_filter_node"] == 0:
            pid = KeyValue(key="pid", value=str(child.pid))
            names = ("audio2pose_ros: /motion_filter_node", "audio2pose_ros: motion_filter_node")
            publisher.publish(
                DiagnosticArray(status=[DiagnosticStatus(name=n, values=[pid]) for n in names])
            )
            rclpy.spin_once(impostor, timeout_sec=0.1)
        assert supervisor.silences["motion_filter_node"] == 1, "impostor kept it alive"
        assert ("audio2pose_ros: /motion_filter_node", 0) in stale  # STALE before the kill
        assert _wait(lambda: supervisor.processes["motion_filter_node"] is not child, HANG_S)
    finally:
        impostor.destroy_node()
        rclpy.try_shutdown()
        monitor.close()
        supervisor.stop()


def test_when_a_restart_cannot_be_started_expect_a_failure_like_a_crash_and_the_others_watched(
    tmp_path: Path,
):
    """A node whose executable is gone (an upgrade while it runs) does not end the supervision."""
    vanishing = tmp_path / "vanishing_node"
    vanishing.write_text('#!/bin/sh\nrm -f "$0"\nexit 1\n')  # runs once, then cannot start
    vanishing.chmod(0o755)
    supervisor = NodeSupervisor(
        {"vanishing": [str(vanishing)], "crashing": _python("import sys; sys.exit(1)")},
        tmp_path / "logs",
        budget=RespawnBudget(max_restarts=3, first_delay_s=0.1),
    )
    supervisor.start()
    try:
        assert _wait(lambda: "vanishing" in supervisor.given_up, 10.0)  # retried, then given up
        assert _wait(lambda: "crashing" in supervisor.given_up, 10.0)  # still supervised
        assert len(supervisor.restarts["crashing"]) == 3
    finally:
        supervisor.stop()


def test_when_run_and_launch_restart_a_node_expect_one_policy():
    """`audio2pose run` restarts as the launch file does: the same RespawnBudget decides."""
    supervisor = NodeSupervisor({"node": _python("pass")}, None)
    launch = RespawnBudget()  # what launch/pepper.launch.py builds
    assert supervisor.budget == launch
    decisions = [supervisor.budget.on_exit("node", 1, ran_s=0.5) for _ in range(6)]
    expected = [launch.on_exit("node", 1, ran_s=0.5) for _ in range(6)]
    assert decisions == expected
    assert [d.delay_s for d in decisions if d.restart] == [0.0, 2.0, 4.0, 8.0, 8.0]
    assert not decisions[-1].restart  # the sixth crash in a row gives up
