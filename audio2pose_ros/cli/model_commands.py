"""``audio2pose train`` and ``audio2pose evaluate``: training and comparing pose models.

:func:`register` adds both verbs to the main parser. Each handler is a function
``command_<verb>(args) -> int``; the library raises typed errors
(:class:`~audio2pose_ros.errors.Audio2PoseError`), which the main entry point reports as one
line.

Registering the verbs imports no torch (the runner and the nodes must start without it): the
model families and hold-out kinds the options accept live in torch modules, so they are
:class:`LazyChoices`, read the first time an option's value is checked or its help is shown.
``audio2pose run`` and every other verb that builds the same parser stay free of torch.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from functools import cached_property
from pathlib import Path

from audio2pose_ros.cli.options import (
    MAX_SEED,
    Verbs,
    add_force,
    bounded_int,
    input_dir,
    input_file,
    output_file,
)
from audio2pose_ros.errors import UsageError


class LazyChoices(Sequence[str]):
    """The ``choices`` of an argparse option, computed only when argparse first looks at them.

    argparse reads ``choices`` to check a value (``in``), to word an error and to expand
    ``%(choices)s`` in help; an option with ``metavar`` set never reads them while the parser is
    built. So the torch modules that define the names are imported only by a command that uses
    the option.
    """

    def __init__(self, load: Callable[[], Iterable[str]]) -> None:
        """``load()`` returns the accepted names, in the order help should show them."""
        self._load = load

    @cached_property
    def names(self) -> tuple[str, ...]:
        """The accepted names (loaded on first use)."""
        return tuple(self._load())

    def __getitem__(self, index: int) -> str:  # type: ignore[override]
        """The ``index``-th name."""
        return self.names[index]

    def __len__(self) -> int:
        """How many names there are."""
        return len(self.names)

    def __iter__(self) -> Iterator[str]:
        """The names in order."""
        return iter(self.names)

    def __contains__(self, value: object) -> bool:
        """Whether ``value`` is one of the names."""
        return value in self.names


def _model_names() -> list[str]:
    return sorted(importlib.import_module("audio2pose_ros.models.registry").MODEL_REGISTRY)


def _holdout_kinds() -> tuple[str, ...]:
    return importlib.import_module("audio2pose_ros.learning.batches").HOLDOUTS


MODEL_NAMES = LazyChoices(_model_names)  # the registered model families (torch)
HOLDOUT_KINDS = LazyChoices(_holdout_kinds)  # what training may hold out (torch)


def command_train(args: argparse.Namespace) -> int:
    """Train a model on a data set folder and write its checkpoint."""
    from audio2pose_ros.learning.training import TrainSettings, train_from_dataset
    from audio2pose_ros.robot.description import load_robot

    data = input_dir(args.data, "data set folder")
    if args.finetune:
        input_file(args.finetune, "checkpoint")
    # --resume continues the training that writes this output: it is replaced by design
    output_file(args.output, "-o", inputs=(args.finetune,), force=args.force or args.resume)
    settings = TrainSettings(max_epochs=args.max_epochs, seed=args.seed)
    checkpoint, report = train_from_dataset(
        data,
        Path(args.output),
        load_robot(),
        model_name=args.model,
        speaker=args.speaker,
        finetune=Path(args.finetune) if args.finetune else None,
        settings=settings,
        resume=args.resume,
        holdout=args.holdout,
    )
    for stage in report.stages:
        print(
            f"{stage.name}: {stage.epochs} epochs, best epoch {stage.best_epoch}, "
            f"validation loss {stage.best_val_loss:.5f}, "
            f"final learning rate {stage.learning_rate:.0e}"
        )
    print(
        f"wrote {args.output} ({checkpoint.model.name}, {len(checkpoint.info['train_clips'])} "
        f"training clips, subject-{checkpoint.info['subject']})"
    )
    return 0


def command_evaluate(args: argparse.Namespace) -> int:
    """Evaluate checkpoints and baselines on a split, or model families leave-one-speaker-out.

    With checkpoints: seed 003's table on the split, then the per-group distribution table on
    the same clips. With ``--loso``: each named family is trained once per speaker on the
    others and measured on the held-out speaker; the per-group table covers every clip.
    ``--out`` gets metrics.txt, distributions.png (and one PNG per clip with checkpoints).
    """
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.data.dataset import Dataset
    from audio2pose_ros.learning.evaluation import (
        checkpoint_predictions,
        evaluate,
        loso_predictions,
    )
    from audio2pose_ros.learning.quality import quality_evaluation
    from audio2pose_ros.robot.description import load_robot

    if not args.checkpoints and not args.loso:
        raise UsageError("evaluate: give checkpoints, or --loso MODEL... (or both)")
    robot = load_robot()
    dataset = Dataset.open(input_dir(args.data, "data set folder"), robot)
    checkpoints = [(Path(p), load_checkpoint(p, robot=robot)) for p in args.checkpoints]
    out_dir = Path(args.out) if args.out else None

    def progress(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    tables, figures = [], 0
    if checkpoints:
        result = evaluate(
            checkpoints,
            dataset,
            robot,
            split=args.split,
            out_dir=out_dir,
            n_samples=args.samples,
            seed=args.seed,
            progress=lambda clip: progress(f"evaluating {clip} ..."),
        )
        tables.append(result.table())
        figures += len(result.figures)
        clips = list(dataset.iter_split(args.split))
        predictions, paused = checkpoint_predictions(checkpoints, clips, args.samples, args.seed)
    else:
        clips, predictions, paused = [], {}, {}
    if args.loso:
        from audio2pose_ros.learning.default_model import LearnedBuildSettings
        from audio2pose_ros.learning.sampling_folds import FoldTuner

        # the default model's evaluation, fold for fold
        settings = LearnedBuildSettings().train_settings(args.max_epochs, seed=args.seed)
        tune = FoldTuner(robot, settings, verbose=True)  # live_groups: as the default model's card
        clips, predictions, paused = loso_predictions(
            dataset, robot, args.loso, settings, args.samples, progress, tune, args.jobs
        )
        tables.append("leave one speaker out: every clip held out once, in its speaker's fold")
    figure = out_dir / "distributions.png" if out_dir is not None else None
    quality = quality_evaluation(clips, predictions, robot, figure, seed=args.seed, paused=paused)
    tables.append(quality.table())
    text = "\n\n".join(tables)
    print(text)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "metrics.txt").write_text(text + "\n", encoding="utf-8")
        print(f"wrote {figures + 1} figures and metrics.txt to {out_dir}")
    return 0


def register(verbs: Verbs) -> None:
    """Add the ``train`` and ``evaluate`` sub-commands to the ``audio2pose`` parser (no torch)."""
    train = verbs.add_parser("train", help="train a pose model on a data set folder")
    train.add_argument(
        "--model", choices=MODEL_NAMES, metavar="MODEL", help="model family: %(choices)s"
    )
    train.add_argument("--data", required=True, metavar="DIR", help="data set folder")
    train.add_argument("-o", "--output", required=True, metavar="CKPT.safetensors")
    add_force(train)
    train.add_argument("--speaker", help="train on this speaker only (subject-dependent)")
    train.add_argument("--finetune", metavar="CKPT", help="start from this checkpoint")
    train.add_argument(
        "--max-epochs",
        type=bounded_int(1, 100_000),
        default=500,
        help="per stage, 1 to 100000 (default 500)",
    )
    train.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0)
    train.add_argument(
        "--resume", action="store_true", help="continue from the training state next to -o"
    )
    train.add_argument(
        "--holdout",
        choices=HOLDOUT_KINDS,
        default="clip",
        metavar="HOLDOUT",
        help="without a validation split, hold out %(choices)s (default: clip)",
    )
    train.set_defaults(func=command_train)

    evaluate = verbs.add_parser("evaluate", help="compare checkpoints and baselines")
    evaluate.add_argument("checkpoints", nargs="*", metavar="CKPT")
    evaluate.add_argument("--data", required=True, metavar="DIR", help="data set folder")
    evaluate.add_argument("--split", default="test", choices=("train", "validation", "test"))
    evaluate.add_argument("--out", metavar="DIR", help="write one PNG per clip and the table")
    evaluate.add_argument(
        "--samples", type=bounded_int(2, 100), default=3, help="samples for diversity, 2 to 100"
    )
    evaluate.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0)
    evaluate.add_argument(
        "--loso",
        nargs="+",
        choices=MODEL_NAMES,
        metavar="MODEL",
        help="train these families leave-one-speaker-out and measure them on held-out speakers",
    )
    evaluate.add_argument(
        "--max-epochs",
        type=bounded_int(1, 100_000),
        default=200,
        help="with --loso: epochs per fold at most (default 200, as make default-model)",
    )
    evaluate.add_argument(
        "--jobs",
        type=bounded_int(1, 256),
        default=1,
        help="with --loso: folds trained side by side, one process each (default 1)",
    )
    evaluate.set_defaults(func=command_evaluate)
