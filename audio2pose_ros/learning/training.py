"""Training of pose models: staged losses, early stopping, learning-rate decay, resumable runs.

Seed 003 sections 3.3.3 and 4.3.3: models regress joint angles normalised to [0, 1] (eq. 3.14)
with the mean squared error (the loss L of eq. 3.15), optimised with Adam, and training stops when
the validation loss has not improved for 10 consecutive epochs; the best epoch's weights are
kept. Seed 002 section 4: RMSprop at 1e-3 with patience 5; on a plateau the best weights are
reloaded and the learning rate divided by 10, down to 1e-5. Each model brings its
:class:`~audio2pose_ros.models.base.TrainingRecipe` and its :class:`FitStage` s (losses that are
not plain MSE, pretraining stages). Runs are seeded, and with a state path they save their
state after every epoch (weights, best weights, optimiser, random generators, schedule) as
safetensors + JSON, so an interrupted run resumes exactly where it stopped.

Data sets (:mod:`audio2pose_ros.data.dataset`) become :class:`Utterance` s with
:func:`prepare_training_data`; :func:`train_from_dataset` is the whole ``audio2pose train``.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from tqdm import tqdm

from audio2pose_ros.audio.features import (
    FeatureSpec,
    extract_features,
)
from audio2pose_ros.audio.normalize import (
    FeatureNormalizer,
)
from audio2pose_ros.checkpoints.format import MAX_HEADER_BYTES, MAX_JSON_DEPTH, json_depth
from audio2pose_ros.checkpoints.torch_io import Checkpoint, load_checkpoint, save_checkpoint
from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.errors import InputError
from audio2pose_ros.models.base import (
    FitStage,
    PoseModel,
    masked_mse,
)
from audio2pose_ros.models.registry import (
    build_model,
)
from audio2pose_ros.robot.description import RobotDescription

STATE_SUFFIX = ".train-state.safetensors"
_STATE_KEY = "audio2pose_train_state"
HOLDOUTS = ("clip", "speaker")


class TrainingError(InputError):
    """Training cannot start or resume: empty splits, unknown speaker, mismatched state."""


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


@dataclass
class StageReport:
    """Outcome of one training stage."""

    name: str
    epochs: int = 0
    best_epoch: int = -1
    best_val_loss: float = math.inf
    learning_rate: float = 0.0


@dataclass
class TrainReport:
    """What happened during training; best_* refer to the last stage."""

    train_loss: list[float] = field(default_factory=list)
    val_loss: list[float] = field(default_factory=list)
    best_epoch: int = -1
    best_val_loss: float = math.inf
    stages: list[StageReport] = field(default_factory=list)


def _windows(
    utterances: Sequence[Utterance], length: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Cut utterances into non-overlapping windows (last one right-aligned, short ones padded)."""
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


def _utterance_tensors(utt: Utterance) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return (
        torch.tensor(utt.features[None], dtype=torch.float32),
        torch.tensor(utt.targets[None], dtype=torch.float32),
        torch.tensor(utt.mask[None]),
    )


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
            features, targets, mask = _utterance_tensors(utt)
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


@dataclass
class _Progress:
    """Where a run stands: saved in the training state after every epoch."""

    stage: int = 0
    epoch: int = 0  # next epoch of the current stage
    learning_rate: float = 0.0
    since_best: int = 0
    report: TrainReport = field(default_factory=TrainReport)


