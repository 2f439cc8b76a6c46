"""Node executables, or the command line, in their own process: tests of how they refuse."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import audio2pose_ros
from audio2pose_ros.errors import EXIT_CONFIGURATION_ERROR
from audio2pose_ros.ros.supervisor import executable_command

PACKAGE_ROOT = Path(audio2pose_ros.__file__).resolve().parent.parent


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


def cli_in_child(*argv: object, timeout: float) -> subprocess.CompletedProcess[str]:
    """``audio2pose *argv`` in a child with 1 GiB of address space, killed after ``timeout``.

    For inputs that could hang a reader or fill the memory: the test fails, not the machine.
    """
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))\n"
        "from audio2pose_ros.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    return subprocess.run(
        [sys.executable, "-c", code, *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "PYTHONPATH": str(PACKAGE_ROOT)},
    )
