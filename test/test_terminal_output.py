"""With ``--log-dir`` the nodes' output goes to files; what the user must see still reaches the
terminal: the console's address with its token, and a node's refused configuration.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
from pathlib import Path

import pytest

from audio2pose_ros.ros.supervisor import executable_command

AUDIO2POSE = executable_command("audio2pose")
TOKEN = "terminal-test-token-0123456789"


def _lines(stream, into: queue.Queue[str | None]) -> None:
    for line in stream:
        into.put(line)
    into.put(None)


@pytest.mark.ros
def test_when_console_logs_to_a_directory_expect_its_address_and_token_on_the_terminal(
    tmp_path: Path,
):
    logs = tmp_path / "logs"
    process = subprocess.Popen(
        [
            *AUDIO2POSE,
            "console",
            "--no-graph",
            "--port",
            "0",
            "--token",
            TOKEN,
            "--log-dir",
            str(logs),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    lines: queue.Queue[str | None] = queue.Queue()
    threading.Thread(target=_lines, args=(process.stdout, lines), daemon=True).start()
    seen: list[str] = []
    try:
        while True:
            line = lines.get(timeout=120)  # a bound on a hang, not a verdict on speed
            if line is None or "operator console: open" in line:
                break
            seen.append(line)
    finally:
        os.killpg(process.pid, signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    assert line is not None, "".join(seen)[-2000:]
    assert line.startswith("[console_node] operator console: open http://127.0.0.1:")
    assert f"/#token={TOKEN} and press Talk (token required)" in line
    assert "operator console: open" in (logs / "console_node.log").read_text()  # and in the log


@pytest.mark.ros
def test_when_run_logs_to_a_directory_expect_a_refused_parameter_named_on_the_terminal(
    tmp_path: Path,
):
    """Not only "see its log": the node's own line, naming the parameter, reaches the terminal."""
    params = tmp_path / "params.yaml"
    params.write_text("motion_filter_node:\n  ros__parameters:\n    head_gain: .nan\n")
    logs = tmp_path / "logs"
    result = subprocess.run(
        [*AUDIO2POSE, "run", "--params-file", str(params), "--log-dir", str(logs)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 1, result.stderr[-500:]
    (line,) = [
        line
        for line in result.stderr.splitlines()
        if line.startswith("[motion_filter_node] configuration error:")
    ]
    assert "head_gain" in line
    assert line in (logs / "motion_filter_node.log").read_text()
