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
WATCHED = (
    "pinocchio",
    "coal",
    "hppfcl",
    "lark",
    "em",
    "rosidl_parser.parser",
    "_hashlib",
    "safetensors",
    "decimal",
    "difflib",
    "tempfile",
    "lxml",
    "urdf_parser_py",
    "audio2pose_ros.robot.kinematics",
)


def _loaded_after(code: str) -> dict[str, bool]:
    """Run ``code`` as a node process would (stop signals, no code generator, URDFs parsed in a
    child process); the modules of :data:`WATCHED` it imported."""
    probe = (
        "import json, sys\n"
        "from audio2pose_ros.ros.nodes.process import (\n"
        "    lighten_node_imports, prepare_node_process)\n"
        "prepare_node_process()\n"
        "lighten_node_imports()\n"
        + code
        + f"\nprint(json.dumps({{m: sys.modules.get(m) is not None for m in {WATCHED!r}}}))\n"
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
    assert loaded["audio2pose_ros.robot.kinematics"]
    assert not loaded["tempfile"], loaded  # its state file is written without it
    assert not loaded["lxml"], loaded  # parsed in a child process
    assert not loaded["urdf_parser_py"], loaded


def test_when_the_inference_node_runs_expect_no_xml_library_and_no_openssl() -> None:
    """The inference node's capsule model comes from the URDF, parsed in a child process;
    its random generators come without OpenSSL.

    Before: ``urdf_parser_py`` and ``lxml`` stayed mapped in the node (4.2 MB) after it read
    its URDF once at start, and ``numpy.random`` loaded OpenSSL's hashes (``secrets`` imports
    ``hmac``, ``hmac`` imports ``hashlib``: 3.3 MB); after: none of them.
    """
    code = (
        "import rclpy\n"
        "from audio2pose_ros.ros.nodes.inference_node import InferenceNode\n"
        "rclpy.init()\n"
        "node = InferenceNode()\n"
        "node.destroy_node()\n"
        "rclpy.shutdown()\n"
    )
    loaded = _loaded_after(code + "import hashlib, hmac, secrets\nsecrets.token_hex(4)\n")
    assert loaded["audio2pose_ros.robot.kinematics"]
    assert not loaded["lxml"], loaded
    assert not loaded["urdf_parser_py"], loaded
    assert not loaded["_hashlib"], loaded


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


def test_when_the_features_node_runs_expect_its_checkpoint_verified_without_openssl() -> None:
    """The features node verifies the model's digest with CPython's own SHA-256.

    Before: it imported OpenSSL's hashes (``_hashlib``: libcrypto, 3.6 MB resident),
    ``safetensors`` (0.8 MB) for one exception class, ``decimal`` (0.3 MB) to round a window
    length and ``difflib`` (0.1 MB) to suggest names for unknown parameters; after: none of
    them, and it still refuses a checkpoint edited after saving.
    """
    code = (
        "import rclpy\n"
        "from audio2pose_ros.checkpoints.format import CheckpointError, feature_spec_of\n"
        "from audio2pose_ros.resources import default_checkpoint_path\n"
        "from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode\n"
        "rclpy.init()\n"
        "node = AudioFeaturesNode()\n"
        "assert node.extractor is not None\n"
        "node.destroy_node()\n"
        "rclpy.shutdown()\n"
        "import pathlib, tempfile\n"
        "data = bytearray(default_checkpoint_path().read_bytes())\n"
        "data[-1] ^= 1\n"
        "edited = pathlib.Path(tempfile.mkdtemp()) / 'edited.safetensors'\n"
        "edited.write_bytes(bytes(data))\n"
        "try:\n"
        "    feature_spec_of(edited)\n"
        "except CheckpointError as exc:\n"
        "    assert 'checksum mismatch' in str(exc), exc\n"
        "else:\n"
        "    raise AssertionError('an edited checkpoint was accepted')\n"
    )
    loaded = _loaded_after(code)
    assert not any(loaded[m] for m in ("_hashlib", "safetensors", "decimal", "difflib")), loaded
