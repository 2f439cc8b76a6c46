"""Self-describing, code-free checkpoints (safetensors).

A checkpoint is one ``.safetensors`` file: the model's tensors plus a JSON header entry holding
everything needed to use it without the training code: format version, model name and config,
feature specification, feature normalisation statistics, the robot description (joint order and
ranges) and free-form training information. Loading never executes code (safetensors holds only
tensors and strings), and a SHA-256 digest over header and tensors detects files changed after
saving. A checkpoint whose joints, ranges or features differ from what the caller expects is
refused with a message that lists the differences.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from audio2pose_ros.audio.features import FeatureNormalizer, FeatureSpec
from audio2pose_ros.checkpoint_format import (
    DIGEST_KEY,
    FORMAT_VERSION,
    HEADER_KEY,
    CheckpointError,
    read_metadata,
)

__all__ = ["Checkpoint", "CheckpointError", "load_checkpoint", "save_checkpoint"]
from audio2pose_ros.models import PoseModel, build_model
from audio2pose_ros.robot import RobotDescription


@dataclass
class Checkpoint:
    """A loaded model with everything needed to feed it and interpret its output."""

    model: PoseModel
    features: FeatureSpec
    normalizer: FeatureNormalizer
    robot: RobotDescription
    info: dict[str, Any] = field(default_factory=dict)


def _digest(header: str, tensors: dict[str, torch.Tensor]) -> str:
    sha = hashlib.sha256(header.encode("utf-8"))
    for name in sorted(tensors):
        tensor = tensors[name].detach().cpu().contiguous()
        sha.update(name.encode("utf-8"))
        sha.update(str(tuple(tensor.shape)).encode("ascii"))
        sha.update(tensor.numpy().tobytes())
    return sha.hexdigest()


def save_checkpoint(path: str | Path, checkpoint: Checkpoint) -> Path:
    """Write ``checkpoint`` to ``path`` (parent folders are created)."""
    header = json.dumps(
        {
            "format_version": FORMAT_VERSION,
            "model": {"name": checkpoint.model.name, "config": checkpoint.model.config_dict()},
            "features": checkpoint.features.to_dict(),
            "normalizer": checkpoint.normalizer.to_dict(),
            "robot": checkpoint.robot.to_dict(),
            "info": checkpoint.info,
        },
        sort_keys=True,
    )
    tensors = {k: v.detach().cpu().contiguous() for k, v in checkpoint.model.state_dict().items()}
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_file(
        tensors, str(out), metadata={HEADER_KEY: header, DIGEST_KEY: _digest(header, tensors)}
    )
    return out


def load_checkpoint(
    path: str | Path,
    robot: RobotDescription | None = None,
    features: FeatureSpec | None = None,
) -> Checkpoint:
    """Load and verify a checkpoint.

    Args:
        path: the ``.safetensors`` file.
        robot: when given, the checkpoint's joint order and position ranges must equal it.
        features: when given, the checkpoint's feature specification must equal it.

    Raises:
        CheckpointError: the file is unreadable, was modified after saving, has another format
            version, or does not match ``robot`` / ``features`` (the message lists what differs).

    """
    file = Path(path)
    header, header_text, digest = read_metadata(file)
    try:
        tensors = load_file(str(file))
    except (SafetensorError, OSError, ValueError) as exc:
        raise CheckpointError(f"{file}: unreadable tensors ({exc})") from None
    if _digest(header_text, tensors) != digest:
        raise CheckpointError(
            f"{file}: checksum mismatch, the file was modified after it was saved; retrain or "
            "restore the original file"
        )

    try:
        stored_robot = RobotDescription.from_dict(header["robot"], source=str(file))
        stored_features = FeatureSpec.from_dict(header["features"])
        normalizer = FeatureNormalizer.from_dict(header["normalizer"])
        model = build_model(header["model"]["name"], header["model"]["config"])
        model.load_state_dict(tensors)
    except (ValueError, RuntimeError, KeyError, TypeError) as exc:
        raise CheckpointError(f"{file}: inconsistent checkpoint ({exc})") from None
    model_dims = model.config_dict()
    if model_dims.get("n_joints") != stored_robot.n_joints or (
        model_dims.get("n_features") != stored_features.dim
    ):
        raise CheckpointError(
            f"{file}: model maps {model_dims.get('n_features')} features to "
            f"{model_dims.get('n_joints')} joints, but the header describes "
            f"{stored_features.dim} features and {stored_robot.n_joints} joints"
        )
    if robot is not None:
        differences = robot.differences(stored_robot)
        if differences:
            raise CheckpointError(
                f"{file}: made for other joints than the configured robot: "
                + "; ".join(differences)
            )
    if features is not None and stored_features != features:
        changed = [
            f"{key}={value!r} (configured {features.to_dict()[key]!r})"
            for key, value in stored_features.to_dict().items()
            if features.to_dict().get(key) != value
        ]
        raise CheckpointError(f"{file}: made for other audio features: " + ", ".join(changed))
    model.eval()
    return Checkpoint(
        model=model,
        features=stored_features,
        normalizer=normalizer,
        robot=stored_robot,
        info=header.get("info", {}),
    )
