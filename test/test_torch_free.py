"""Torch is for training only: the runner and the node processes never import it.

``audio2pose run`` (parser, supervisor, player, recorder) and the three node executables, in
either mode, are checked in a fresh interpreter: after building the parser and parsing ``run``
and ``demo``, ``torch`` must be absent from ``sys.modules``; after importing the node modules
and building the nodes, torch and scipy (which only offline code and the low-pass filter
need) must be absent. A verb that needs torch still gets it.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

GRAPH_MODULES = (
    "audio2pose_ros.ros.nodes.process",
    "audio2pose_ros.ros.nodes.single_process",
    "audio2pose_ros.ros.nodes.audio_features_node",
    "audio2pose_ros.ros.nodes.inference_node",
    "audio2pose_ros.ros.nodes.motion_filter_node",
)


def _loaded_after(code: str) -> dict[str, bool]:
    """Run ``code`` in a fresh interpreter; whether torch and scipy were imported by it."""
    probe = (
        "import json, sys\n"
        + code
        + "\nprint(json.dumps({m: m in sys.modules for m in ('torch', 'scipy')}))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_run_and_demo_verbs_and_the_graph_runner_import_no_torch_nor_scipy() -> None:
    """Before: building the parser imported torch (model_commands.register) and scipy
    (render_commands -> viz.render); after: neither."""
    code = (
        "from audio2pose_ros.cli.main import build_parser\n"
        "parser = build_parser()\n"
        "parser.parse_args(['run', '--single-process'])\n"
        "parser.parse_args(['demo'])\n"
        "import audio2pose_ros.ros.run_command\n"
    )
    assert _loaded_after(code) == {"torch": False, "scipy": False}


def test_the_node_processes_import_neither_torch_nor_scipy() -> None:
    """Importing every node module and building the three nodes needs neither.

    Before: motion_filter_node imported scipy (motion.smoothing, ~70 MB); after: not.
    """
    code = (
        "import importlib\n"
        f"for name in {GRAPH_MODULES!r}:\n"
        "    importlib.import_module(name)\n"
        "import rclpy\n"
        "from audio2pose_ros.ros.nodes.audio_features_node import AudioFeaturesNode\n"
        "from audio2pose_ros.ros.nodes.inference_node import InferenceNode\n"
        "from audio2pose_ros.ros.nodes.motion_filter_node import MotionFilterNode\n"
        "rclpy.init(args=['--ros-args', '-p', 'state_file:=/dev/null/none'])\n"
        "nodes = [cls() for cls in (AudioFeaturesNode, InferenceNode, MotionFilterNode)]\n"
        "rclpy.shutdown()\n"
    )
    assert _loaded_after(code) == {"torch": False, "scipy": False}


def test_a_training_verb_still_checks_its_choices() -> None:
    """The lazy choices are the registry's: an unknown model family is refused with the list."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "audio2pose_ros.cli.main",
            "train",
            "--data",
            "d",
            "-o",
            "o",
            "--model",
            "nope",
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    assert result.returncode == 2
    assert "invalid choice: 'nope'" in result.stderr
    assert "'live_groups'" in result.stderr
