"""Self-describing, code-free checkpoints (safetensors).

A checkpoint is one ``.safetensors`` file: the model's tensors plus a JSON header entry holding
everything needed to use it without the training code: format version, model name and config,
feature specification, feature normalisation statistics, the robot description (joint order and
ranges) and free-form training information. Loading never executes code (safetensors holds only
tensors and strings), and a SHA-256 digest over header and tensors detects files changed after
saving. A checkpoint whose joints, ranges or features differ from what the caller expects is
refused with a message that lists the differences.

Loading checks, in this order and before any tensor is read: the container and header structure
and sizes (:func:`~audio2pose_ros.checkpoints.format.read_checkpoint_file`), the digest, the
model config (:func:`~audio2pose_ros.models.registry.build_model`), and that the file holds
exactly the tensors the model has, with its shapes and dtype (the model is first built on
torch's ``meta`` device, which allocates nothing). Weights must be finite; the normalisation
statistics must fit the features.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.format import (
    DIGEST_KEY,
    FORMAT_VERSION,
    HEADER_KEY,
    CheckpointError,
    CheckpointFile,
    check_made_for,
    check_tensor_layout,
    digest_update,
    header_sections,
    load_checked_tensors,
    parse_section,
    read_checkpoint_file,
    verify_digest,
)
from audio2pose_ros.models.base import PoseModel
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.robot.description import RobotDescription

__all__ = ["Checkpoint", "CheckpointError", "load_checkpoint", "save_checkpoint"]


@dataclass
class Checkpoint:
    """A loaded model with everything needed to feed it and interpret its output."""

    model: PoseModel
    features: FeatureSpec
    normalizer: FeatureNormalizer
    robot: RobotDescription
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        """Tell a model that samples with the robot's body in mind which robot it drives."""
        bind = getattr(self.model, "bind_robot", None)
        if bind is not None:
            bind(self.robot)


def _digest(header: str, tensors: dict[str, torch.Tensor]) -> str:
    sha = hashlib.sha256(header.encode("utf-8"))
    for name in sorted(tensors):
        tensor = tensors[name].detach().cpu().contiguous()
        digest_update(sha, name, tuple(tensor.shape), tensor.numpy().tobytes())
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
    file = read_checkpoint_file(path)
    verify_digest(file)
    stored_robot, stored_features, normalizer = header_sections(file)
    model = _model_for(file)
    model_dims = model.config_dict()
    if model_dims.get("n_joints") != stored_robot.n_joints or (
        model_dims.get("n_features") != stored_features.dim
    ):
        raise CheckpointError(
            f"{file.path}: model maps {model_dims.get('n_features')} features to "
            f"{model_dims.get('n_joints')} joints, but the header describes "
            f"{stored_features.dim} features and {stored_robot.n_joints} joints"
        )
    check_made_for(file, stored_robot, stored_features, robot, features)
    model.eval()
    return Checkpoint(
        model=model,
        features=stored_features,
        normalizer=normalizer,
        robot=stored_robot,
        info=file.header.get("info", {}),
    )


def _model_for(file: CheckpointFile) -> PoseModel:
    """Build the header's model and load the file's tensors into it, checking both first.

    The model is first built on the ``meta`` device (no memory) and its state dict compared
    with the file's tensor entries: same names, same shapes, float32 everywhere. Only then is
    it built for real and the tensors read; they must be finite.
    """
    spec = file.header["model"]
    with torch.device("meta"):
        state = parse_section(
            file, "model", lambda m: build_model(m["name"], m["config"])
        ).state_dict()
    not_float32 = [name for name, tensor in state.items() if tensor.dtype != torch.float32]
    if not_float32:
        raise CheckpointError(
            f"{file.path}: model {spec['name']!r} has tensors {not_float32[:5]} that are not "
            "torch.float32, which checkpoints hold"
        )
    check_tensor_layout(
        file, spec["name"], {name: tuple(tensor.shape) for name, tensor in state.items()}
    )
    model = build_model(spec["name"], spec["config"])
    tensors = load_checked_tensors(
        file, load_file, lambda t: t.dtype == torch.float32 and bool(torch.isfinite(t).all())
    )
    model.load_state_dict(tensors, strict=True)
    return model
