"""A node process ends in order: its executor shut down, its nodes destroyed, then rclpy.

:func:`audio2pose_ros.ros.spin.run_nodes` leaves nothing to the interpreter's exit, which tears
objects down in whatever order it finds them (a service or a guard condition destroyed after the
context it lives in). A process of two nodes, started as the node executables start (stop
signals blocked from the first line), is stopped by SIGTERM and by SIGINT while it spins; each
node says when it is destroyed, whether the executor still held it then and whether rclpy was
still up: Jazzy's middleware crashes when an entity is destroyed after its context shut down
(SIGSEGV in a subscription's destruction), which rclpy's own signal handlers did on a thread of
their own.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

PROCESS = """
from audio2pose_ros.ros.nodes.process import prepare_node_process
prepare_node_process()
import atexit
import rclpy
from rclpy.node import Node
from audio2pose_ros.ros import spin

class Told(Node):
    def __init__(self, name):
        super().__init__(name)
        self.create_timer(0.1, lambda: print("spinning", name, flush=True))

    def destroy_node(self):
        held = self in self.executor.get_nodes() if self.executor is not None else False
        print("destroyed", self.get_name(), "held:", held, "rclpy ok:", rclpy.ok(), flush=True)
        super().destroy_node()

atexit.register(lambda: print("at exit: rclpy ok:", rclpy.ok(), flush=True))
spin.run_nodes([lambda: Told("first"), lambda: Told("second")], "test_spin_close")
"""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_when_a_node_process_is_stopped_expect_its_nodes_destroyed_before_rclpy_shuts_down(
    signum: signal.Signals,
) -> None:
    process = subprocess.Popen(
        [sys.executable, "-c", PROCESS], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert process.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + 60.0
    while not any(line.startswith("spinning second") for line in lines):
        line = process.stdout.readline()
        assert line, "".join(lines)
        assert time.monotonic() < deadline, "".join(lines)
        lines.append(line)
    process.send_signal(signum)
    output = "".join(lines) + process.communicate(timeout=30)[0]
    assert process.returncode in (0, 128 + signum), output
    assert "Traceback" not in output, output
    said = [line for line in output.splitlines() if not line.startswith("spinning")]
    # the nodes destroyed in the reverse of their building, out of the executor by then and
    # before rclpy shut down (SIGTERM leaves with exit status 143, after the same end)
    assert said == [
        "destroyed second held: False rclpy ok: True",
        "destroyed first held: False rclpy ok: True",
        "at exit: rclpy ok: False",
    ], output
