"""The model registry: a model name (``mlp``, ``live_groups``, ...) to its class and config."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.base import (
    FitStage,
    OfflineOnlyModelError,
    PoseModel,
    StreamingPredictor,
    TrainingRecipe,
    require_streaming,
)
from audio2pose_ros.models.blstm import BLSTMConfig, SpanBLSTM
from audio2pose_ros.models.blstm_prior import BLSTMPriorConfig, PriorMotionBLSTM
from audio2pose_ros.models.cvae import CVAEConfig, SpeechCVAE
from audio2pose_ros.models.dae_gru import DAEGRU, DAEGRUConfig
from audio2pose_ros.models.live import LiveConfig, LiveSampler
from audio2pose_ros.models.live_groups import LiveGroups, LiveGroupsConfig
from audio2pose_ros.models.lstm import CausalLSTM, LSTMConfig
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.models.sampling_noise import PerJoint

MODEL_REGISTRY: dict[str, tuple[type[PoseModel], type]] = {
    model.name: (model, config)
    for model, config in (
        (FramewiseMLP, MLPConfig),
        (CausalLSTM, LSTMConfig),
        (DAEGRU, DAEGRUConfig),
        (SpanBLSTM, BLSTMConfig),
        (PriorMotionBLSTM, BLSTMPriorConfig),
        (SpeechCVAE, CVAEConfig),
        (LiveSampler, LiveConfig),
        (LiveGroups, LiveGroupsConfig),
    )
}


MAX_CONFIG_INT = 1024  # largest integer a model config may hold (units, layers, frames)


def build_model(name: str, config: dict[str, Any]) -> PoseModel:
    """Instantiate the model ``name`` from its config dict.

    Every value must have its field's type (an integer is accepted for a float), be finite, and
    integers must lie in [0, :data:`MAX_CONFIG_INT`]: a config read from a file cannot ask for
    millions of layers or units.

    Raises:
        ConfigurationError: unknown model name, unknown config keys, or a bad value (the message
            names the model and the key).

    """
    if name not in MODEL_REGISTRY:
        raise ConfigurationError(f"unknown model {name!r}; available: {sorted(MODEL_REGISTRY)}")
    model_cls, config_cls = MODEL_REGISTRY[name]
    kinds = {f.name: type(f.default) for f in dataclasses.fields(config_cls)}
    unknown = sorted(set(config) - set(kinds))
    if unknown:
        raise ConfigurationError(
            f"model {name!r}: unknown config keys {unknown}; known {sorted(kinds)}"
        )
    # a PerJoint may be one number per joint: the model checks it against its joints
    per_joint = {f.name for f in dataclasses.fields(config_cls) if f.type in ("PerJoint", PerJoint)}
    for key, value in config.items():
        if not (key in per_joint and isinstance(value, list | tuple)):
            _check_config_value(name, key, value, kinds[key])
    return model_cls(config_cls(**config))


def _check_config_value(name: str, key: str, value: object, kind: type) -> None:
    """Refuse a config value of the wrong type, non-finite, or an integer out of range."""
    number = isinstance(value, int | float) and not isinstance(value, bool)
    if kind is int and (not number or not isinstance(value, int)):
        problem = "is not an integer"
    elif kind is float and not number:
        problem = "is not a number"
    elif kind is bool and not isinstance(value, bool):
        problem = "is not true or false"
    elif isinstance(value, int | float) and not math.isfinite(value):
        problem = "is not finite"
    elif kind is int and isinstance(value, int) and not 0 <= value <= MAX_CONFIG_INT:
        problem = f"is outside [0, {MAX_CONFIG_INT}]"
    else:
        return
    raise ConfigurationError(f"model {name!r}: config {key}={value!r} {problem}")


__all__ = [
    "DAEGRU",
    "MAX_CONFIG_INT",
    "MODEL_REGISTRY",
    "BLSTMConfig",
    "BLSTMPriorConfig",
    "CVAEConfig",
    "CausalLSTM",
    "DAEGRUConfig",
    "FitStage",
    "FramewiseMLP",
    "LSTMConfig",
    "LiveConfig",
    "LiveGroups",
    "LiveGroupsConfig",
    "LiveSampler",
    "MLPConfig",
    "OfflineOnlyModelError",
    "PoseModel",
    "PriorMotionBLSTM",
    "SpanBLSTM",
    "SpeechCVAE",
    "StreamingPredictor",
    "TrainingRecipe",
    "build_model",
    "require_streaming",
]
