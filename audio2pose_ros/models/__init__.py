"""Pose models (torch, no ROS): the registry maps a model name to its class and config."""

from __future__ import annotations

from typing import Any

from audio2pose_ros.models.base import PoseModel, StreamingPredictor
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig

MODEL_REGISTRY: dict[str, tuple[type[PoseModel], type]] = {
    FramewiseMLP.name: (FramewiseMLP, MLPConfig),
}


def build_model(name: str, config: dict[str, Any]) -> PoseModel:
    """Instantiate the model ``name`` from its config dict.

    Raises:
        ValueError: unknown model name or config keys the model does not take.

    """
    if name not in MODEL_REGISTRY:
        raise ValueError(f"unknown model {name!r}; available: {sorted(MODEL_REGISTRY)}")
    model_cls, config_cls = MODEL_REGISTRY[name]
    try:
        return model_cls(config_cls(**config))
    except TypeError as exc:
        raise ValueError(f"model {name!r}: bad config {config} ({exc})") from None


__all__ = [
    "MODEL_REGISTRY",
    "FramewiseMLP",
    "MLPConfig",
    "PoseModel",
    "StreamingPredictor",
    "build_model",
]
