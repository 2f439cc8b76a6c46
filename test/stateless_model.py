"""A frame-wise MLP checkpoint for graph tests that compare poses across runs.

The packaged default samples with a recurrent state, which depends on every frame it has seen
(the warm-up silence included); a frame-wise MLP's pose depends on the current frame only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch


def stateless_checkpoint(path: Path, robot, speech: np.ndarray) -> Path:
    """A frame-wise MLP checkpoint: its pose depends on the current frame only, so the stream
    and the offline run agree frame for frame whatever the warm-up (the packaged default is a
    recurrent sampler, whose state depends on every frame it has seen). Untrained, normalised
    on the speech itself, so that its poses follow the audio."""
    from audio2pose_ros.audio.features import FeatureSpec, extract_features
    from audio2pose_ros.audio.normalize import FeatureNormalizer
    from audio2pose_ros.checkpoints.torch_io import Checkpoint, save_checkpoint
    from audio2pose_ros.models.registry import build_model

    spec = FeatureSpec()
    torch.manual_seed(0)
    model = build_model("mlp", {"n_features": spec.dim, "n_joints": robot.n_joints})
    normalizer = FeatureNormalizer.fit(extract_features(speech, spec))
    return save_checkpoint(path, Checkpoint(model, spec, normalizer, robot))
