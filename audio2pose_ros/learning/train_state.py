"""Resumable training: the state saved after every epoch, read back with bounded parsing.

The state (weights, best weights, optimiser, random generators, schedule position and report)
is one safetensors file whose JSON metadata is size- and depth-checked before it is parsed.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from audio2pose_ros.checkpoints.format import MAX_HEADER_BYTES, MAX_JSON_DEPTH, json_depth
from audio2pose_ros.learning.batches import TrainingError
from audio2pose_ros.models.base import PoseModel

STATE_SUFFIX = ".train-state.safetensors"


_STATE_KEY = "audio2pose_train_state"


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


@dataclass
class Progress:
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


def save_state(
    path: Path,
    model: PoseModel,
    best_state: dict[str, torch.Tensor],
    optimizer: torch.optim.Optimizer,
    generator: torch.Generator,
    progress: Progress,
) -> None:
    """Write the state after an epoch: to a temporary file first, then renamed over ``path``."""
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


def load_state(
    path: Path, model: PoseModel
) -> tuple[dict[str, torch.Tensor], dict[str, Any], Progress]:
    """Read a state file written by :func:`save_state`; its header is checked before parsing.

    Raises:
        TrainingError: unreadable, malformed or over-sized state.
    """
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
    except TrainingError as exc:
        message = str(exc)
        raise TrainingError(
            message if message.startswith(str(path)) else f"{path}: {message}"
        ) from None
    except (KeyError, TypeError, AttributeError, RuntimeError) as exc:
        # the metadata or tensors do not have the structure save_state writes (RuntimeError:
        # load_state_dict's shape mismatch)
        raise TrainingError(f"{path}: malformed training state ({exc!r:.200})") from None


def _restore_state(
    path: Path, model: PoseModel, tensors: dict[str, torch.Tensor], meta: dict[str, Any]
) -> tuple[dict[str, torch.Tensor], dict[str, Any], Progress]:
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
        train_loss=_losses(report_data["train_loss"], "report.train_loss"),
        val_loss=_losses(report_data["val_loss"], "report.val_loss"),
        best_epoch=_count(report_data["best_epoch"], "report.best_epoch", low=-1),
        best_val_loss=_loss(report_data["best_val_loss"], "report.best_val_loss"),
        stages=[
            StageReport(
                name=_text(stage["name"], f"report.stages[{i}].name"),
                epochs=_count(stage["epochs"], f"report.stages[{i}].epochs"),
                best_epoch=_count(stage["best_epoch"], f"report.stages[{i}].best_epoch", low=-1),
                best_val_loss=_loss(stage["best_val_loss"], f"report.stages[{i}].best_val_loss"),
                learning_rate=_rate(stage["learning_rate"], f"report.stages[{i}].learning_rate"),
            )
            for i, stage in enumerate(report_data["stages"])
        ],
    )
    saved = meta["progress"]
    progress = Progress(
        stage=_count(saved["stage"], "progress.stage"),
        epoch=_count(saved["epoch"], "progress.epoch"),
        learning_rate=_rate(saved["learning_rate"], "progress.learning_rate"),
        since_best=_count(saved["since_best"], "progress.since_best"),
        report=report,
    )
    if progress.epoch > 0 and not report.stages:
        raise TrainingError(f"{path}: malformed training state (an epoch into no stage)")
    return tensors, meta["optimizer"], progress


def _count(value: object, name: str, low: int = 0) -> int:
    """An integer of the state's metadata, at least ``low``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise TrainingError(f"malformed training state: {name} must be an integer >= {low}")
    return value


def _loss(value: object, name: str) -> float:
    """A loss: a number, not NaN (infinity is the loss before any epoch)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise TrainingError(f"malformed training state: {name} must be a number")
    return float(value)


def _losses(values: object, name: str) -> list[float]:
    """A list of losses."""
    if not isinstance(values, list):
        raise TrainingError(f"malformed training state: {name} must be a list")
    return [_loss(v, f"{name}[{i}]") for i, v in enumerate(values)]


def _rate(value: object, name: str) -> float:
    """A learning rate: finite and >= 0."""
    number = _loss(value, name)
    if not (math.isfinite(number) and number >= 0.0):
        raise TrainingError(f"malformed training state: {name} must be finite and >= 0")
    return number


def _text(value: object, name: str) -> str:
    """A name of the state's metadata."""
    if not isinstance(value, str):
        raise TrainingError(f"malformed training state: {name} must be text")
    return value


def restore_optimizer(
    optimizer: torch.optim.Optimizer, tensors: dict[str, torch.Tensor], meta: dict[str, Any]
) -> None:
    """Give ``optimizer`` the per-parameter state and groups saved by :func:`save_state`."""
    state: dict[int, dict[str, Any]] = {}
    for key, value in tensors.items():
        if key.startswith("optim."):
            _, index, name = key.split(".", 2)
            state.setdefault(int(index), {})[name] = value
    for index, values in meta["scalars"].items():
        state.setdefault(int(index), {}).update(values)
    optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})


def state_path_for(output: Path) -> Path:
    """The training state file kept next to a checkpoint: ``<name>.train-state.safetensors``."""
    return output.with_name(output.name.removesuffix(".safetensors") + STATE_SUFFIX)