def _state_tensors(
    model: PoseModel,
    best_state: dict[str, torch.Tensor],
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    tensors = {f"model.{k}": v for k, v in model.state_dict().items()}
    tensors |= {f"best.{k}": v for k, v in best_state.items()}
    optim = optimizer.state_dict()
    scalars: dict[str, dict[str, Any]] = {}
    for index, values in optim["state"].items():
        for key, value in values.items():
            if isinstance(value, torch.Tensor):
                tensors[f"optim.{index}.{key}"] = value
            else:
                scalars.setdefault(str(index), {})[key] = value
    tensors["rng.torch"] = torch.get_rng_state()
    tensors["rng.batches"] = generator.get_state()
    return tensors, {"param_groups": optim["param_groups"], "scalars": scalars}


def _save_state(
    path: Path,
    model: PoseModel,
    best_state: dict[str, torch.Tensor],
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
    progress: _Progress,
) -> None:
    tensors, optim_meta = _state_tensors(model, best_state, optimizer, generator)
    meta = {
        "model": {"name": model.name, "config": model.config_dict()},
        "progress": {
            "stage": progress.stage,
            "epoch": progress.epoch,
            "learning_rate": progress.learning_rate,
            "since_best": progress.since_best,
        },
        "report": asdict(progress.report),
        "optimizer": optim_meta,
    }
    tmp = path.with_name(path.name + ".tmp")
    contiguous = {k: v.detach().cpu().contiguous() for k, v in tensors.items()}
    save_file(contiguous, str(tmp), metadata={_STATE_KEY: json.dumps(meta)})
    tmp.replace(path)


def _read_state_metadata(path: Path) -> dict[str, Any]:
    """The JSON metadata of a training state, size and depth checked before parsing."""
    with path.open("rb") as stream:
        size = int.from_bytes(stream.read(8), "little")
        if not 2 <= size <= min(MAX_HEADER_BYTES, path.stat().st_size - 8):
            raise TrainingError(f"{path}: not a training state (header length {size})")
        text = stream.read(size).decode("utf-8")
    if json_depth(text) > MAX_JSON_DEPTH:
        raise TrainingError(f"{path}: training state header nests too deeply")
    metadata = json.loads(text)["__metadata__"][_STATE_KEY]
    if json_depth(metadata) > MAX_JSON_DEPTH:
        raise TrainingError(f"{path}: training state metadata nests too deeply")
    meta = json.loads(metadata)
    if not isinstance(meta, dict):
        raise TrainingError(f"{path}: training state metadata is not a JSON object")
    return meta


def _load_state(
    path: Path, model: PoseModel
) -> tuple[dict[str, torch.Tensor], dict[str, Any], _Progress]:
    try:
        meta = _read_state_metadata(path)
        tensors = load_file(str(path))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as exc:
        # TypeError: a JSON value of another type where an object is meant
        raise TrainingError(f"{path}: unreadable training state ({exc})") from None
    except SafetensorError as exc:
        raise TrainingError(f"{path}: unreadable training state ({exc})") from None
    try:
        return _restore_state(path, model, tensors, meta)
    except (KeyError, TypeError, AttributeError, RuntimeError) as exc:
        # the metadata or tensors do not have the structure _save_state writes (RuntimeError:
        # load_state_dict's shape mismatch)
        raise TrainingError(f"{path}: malformed training state ({exc!r:.200})") from None


def _restore_state(
    path: Path, model: PoseModel, tensors: dict[str, torch.Tensor], meta: dict[str, Any]
) -> tuple[dict[str, torch.Tensor], dict[str, Any], _Progress]:
    """Load a read training state into ``model``; refuse one of another model."""
    stored = meta["model"]
    if stored["name"] != model.name or stored["config"] != model.config_dict():
        raise TrainingError(
            f"{path}: training state of model {stored['name']} {stored['config']}, not of "
            f"{model.name} {model.config_dict()}; delete it or train without --resume"
        )
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    report_data = meta["report"]
    report = TrainReport(
        train_loss=report_data["train_loss"],
        val_loss=report_data["val_loss"],
        best_epoch=report_data["best_epoch"],
        best_val_loss=report_data["best_val_loss"],
        stages=[StageReport(**s) for s in report_data["stages"]],
    )
    progress = _Progress(report=report, **meta["progress"])
    return tensors, meta["optimizer"], progress


def _restore_optimizer(
    optimizer: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], meta: dict[str, Any]
) -> None:
    state: dict[int, dict[str, Any]] = {}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, index, name = key.split(".", 2)
            state.setdefault(int(index), {})[name] = value
    for index, values in meta["scalars"].items():
        state.setdefault(int(index), {}).update(values)
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


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
        loss.backward()
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
    data = _windows(train, settings.window_frames)
    stages = model.fit_stages()

    saved: tuple[dict[str, torch.Tensor], dict[str, Any]] | None = None
    progress = _Progress()
    if resume and state_path is not None and state_path.exists():
        tensors, optim_meta, progress = _load_state(state_path, model)
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
            _restore_optimizer(optimizer, tensors, optim_meta)
            best_state = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
            stage_report = report.stages[-1]
        else:
            progress = _Progress(stage_index, 0, initial_lr, 0, report)
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
                _save_state(state_path, model, best_state, optimizer, generator, progress)
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


