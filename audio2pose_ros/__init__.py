"""audio2pose_ros: speech-driven upper-body motion for the Pepper humanoid.

The folders are the layers of the pipeline (the code map of doc/architecture.md): a ROS-free
core (``audio``, ``robot``, ``motion``, ``models``, ``checkpoints``, ``data``, ``offline``,
``viz``, ``learning``), the thin rclpy nodes in ``ros`` and the ``audio2pose`` command in ``cli``.

The public Python API is the names of :data:`__all__`, importable from here (``from
audio2pose_ros import FeatureSpec, MotionFilter``); they are loaded on first use, so importing
the package costs nothing. These names keep working across releases: a name that moves or goes
is first deprecated (a ``DeprecationWarning`` for at least one release, noted in CHANGELOG.md).
Everything else is internal and may change.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_PUBLIC = {
    "Audio2PoseError": "audio2pose_ros.errors",
    "ConfigurationError": "audio2pose_ros.errors",
    "InputError": "audio2pose_ros.errors",
    "FeatureSpec": "audio2pose_ros.audio.features",
    "extract_features": "audio2pose_ros.audio.features",
    "StreamingFeatureExtractor": "audio2pose_ros.audio.streaming",
    "RobotDescription": "audio2pose_ros.robot.description",
    "load_robot": "audio2pose_ros.robot.description",
    "BodyModel": "audio2pose_ros.robot.body",
    "SimulatedPepper": "audio2pose_ros.robot.simulated_pepper",
    "JointLimiter": "audio2pose_ros.motion.limits",
    "LimitSettings": "audio2pose_ros.motion.limits",
    "BodyGuard": "audio2pose_ros.motion.body_guard",
    "MotionFilter": "audio2pose_ros.motion.filter",
    "MotionFilterSettings": "audio2pose_ros.motion.filter",
    "StyleSettings": "audio2pose_ros.motion.style",
    "load_checkpoint": "audio2pose_ros.checkpoints.torch_io",
    "load_streaming_model": "audio2pose_ros.checkpoints.numpy_runtime",
    "synthesize": "audio2pose_ros.offline.synthesis",
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'audio2pose_ros' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
