"""Pose models (torch, no ROS): the registry maps a model name to its class and config.

| name | seed | streams |
|---|---|---|
| ``mlp`` | 003 section 4.3.3 | yes |
| ``lstm`` | 003 section 4.3.4 | yes (state carried) |
| ``dae_gru`` | 000 sections 4.3-4.5 | no (centred 61-frame context) |
| ``blstm`` | 002 section 3.1 | no |
| ``blstm_prior`` | 002 section 3.2 | no |
| ``cvae`` | 002 section 3.3 | no (samples) |
| ``live`` | ours | yes (samples) |
"""

from __future__ import annotations

from typing import Any

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
from audio2pose_ros.models.lstm import CausalLSTM, LSTMConfig
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig

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
    )
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
    "DAEGRU",
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
