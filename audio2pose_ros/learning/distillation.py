"""Train a streaming MLP to imitate the hand-written prosody rule (``audio2pose distill-prosody``).

Audio features are the model's input, the trajectory of
:func:`~audio2pose_ros.motion.prosody.prosody_trajectory` its target. The result moves the robot
in time with the voice, but it has learned a rule written in this repository, not human motion;
the model card it writes says so. It was the first wave's default model; the default is now
learned from people (:mod:`~audio2pose_ros.learning.default_model`), and this remains as a
baseline and as the smallest example of training a streaming model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.checkpoints.torch_io import Checkpoint, save_checkpoint
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.learning.batches import Utterance
from audio2pose_ros.learning.train_state import TrainReport
from audio2pose_ros.learning.training import TrainSettings, train_model
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.motion.prosody import ProsodyRule, prosody_trajectory
from audio2pose_ros.offline.synthesis import synthesize
from audio2pose_ros.robot.description import RobotDescription


def _rmse_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Overall RMSE in degrees (seed 003 eq. 3.12)."""
    return float(np.degrees(np.sqrt(np.mean((a - b) ** 2))))


def distill_prosody(
    wavs: Sequence[Path],
    output: Path,
    robot: RobotDescription,
    validation: Sequence[str] = (),
    spec: FeatureSpec | None = None,
    model_config: MLPConfig | None = None,
    settings: TrainSettings | None = None,
) -> tuple[Checkpoint, TrainReport, dict[str, float]]:
    """Train an MLP on ``wavs`` to reproduce :class:`ProsodyRule` and save it to ``output``.

    Args:
        wavs: speech files (any rate; mono or stereo).
        output: checkpoint path (.safetensors).
        robot: joint order, limits and neutral pose.
        validation: file stems held out for validation (default: the last file).
        spec: input features (default LogFB-26, seed 003's choice).
        model_config: MLP architecture (default: seed 003 Table 4.5 sized for ``spec``).
        settings: training settings.

    Returns:
        The checkpoint, the training report and held-out metrics: RMSE in degrees of the
        smoothed model output against the rule, and of the static neutral pose against the rule.

    """
    spec = spec or FeatureSpec()
    if spec.kind != "logfbank" or spec.delta_order != 0:
        raise ConfigurationError(
            f"the prosody rule reads plain log filter banks (kind 'logfbank', no deltas), not "
            f"{spec.kind} with delta order {spec.delta_order}"
        )
    held_out = set(validation) or {Path(wavs[-1]).stem}
    signals = {Path(w).stem: read_wav(w)[0] for w in wavs}
    raw = {name: extract_features(sig, spec) for name, sig in signals.items()}
    targets = {name: prosody_trajectory(frames, robot) for name, frames in raw.items()}
    normalizer = FeatureNormalizer.fit(np.concatenate(list(raw.values())))
    utterances = {
        name: Utterance(
            name=name,
            features=normalizer.apply(frames),
            targets=robot.normalize(targets[name]),
            mask=np.ones_like(targets[name], dtype=bool),
        )
        for name, frames in raw.items()
    }
    train = [u for n, u in utterances.items() if n not in held_out]
    val = [u for n, u in utterances.items() if n in held_out]

    torch.manual_seed((settings or TrainSettings()).seed)
    config = model_config or MLPConfig(n_features=spec.dim, n_joints=robot.n_joints)
    model = FramewiseMLP(config)
    report = train_model(model, train, val, settings)
    checkpoint = Checkpoint(
        model=model,
        features=spec,
        normalizer=normalizer,
        robot=robot,
        info={
            "trained_on": "prosody rule targets (audio2pose_ros.motion.prosody), not human motion",
            "prosody_rule": asdict(ProsodyRule()),
            "train_clips": sorted(u.name for u in train),
            "validation_clips": sorted(u.name for u in val),
            "best_epoch": report.best_epoch,
            "best_validation_loss": report.best_val_loss,
        },
    )
    save_checkpoint(output, checkpoint)

    metrics = {}
    for name in sorted(held_out):
        _, predicted = synthesize(checkpoint, signals[name])
        metrics[f"{name} model RMSE deg"] = _rmse_deg(predicted, targets[name])
        neutral = np.broadcast_to(robot.neutral_rad, targets[name].shape)
        metrics[f"{name} neutral-pose RMSE deg"] = _rmse_deg(neutral, targets[name])
    return checkpoint, report, metrics


def write_prosody_model_card(
    checkpoint_path: Path,
    checkpoint: Checkpoint,
    report: TrainReport,
    metrics: dict[str, float],
    wavs: Sequence[Path],
) -> Path:
    """Write MODEL_CARD.md beside a checkpoint made by ``audio2pose distill-prosody``."""
    model = checkpoint.model
    n_params = sum(p.numel() for p in model.parameters())
    metric_rows = "\n".join(f"| {k} | {v:.2f} |" for k, v in metrics.items())
    files = " ".join(w.name for w in wavs)
    card = f"""# Model card: `{checkpoint_path.name}`

## What it is
A frame-wise MLP (seed 003 section 4.3.3; config `{model.config_dict()}`, {n_params} parameters)
mapping {checkpoint.features.kind}{checkpoint.features.dim} audio features (seed 003 section
4.2.2 parameters) to Pepper's {checkpoint.robot.n_joints} joints. It streams (no state), so it runs
in `inference_node`.

## What it was trained on (read this)
**It was not trained on human motion.** Its targets are the output of a hand-written rule,
`audio2pose_ros.motion.prosody.ProsodyRule`: loudness raises the forearms and nods the head, the
spectral balance of the voice turns head and hip and makes arm motion asymmetric, smoothed by the
seed's 4 Hz Butterworth filter. The model learned to reproduce that rule from audio features, so
the robot moves in time with the voice, in a repetitive, rule-like way, with no learned gesture.

Audio: {files}. Keep the licences and attribution of these recordings with the model.
Train clips: {", ".join(checkpoint.info.get("train_clips", []))}.
Validation clips: {", ".join(checkpoint.info.get("validation_clips", []))}.
Feature z-normalisation statistics: all given clips.

## Training
Adam, lr 1e-3, masked MSE on range-normalised angles (seed 003 eq. 3.15), early stopping after 10
epochs without validation improvement; best epoch {report.best_epoch}, validation loss L
{report.best_val_loss:.5f}.

## Held-out results (against the rule's own trajectory, after smoothing)
| metric | value |
|---|---|
{metric_rows}

These numbers say how well the model imitates the rule, nothing about how human-like the motion is.

## Limits
Voices, noise and music unlike the training audio are out of distribution. The motion is a
deterministic function of loudness and spectral balance, with none of the variety of real
gesture.

## Rebuild
`audio2pose distill-prosody {files} -o {checkpoint_path.name}` (seeded; CPU, seconds).
"""
    out = checkpoint_path.parent / "MODEL_CARD.md"
    out.write_text(card, encoding="utf-8")
    return out
