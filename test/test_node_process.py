"""Node processes die with the process that started them and stop cleanly on any signal.

``ros2 launch`` killed by SIGTERM (systemd, ``docker stop``) used to leave the three nodes running
as orphans, and Ctrl-C while a node was still importing was once swallowed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from audio2pose_ros.ros.supervisor import executable_command

pytestmark = pytest.mark.ros
NODE = "motion_filter_node"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    status = Path(f"/proc/{pid}/status")
    return not (status.exists() and "\nState:\tZ" in status.read_text())


def test_when_the_parent_is_killed_expect_the_node_to_exit(tmp_path: Path):
    """A parent that starts the node and is then SIGKILLed (it cannot clean up)."""
    pid_file = tmp_path / "node.pid"
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import subprocess, sys, time\n"
            f"p = subprocess.Popen({executable_command(NODE)!r} + ['--ros-args', '-p',"
            f" 'state_file:={tmp_path / 'state.json'}'])\n"
            f"open({str(pid_file)!r}, 'w').write(str(p.pid))\n"
            "time.sleep(600)\n",
        ]
    )
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not pid_file.exists():
        time.sleep(0.05)
    node = int(pid_file.read_text())
    time.sleep(3.0)  # the node is up (imports done, spinning)
    assert _alive(node)
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and _alive(node):
        time.sleep(0.05)
    orphan = _alive(node)
    if orphan:
        os.kill(node, signal.SIGKILL)
    assert not orphan, "the node outlived its parent"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize("after_s", [0.3, 1.0, 4.0])
def test_when_signalled_at_any_point_of_start_up_expect_quiet_exit(tmp_path, signum, after_s):
    """Started with SIGINT ignored, as a shell's background job is: Ctrl-C must still work."""
    process = subprocess.Popen(
        [*executable_command(NODE), "--ros-args", "-p", f"state_file:={tmp_path / 's.json'}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    time.sleep(after_s)
    process.send_signal(signum)
    try:
        output = process.communicate(timeout=10)[0]
    except subprocess.TimeoutExpired:
        process.kill()
        pytest.fail(f"{signal.Signals(signum).name} after {after_s} s was ignored")
    assert "Traceback" not in output, output
    assert process.returncode in (0, 128 + signum), output  # with a crash, faulthandler's stacks


def test_when_start_up_threads_exist_expect_stop_signals_blocked_in_every_one():
    """A stop signal during start-up must not run rclpy's handler on another thread.

    Before: numpy's and the middleware's threads accepted SIGINT, so under load a Ctrl-C could
    run rclpy's handler on one of them while the main thread created the node in the context it
    shut down: exit 78 ("the given context is not valid") or SIGABRT. After: every thread of a
    starting node process blocks SIGINT and SIGTERM until the nodes are built.
    """
    code = (
        "from audio2pose_ros.ros.nodes.process import prepare_node_process\n"
        "prepare_node_process()\n"
        "import numpy, rclpy, threading, pathlib\n"
        "numpy.ones((64, 64)) @ numpy.ones((64, 64))\n"
        "threading.Thread(target=lambda: None).start()\n"
        "for status in pathlib.Path('/proc/self/task').glob('*/status'):\n"
        "    line = next(l for l in status.read_text().splitlines() if l.startswith('SigBlk'))\n"
        "    print(int(line.split()[1], 16))\n"
    )
    masks = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    stop = (1 << (signal.SIGINT - 1)) | (1 << (signal.SIGTERM - 1))
    assert masks, "no thread found"
    assert all(int(mask) & stop == stop for mask in masks), masks
