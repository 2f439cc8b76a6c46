"""Training loop for pose models: masked MSE on range-normalised angles, early stopping.

Seed 003 section 3.3.3 / 4.3.3: the models regress joint angles normalised to [0, 1]
(eq. 3.14) with the mean squared error (the loss L of eq. 3.15), optimised with Adam, and training
stops when the validation loss has not improved for 10 consecutive epochs. The best epoch's
weights are kept.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from audio2pose_ros.models import PoseModel


@dataclass(frozen=True)
class Utterance:
    """One training clip, frame-aligned at the feature rate.

    Attributes:
        name: clip identifier (used for utterance-level splits).
        features: (T, n_features) z-normalised audio features.
        targets: (T, n_joints) joint angles normalised to [0, 1].
        mask: (T, n_joints) True where the target is known.

    """

    name: str
    features: np.ndarray
    targets: np.ndarray
    mask: np.ndarray

    def __post_init__(self) -> None:
        """Check that the arrays are frame-aligned."""
        n = self.features.shape[0]
        if self.targets.shape[0] != n or self.mask.shape != self.targets.shape:
            raise ValueError(
                f"utterance {self.name}: features {self.features.shape}, targets "
                f"{self.targets.shape} and mask {self.mask.shape} are not frame-aligned"
            )


@dataclass(frozen=True)
class TrainSettings:
    """Training hyper-parameters (defaults follow seed 003 section 4.3.3 where it gives them)."""

    max_epochs: int = 500
    patience: int = 10  # seed 003: stop after 10 epochs without validation improvement
    learning_rate: float = 1e-3  # Adam
    window_frames: int = 200  # training windows of 2 s at 100 Hz
    batch_size: int = 32  # windows per optimiser step
    seed: int = 0
    show_progress: bool = True


@dataclass
class TrainReport:
    """What happened during training."""

    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best_epoch: int = -1
    best_val_loss: float = math.inf


def _windows(
    utterances: Sequence[Utterance], length: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Cut utterances into non-overlapping windows (the last one right-aligned)."""
    feats, targets, masks = [], [], []
    for utt in utterances:
        n = utt.features.shape[0]
        if n < length:
            pad = length - n
            feats.append(np.pad(utt.features, ((0, pad), (0, 0))))
            targets.append(np.pad(utt.targets, ((0, pad), (0, 0))))
            masks.append(np.pad(utt.mask, ((0, pad), (0, 0))))
            continue
        starts = list(range(0, n - length + 1, length))
        if starts[-1] != n - length:
            starts.append(n - length)
        for s in starts:
            feats.append(utt.features[s : s + length])
            targets.append(utt.targets[s : s + length])
            masks.append(utt.mask[s : s + length])
    return (
        torch.tensor(np.stack(feats), dtype=torch.float32),
        torch.tensor(np.stack(targets), dtype=torch.float32),
        torch.tensor(np.stack(masks), dtype=torch.bool),
    )


def masked_mse(prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over known targets only: the loss L of seed 003 eq. 3.15."""
    weight = mask.to(prediction.dtype)
    return ((prediction - target) ** 2 * weight).sum() / weight.sum().clamp_min(1.0)


def evaluate_loss(model: PoseModel, utterances: Sequence[Utterance]) -> float:
    """Masked MSE of ``model`` over whole utterances, in range-normalised units."""
    model.eval()
    total, count = 0.0, 0.0
    with torch.no_grad():
        for utt in utterances:
            pred = model(torch.tensor(utt.features[None], dtype=torch.float32))[0]
            mask = torch.tensor(utt.mask)
            total += float(
                masked_mse(pred, torch.tensor(utt.targets, dtype=torch.float32), mask) * mask.sum()
            )
            count += float(mask.sum())
    return total / max(count, 1.0)


def train_model(
    model: PoseModel,
    train: Sequence[Utterance],
    validation: Sequence[Utterance],
    settings: TrainSettings | None = None,
) -> TrainReport:
    """Fit ``model`` in place; on return it holds the weights of its best validation epoch.

    Raises:
        ValueError: when either split is empty.

    """
    settings = settings or TrainSettings()
    if not train or not validation:
        raise ValueError("training needs at least one training and one validation utterance")
    torch.manual_seed(settings.seed)
    generator = torch.Generator().manual_seed(settings.seed)
    feats, targets, masks = _windows(train, settings.window_frames)
    optimiser = torch.optim.Adam(model.parameters(), lr=settings.learning_rate)
    report = TrainReport()
    best_state = copy.deepcopy(model.state_dict())
    epochs = tqdm(
        range(settings.max_epochs),
        desc=f"train {model.name}",
        unit="epoch",
        disable=not settings.show_progress,
        mininterval=1.0,
    )
    for epoch in epochs:
        model.train()
        order = torch.randperm(feats.shape[0], generator=generator)
        epoch_loss = 0.0
        for start in range(0, len(order), settings.batch_size):
            idx = order[start : start + settings.batch_size]
            optimiser.zero_grad()
            loss = masked_mse(model(feats[idx]), targets[idx], masks[idx])
            loss.backward()
            optimiser.step()
            epoch_loss += loss.item() * len(idx)
        report.train_loss.append(epoch_loss / len(order))
        report.val_loss.append(evaluate_loss(model, validation))
        if report.val_loss[-1] < report.best_val_loss:
            report.best_val_loss, report.best_epoch = report.val_loss[-1], epoch
            best_state = copy.deepcopy(model.state_dict())
        epochs.set_postfix(
            train=f"{report.train_loss[-1]:.4f}", val=f"{report.val_loss[-1]:.4f}", refresh=False
        )
        if epoch - report.best_epoch >= settings.patience:
            break
    model.load_state_dict(best_state)
    model.eval()
    return report
