"""The launch file's default arguments, as launch hands them to its OpaqueFunction (strings)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def arguments(**overrides: str) -> dict[str, str]:
    """The launch file's default arguments, as launch hands them over (strings)."""
    values = {
        "params_file": str(ROOT / "config" / "pepper.yaml"),
        "model_path": "",
        "style": "",
        "audio_ns": "/audio",
        "controller_topic": "/pepper_joint_trajectory_controller/joint_trajectory",
        "rviz": "false",
        "robot_state_publisher": "false",
        "sim": "none",
        "diagnostic_aggregator": "false",
        "single_process": "false",
        "console": "false",
        "voice_out": "off",
    }
    return {**values, **overrides}
