"""What the node processes import: nothing they do not use (their resident memory).

Checked in fresh interpreters started as the node executables start (``nodes.process``), so
that no other test's imports count. The figures themselves (MB per node against bare rclpy
relays) come from ``audio2pose bench --graph``; these checks are structural.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WATCHED = ("pinocchio", "coal", "hppfcl", "lark", "em", "rosidl_parser.parser")


def _loaded_after(code: str) -> dict[str, bool]:
    """Run ``code`` as a node process would (stop signals, no code generator); the modules of
    :data:`WATCHED` it imported."""
    probe = (
        "import json, sys\n"
        "from audio2pose_ros.ros.nodes.process import (\n"
        "    defer_message_code_generator, prepare_node_process)\n"
        "prepare_node_process()\n"
        "defer_message_code_generator()\n"
        + code
        + f"\nprint(json.dumps({{m: m in sys.modules for m in {WATCHED!r}}}))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def test_when_the_motion_filter_runs_expect_its_guard_on_coal_without_pinocchio() -> None:
    """The guard's exact body model measures with coal and places the shapes with numpy.

    Before: motion_filter_node loaded Pinocchio for the forward kinematics alone (about 21 MB
    of its 130 MB); after: coal only.
    """
    code = (
        "import numpy as np\n"
        "import rclpy\n"
        "from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode\n"
        "rclpy.init(args=['--ros-args', '-p', 'state_file:=/dev/null/none'])\n"
        "node = MotionFilterNode()\n"
        "guard = node.filter.body_guard\n"
        "assert guard.margin_m > 0.0\n"
        "assert guard.body.clearance(guard.body.robot.neutral_rad) > guard.margin_m\n"
        "node.destroy_node()\n"
        "rclpy.shutdown()\n"
    )
    loaded = _loaded_after(code)
    assert not loaded["pinocchio"]
    assert loaded["coal"] or loaded["hppfcl"]


def test_when_a_node_publishes_expect_no_message_code_generator_yet_all_of_its_package() -> None:
    """Message type support comes from rosidl_generator_py without its build-time generator.

    Before: the first publisher imported the generator (lark, empy, OpenSSL: 3 to 6.5 MB of
    each node process); after: not, and the package's other names still load when asked for.
    """
    code = (
        "import rclpy\n"
        "from std_msgs.msg import Float32MultiArray\n"
        "rclpy.init()\n"
        "node = rclpy.create_node('footprint_probe')\n"
        "node.create_publisher(Float32MultiArray, 'footprint_probe', 1).publish(\n"
        "    Float32MultiArray(data=[1.0]))\n"
        "node.destroy_node()\n"
        "rclpy.shutdown()\n"
    )
    loaded = _loaded_after(code)
    assert not any(loaded[m] for m in ("lark", "em", "rosidl_parser.parser")), loaded
    later = (
        "import rosidl_generator_py\n"
        "from rosidl_generator_py import generate_py, import_type_support\n"
        "assert callable(generate_py) and callable(import_type_support)\n"
    )
    assert _loaded_after(later)["lark"]  # asked for: the whole package, as usual