def clip_utterance(
    clip: Clip, spec: FeatureSpec, normalizer: FeatureNormalizer, robot: RobotDescription
) -> Utterance:
    """Features, targets in [0, 1] (eq. 3.14, clamped to the limits) and mask of one clip.

    Features and motion are cut to the shorter of the two; unknown angles become 0.5 (masked).
    """
    features = normalizer.apply(extract_features(clip.audio, spec))
    n = min(features.shape[0], clip.n_frames)
    known = clip.mask[:n]
    targets = np.where(
        known, np.clip(robot.normalize(np.nan_to_num(clip.angles_rad[:n])), 0, 1), 0.5
    )
    return Utterance(clip.info.clip_id, features[:n], targets, known.copy())


@dataclass
class TrainingData:
    """Utterances of both splits and the feature normaliser fitted on the training clips."""

    train: list[Utterance]
    validation: list[Utterance]
    normalizer: FeatureNormalizer
    speakers: list[str]


def _hold_out(
    clips: list[Clip], fraction: float, holdout: str, seed: int
) -> tuple[list[Clip], list[Clip]]:
    """Split training clips into train and validation, by clip or by whole speakers."""
    rng = np.random.default_rng(seed)
    if holdout == "speaker":
        speakers = sorted({c.info.speaker for c in clips})
        if len(speakers) < 2:
            raise TrainingError("holding out by speaker needs training clips of two speakers")
        count = min(len(speakers) - 1, max(1, round(fraction * len(speakers))))
        held = set(rng.permutation(speakers)[:count].tolist())
        return [c for c in clips if c.info.speaker not in held], [
            c for c in clips if c.info.speaker in held
        ]
    if len(clips) < 2:
        raise TrainingError("need two training clips to hold one out for validation")
    count = min(len(clips) - 1, max(1, round(fraction * len(clips))))
    held_idx = set(rng.permutation(len(clips))[:count].tolist())
    return [c for i, c in enumerate(clips) if i not in held_idx], [
        c for i, c in enumerate(clips) if i in held_idx
    ]


def prepare_training_data(
    dataset: Dataset,
    robot: RobotDescription,
    spec: FeatureSpec,
    speaker: str | None = None,
    validation_fraction: float = 0.2,
    holdout: str = "clip",
    seed: int = 0,
) -> TrainingData:
    """Read the training and validation utterances of a data set.

    Validation is the data set's 'validation' split (of ``speaker`` if given); without one, a
    ``validation_fraction`` of the training clips is held out, by clip or by speaker
    (subject-independent validation). The normaliser is fitted on the training clips: on one
    speaker's clips when ``speaker`` is given (per-speaker z-normalisation, seed 003 section
    3.2 step 8), else on all speakers together.

    Raises:
        TrainingError: unknown speaker, unknown holdout, or no clips to train on.

    """
    if holdout not in HOLDOUTS:
        raise TrainingError(f"holdout {holdout!r} not in {HOLDOUTS}")
    if speaker is not None and speaker not in dataset.speakers:
        raise TrainingError(f"{dataset.root}: no speaker {speaker!r}; has {dataset.speakers}")

    def of_speaker(split: str) -> list[Clip]:
        return [c for c in dataset.iter_split(split) if speaker in (None, c.info.speaker)]

    train_clips, val_clips = of_speaker("train"), of_speaker("validation")
    if not train_clips:
        raise TrainingError(
            f"{dataset.root}: no training clips" + (f" of {speaker}" * bool(speaker))
        )
    if not val_clips:
        train_clips, val_clips = _hold_out(train_clips, validation_fraction, holdout, seed)
    return training_data_from_clips(train_clips, val_clips, robot, spec)


