"""Model cards written next to checkpoints, so a model states what it was trained on."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.learning.training import TrainReport


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
