"""Training of pose models: staged losses, early stopping, learning-rate decay, resumable runs.

Seed 003 sections 3.3.3 and 4.3.3: models regress joint angles normalised to [0, 1] (eq. 3.14)
with the mean squared error (the loss L of eq. 3.15), optimised with Adam, and training stops when
the validation loss has not improved for 10 consecutive epochs; the best epoch's weights are
kept. Seed 002 section 4: RMSprop at 1e-3 with patience 5; on a plateau the best weights are
reloaded and the learning rate divided by 10, down to 1e-5. Each model brings its
:class:`~audio2pose_ros.models.base.TrainingRecipe` and its :class:`FitStage` s (losses that are
not plain MSE, pretraining stages). Runs are seeded, and with a state path they save their
state after every epoch (:mod:`~audio2pose_ros.learning.train_state`), so an interrupted run
resumes exactly where it stopped.

Data sets (:mod:`audio2pose_ros.data.dataset`) become utterances with
:func:`~audio2pose_ros.learning.batches.prepare_training_data`; :func:`train_from_dataset` is the
whole ``audio2pose train``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.checkpoints.torch_io import Checkpoint, load_checkpoint, save_checkpoint
from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.learning.batches import (
    TrainingData,
    TrainingError,
    Utterance,
    hold_out,
    prepare_training_data,
    training_data_from_clips,
    utterance_tensors,
    windows,
)
from audio2pose_ros.learning.train_state import (
    Progress,
    StageReport,
    TrainReport,
    load_state,
    restore_optimizer,
    save_state,
    state_path_for,
)
from audio2pose_ros.models.base import FitStage, PoseModel, masked_mse
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.robot.description import RobotDescription


@dataclass(frozen=True)
class TrainSettings:
    """Training settings; None takes the model's recipe (seed 003 or seed 002 section 4).

    Attributes:
        max_epochs: epochs per training stage at most.
        patience: epochs without validation improvement before decay or stop (None: recipe).
        learning_rate: initial learning rate of every stage (None: stage, then recipe).
        window_frames: training windows of 2 s at 100 Hz.
        batch_size: windows per optimiser step.
        seed: seeds weight initialisation order, batching, noise and dropout.
        show_progress: tqdm progress bars on stderr.

    """

    max_epochs: int = 500
    patience: int | None = None
    learning_rate: float | None = None
    window_frames: int = 200
    batch_size: int = 32
    seed: int = 0
    show_progress: bool = True


def evaluate_loss(
    model: PoseModel, utterances: Sequence[Utterance], stage: FitStage | None = None
) -> float:
    """Validation loss over whole utterances, weighted by their known values.

    Args:
        model: the model (put in eval mode).
        utterances: validation utterances.
        stage: its ``validation_loss`` is used; None or unset = masked MSE of ``forward`` in
            range-normalised units (seed 003 eq. 3.15).

    Returns:
        The loss.

    """
    model.eval()
    loss_fn = stage.validation_loss if stage is not None else None
    total, count = 0.0, 0.0
    with torch.no_grad():
        for utt in utterances:
            features, targets, mask = utterance_tensors(utt)
            if loss_fn is None:
                loss = masked_mse(model(features), targets, mask)
            else:
                loss = loss_fn(features, targets, mask)
            weight = float(mask.sum())
            total += float(loss) * weight
            count += weight
    return total / max(count, 1.0)


def _optimizer(name: str, parameters: list[torch.nn.Parameter], lr: float) -> torch.optim.Optimizer:
    if name == "adam":
        return torch.optim.Adam(parameters, lr=lr)
    if name == "rmsprop":
        return torch.optim.RMSprop(parameters, lr=lr)
    raise TrainingError(f"unknown optimizer {name!r}; expected 'adam' or 'rmsprop'")


def _train_epoch(
    model: PoseModel,
    stage: FitStage,
    optimizer: torch.optim.Optimizer,
    data: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    batch_size: int,
    generator: torch.Generator,
) -> float:
    feats, targets, masks = data
    model.train()
    order = torch.randperm(feats.shape[0], generator=generator)
    total = 0.0
    for start in range(0, len(order), batch_size):
        idx = order[start : start + batch_size]
        optimizer.zero_grad()
        loss = stage.loss(feats[idx], targets[idx], masks[idx])
        loss.backward()  # type: ignore[no-untyped-call]  # unannotated in torch
        optimizer.step()
        total += loss.item() * len(idx)
    return total / len(order)


def train_model(
    model: PoseModel,
    train: Sequence[Utterance],
    validation: Sequence[Utterance],
    settings: TrainSettings | None = None,
    state_path: Path | None = None,
    resume: bool = False,
) -> TrainReport:
    """Fit ``model`` in place, stage by stage; on return it holds each stage's best weights.

    Args:
        model: the model to train (already initialised; seed torch before building it).
        train: training utterances, cut into windows of ``settings.window_frames``.
        validation: whole validation utterances for early stopping.
        settings: training settings (default :class:`TrainSettings`).
        state_path: save the training state here after every epoch.
        resume: continue from ``state_path`` if it exists.

    Raises:
        TrainingError: either split is empty, or a state file belongs to another model.

    """
    settings = settings or TrainSettings()
    if not train or not validation:
        raise TrainingError("training needs at least one training and one validation utterance")
    recipe = model.recipe
    patience = settings.patience if settings.patience is not None else recipe.patience
    torch.manual_seed(settings.seed)
    generator = torch.Generator().manual_seed(settings.seed)
    data = windows(train, settings.window_frames)
    stages = model.fit_stages()

    saved: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None
    progress = Progress()
    if resume and state_path is not None and state_path.exists():
        tensors, optim_meta, progress = load_state(state_path, model)
        if progress.stage > len(stages):
            raise TrainingError(
                f"{state_path}: training state at stage {progress.stage} of a model with "
                f"{len(stages)}; delete it or train without --resume"
            )
        saved = (tensors, optim_meta)
        torch.set_rng_state(tensors["rng.torch"])
        generator.set_state(tensors["rng.batches"])

    report = progress.report
    for stage_index in range(progress.stage, len(stages)):
        stage = stages[stage_index]
        initial_lr = settings.learning_rate or stage.learning_rate or recipe.learning_rate
        optimizer = _optimizer(recipe.optimizer, list(stage.parameters()), initial_lr)
        best_state = copy.deepcopy(model.state_dict())
        if saved is not None and progress.epoch > 0:  # resume inside this stage
            tensors, optim_meta = saved
            restore_optimizer(optimizer, tensors, optim_meta)
            best_state = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
            stage_report = report.stages[-1]
        else:
            progress = Progress(stage_index, 0, initial_lr, 0, report)
            stage_report = StageReport(stage.name, learning_rate=initial_lr)
            report.stages.append(stage_report)
        saved = None
        epochs = tqdm(
            range(progress.epoch, settings.max_epochs),
            desc=f"train {model.name}/{stage.name}",
            unit="epoch",
            disable=not settings.show_progress,
            mininterval=1.0,
        )
        for epoch in epochs:
            report.train_loss.append(
                _train_epoch(model, stage, optimizer, data, settings.batch_size, generator)
            )
            report.val_loss.append(evaluate_loss(model, validation, stage))
            stage_report.epochs = epoch + 1
            if report.val_loss[-1] < stage_report.best_val_loss:
                stage_report.best_val_loss, stage_report.best_epoch = report.val_loss[-1], epoch
                best_state = copy.deepcopy(model.state_dict())
                progress.since_best = 0
            else:
                progress.since_best += 1
            epochs.set_postfix(
                train=f"{report.train_loss[-1]:.4f}",
                val=f"{report.val_loss[-1]:.4f}",
                lr=f"{progress.learning_rate:.0e}",
                refresh=False,
            )
            stop = False
            if progress.since_best >= patience:
                decayed = progress.learning_rate * recipe.lr_decay
                if decayed >= recipe.min_learning_rate * (1 - 1e-9):
                    model.load_state_dict(best_state)  # seed 002 section 4: reload the best
                    progress.learning_rate = decayed
                    for group in optimizer.param_groups:
                        group["lr"] = decayed
                    progress.since_best = 0
                else:
                    stop = True
            stage_report.learning_rate = progress.learning_rate
            progress.epoch = epoch + 1
            if stop:  # the next run starts with the next stage, from this one's best weights
                model.load_state_dict(best_state)
                progress.stage, progress.epoch = stage_index + 1, 0
            if state_path is not None:
                save_state(state_path, model, best_state, optimizer, generator, progress)
            if stop:
                break
        epochs.close()
        model.load_state_dict(best_state)
        report.best_epoch, report.best_val_loss = (
            stage_report.best_epoch,
            stage_report.best_val_loss,
        )
    model.eval()
    return report


def training_info(
    model: PoseModel,
    data: TrainingData,
    settings: TrainSettings,
    report: TrainReport,
    **extra: object,
) -> dict[str, Any]:
    """What a trained checkpoint records about its training (its ``info`` header section).

    ``extra`` adds the caller's own entries first (the data set, subject, fine-tuning source).
    """
    return {
        **extra,
        "train_clips": sorted(u.name for u in data.train),
        "validation_clips": sorted(u.name for u in data.validation),
        "speakers": data.speakers,
        "recipe": asdict(model.recipe),
        "seed": settings.seed,
        "stages": [asdict(stage) for stage in report.stages],
        "epochs": len(report.val_loss),
        "best_epoch": report.best_epoch,
        "best_validation_loss": report.best_val_loss,
    }


def lineage(start: Checkpoint) -> dict[str, Any]:
    """What a checkpoint trained from ``start`` records of it (its ``started_from`` entry).

    The speakers ``start`` learned from, and its own ``started_from`` in turn, so that the
    speakers behind a chain of pretraining and fine-tuning stay known: a fold of the default
    model's rebuild must not start from weights that saw the source it is scored on
    (:func:`~audio2pose_ros.learning.source_holdout.learned_sources`).
    """
    return {k: start.info[k] for k in ("speakers", "started_from") if k in start.info}


def train_on_clips(
    model_name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    settings: TrainSettings | None = None,
    config: dict[str, Any] | None = None,
    validation: Sequence[Clip] | None = None,
    start: Checkpoint | None = None,
) -> tuple[Checkpoint, TrainReport]:
    """Train a model on in-memory clips, validating on held-out speakers (or clips).

    Used by the leave-one-speaker-out evaluation (:mod:`audio2pose_ros.learning.evaluation`) and the
    default model's rebuild: a fifth of the speakers (at least one) is held out for early
    stopping when there are two or more, else a fifth of the clips; or the given validation
    clips.

    Args:
        model_name: registry name.
        clips: the training clips (any split label).
        robot: joint order and ranges.
        settings: training settings (no training state is saved).
        config: model config beyond the feature and joint counts.
        validation: clips for early stopping; None = held out from ``clips``.
        start: a trained checkpoint of ``model_name`` to start from (pretraining, e.g. on
            many clips of other speakers), with its features and config; None = new weights.
            Its weights are copied, not changed; the feature normaliser is fitted anew on
            ``clips``, as when fine-tuning (:func:`train_from_dataset`).

    Raises:
        TrainingError: fewer than two clips (without ``validation``), or ``start`` is
            another model family than ``model_name``.

    """
    settings = settings or TrainSettings()
    torch.manual_seed(settings.seed)
    if start is not None:
        if start.model.name != model_name:
            raise TrainingError(f"cannot start {model_name} from a {start.model.name} checkpoint")
        spec, model = start.features, copy.deepcopy(start.model)
    else:
        spec = FeatureSpec()
        model = build_model(
            model_name, {"n_features": spec.dim, "n_joints": robot.n_joints, **(config or {})}
        )
    if validation:
        train_clips, val_clips = list(clips), list(validation)
    else:
        holdout = "speaker" if len({c.info.speaker for c in clips}) >= 2 else "clip"
        train_clips, val_clips = hold_out(list(clips), 0.2, holdout, settings.seed)
    data = training_data_from_clips(train_clips, val_clips, robot, spec)
    report = train_model(model, data.train, data.validation, settings)
    extra: dict[str, Any] = {"subject": "independent"}
    if start is not None:
        extra["started_from"] = lineage(start)
    info = training_info(model, data, settings, report, **extra)
    return Checkpoint(model, spec, data.normalizer, robot, info), report


def train_from_dataset(
    data_dir: Path,
    output: Path,
    robot: RobotDescription,
    model_name: str | None = None,
    speaker: str | None = None,
    finetune: Path | None = None,
    settings: TrainSettings | None = None,
    resume: bool = False,
    holdout: str = "clip",
) -> tuple[Checkpoint, TrainReport]:
    """``audio2pose train``: train a model on a data set folder and write its checkpoint.

    Args:
        data_dir: data set folder (:mod:`audio2pose_ros.data.dataset`).
        output: checkpoint to write; the training state goes next to it.
        robot: joint order and ranges (targets are normalised by them).
        model_name: registry name; may be None with ``finetune`` (the checkpoint's model).
        speaker: train on this speaker only (subject-dependent, seed 003); None = all speakers.
        finetune: start from this (subject-independent) checkpoint with its features.
        settings: training settings.
        resume: continue an interrupted run from its training state.
        holdout: without a validation split, hold out clips ('clip') or speakers ('speaker').

    Raises:
        TrainingError: bad arguments or data.

    """
    settings = settings or TrainSettings()
    dataset = Dataset.open(data_dir, robot)
    torch.manual_seed(settings.seed)
    if finetune is not None:
        base = load_checkpoint(finetune, robot=robot)
        if model_name not in (None, base.model.name):
            raise TrainingError(
                f"--model {model_name} differs from the fine-tuned checkpoint's {base.model.name}"
            )
        model, spec = base.model, base.features
    elif model_name is None:
        raise TrainingError("give --model NAME (or --finetune CKPT)")
    else:
        spec = FeatureSpec()
        model = build_model(model_name, {"n_features": spec.dim, "n_joints": robot.n_joints})
    data = prepare_training_data(dataset, robot, spec, speaker, holdout=holdout, seed=settings.seed)
    report = train_model(
        model, data.train, data.validation, settings, state_path_for(output), resume
    )
    info = training_info(
        model,
        data,
        settings,
        report,
        dataset=str(Path(data_dir).resolve()),
        subject="dependent" if speaker else "independent",
        finetuned_from=str(finetune) if finetune else None,
        **({"started_from": lineage(base)} if finetune is not None else {}),
    )
    checkpoint = Checkpoint(model, spec, data.normalizer, robot, info)
    save_checkpoint(output, checkpoint)
    return checkpoint, report