def training_data_from_clips(
    train_clips: Sequence[Clip],
    val_clips: Sequence[Clip],
    robot: RobotDescription,
    spec: FeatureSpec,
) -> TrainingData:
    """Utterances of given training and validation clips, normalised by the training clips."""
    normalizer = FeatureNormalizer.fit(
        np.concatenate([extract_features(c.audio, spec) for c in train_clips])
    )
    return TrainingData(
        train=[clip_utterance(c, spec, normalizer, robot) for c in train_clips],
        validation=[clip_utterance(c, spec, normalizer, robot) for c in val_clips],
        normalizer=normalizer,
        speakers=sorted({c.info.speaker for c in train_clips}),
    )


def train_on_clips(
    model_name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    settings: TrainSettings | None = None,
    config: dict[str, Any] | None = None,
    validation: Sequence[Clip] | None = None,
) -> tuple[Checkpoint, TrainReport]:
    """Train a new model on in-memory clips, validating on held-out speakers (or clips).

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

    Raises:
        TrainingError: fewer than two clips (without ``validation``).

    """
    settings = settings or TrainSettings()
    spec = FeatureSpec()
    torch.manual_seed(settings.seed)
    model = build_model(
        model_name, {"n_features": spec.dim, "n_joints": robot.n_joints, **(config or {})}
    )
    if validation:
        train_clips, val_clips = list(clips), list(validation)
    else:
        holdout = "speaker" if len({c.info.speaker for c in clips}) >= 2 else "clip"
        train_clips, val_clips = _hold_out(list(clips), 0.2, holdout, settings.seed)
    data = training_data_from_clips(train_clips, val_clips, robot, spec)
    report = train_model(model, data.train, data.validation, settings)
    info = {
        "train_clips": sorted(u.name for u in data.train),
        "validation_clips": sorted(u.name for u in data.validation),
        "speakers": data.speakers,
        "subject": "independent",
        "recipe": asdict(model.recipe),
        "seed": settings.seed,
        "stages": [asdict(s) for s in report.stages],
        "epochs": len(report.val_loss),
        "best_epoch": report.best_epoch,
        "best_validation_loss": report.best_val_loss,
    }
    return Checkpoint(model, spec, data.normalizer, robot, info), report


def state_path_for(output: Path) -> Path:
    """The training state file kept next to a checkpoint: ``<name>.train-state.safetensors``."""
    return output.with_name(output.name.removesuffix(".safetensors") + STATE_SUFFIX)


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
    info = {
        "dataset": str(Path(data_dir).resolve()),
        "train_clips": sorted(u.name for u in data.train),
        "validation_clips": sorted(u.name for u in data.validation),
        "speakers": data.speakers,
        "subject": "dependent" if speaker else "independent",
        "finetuned_from": str(finetune) if finetune else None,
        "recipe": asdict(model.recipe),
        "seed": settings.seed,
        "stages": [asdict(s) for s in report.stages],
        "epochs": len(report.val_loss),
        "best_epoch": report.best_epoch,
        "best_validation_loss": report.best_val_loss,
    }
    checkpoint = Checkpoint(model, spec, data.normalizer, robot, info)
    save_checkpoint(output, checkpoint)
    return checkpoint, report
