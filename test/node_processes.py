"""Starting a node executable as its own process, for tests of how it refuses to start."""

from __future__ import annotations

import subprocess

from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR
from audio2pose_ros.ros.graph import executable_command


def configuration_error_line(node: str, *ros_args: str) -> str:
    """Run ``node --ros-args *ros_args``; return the one line it leaves when it refuses to start.

    Asserts the exit status supervisors never respawn (78), exactly one error line and no
    traceback.
    """
    result = subprocess.run(
        [*executable_command(node), "--ros-args", *ros_args],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == EXIT_CONFIGURATION_ERROR, result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    lines = [line for line in result.stderr.splitlines() if "configuration error" in line]
    assert len(lines) == 1, result.stderr
    return lines[0]
