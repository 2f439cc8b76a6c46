"""``audio2pose enroll`` and ``evaluate-style``, and the style options of synth, render and run.

``--model`` of these verbs takes a checkpoint or a personal model folder (``enroll``'s output);
``--style PRESET|FILE|DIR`` picks a style (a preset of ``config/styles``, a style file, or a
personal model's), which wins over the folder's own; ``--style-set NAME=VALUE`` sets one of the
motion filter's style parameters after that (e.g. ``arms_gain=0.5``).
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from audio2pose_ros.cli.options import Verbs, bounded_float, new_dir
from audio2pose_ros.errors import ConfigurationError, UsageError

if TYPE_CHECKING:
    from audio2pose_ros.motion.style import StyleSettings
    from audio2pose_ros.robot.description import RobotDescription


def add_style_options(parser: argparse.ArgumentParser) -> None:
    """``--style`` and ``--style-set`` (the model option is the verb's own ``--model``)."""
    parser.add_argument(
        "--style",
        metavar="PRESET|FILE|DIR",
        help="speaking style: a preset (see config/styles), a style file or a personal model",
    )
    parser.add_argument(
        "--style-set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set one style parameter after the style (e.g. arms_gain=0.5); repeatable",
    )


def model_and_style_settings(
    args: argparse.Namespace, robot: RobotDescription
) -> tuple[Path, StyleSettings | None]:
    """The checkpoint and the style settings that ``--model``, ``--style`` and ``--style-set`` mean.

    Returns ``None`` settings when no style is asked for (the model as generated).

    Raises:
        UsageError: a ``--style-set`` that is not NAME=VALUE, or names no style parameter.
        ConfigurationError: a refused value.
        StyleError: an unreadable style or personal model.
    """
    import dataclasses

    from audio2pose_ros.motion.style import STYLE_FIELDS
    from audio2pose_ros.style.figures import load_style
    from audio2pose_ros.style.personal import model_and_style, style_settings

    checkpoint, style = model_and_style(args.model)
    if args.style:
        style = load_style(args.style)
    settings = style_settings(checkpoint, style, robot) if style is not None else None
    changes: dict[str, float] = {}
    for item in args.style_set:
        name, sep, text = item.partition("=")
        if not sep or name not in STYLE_FIELDS:
            raise UsageError(
                f"--style-set {item!r}: expected NAME=VALUE with NAME one of {list(STYLE_FIELDS)}"
            )
        try:
            changes[name] = float(text)
        except ValueError:
            raise ConfigurationError(f"parameter {name}: value {text!r} is not a number") from None
    if changes:
        from audio2pose_ros.motion.style import StyleSettings

        settings = dataclasses.replace(settings or StyleSettings(), **changes)
    return checkpoint, settings


def graph_overrides(args: argparse.Namespace) -> list[str]:
    """The node graph's parameter overrides of ``--model``, ``--style`` and ``--style-set``.

    ``--model`` is a checkpoint or a personal model folder (``run``, ``console``).

    Raises:
        InputError: a missing checkpoint or an unreadable style.
        UsageError: a bad ``--style-set``.
    """
    from audio2pose_ros.cli.options import input_file
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.style.personal import style_overrides

    if not (args.model or args.style or args.style_set):
        return []
    if args.model and not Path(args.model).is_dir():
        input_file(args.model, "checkpoint")
    checkpoint, style = model_and_style_settings(args, load_robot())
    overrides = [f"model_path:={Path(checkpoint).resolve()}"] if args.model else []
    return overrides + (style_overrides(style) if style is not None else [])


def command_enroll(args: argparse.Namespace) -> int:
    """Learn a person's style from a video or data set folder; write a personal model."""
    from audio2pose_ros.checkpoints.switch import CHECKPOINT_FILE
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.style.personal import enroll, style_overrides

    out = Path(args.output)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        raise UsageError(f"-o {out}: exists and is not empty (use --force to replace its style)")
    if not out.exists():
        new_dir(out, "-o", parents=True)

    def progress(line: str) -> None:
        print(f"enroll: {line}", file=sys.stderr, flush=True)

    result = enroll(
        Path(args.recording),
        out,
        load_robot(),
        progress,
        max_seconds=args.max_seconds,
        command=shlex.join(["audio2pose", "enroll", *sys.argv[2:]]) if sys.argv else "",
    )
    learned = ", ".join(result.style.parts) or "no part learned"
    print(f"wrote {result.folder} ({learned}; {result.seconds:.1f} s used)")
    for line in result.report:  # per part: the expected gain, or why it kept the default
        print(line)
    if result.arms_noise != 1.0:
        print(
            f"the arms' sampling noise: {result.arms_noise:g} times the packaged model's "
            f"({result.folder / CHECKPOINT_FILE})"
        )
    else:
        print("no arms' noise fitted: the folder runs the packaged model")
    fitted = result.style.fitted[1] if result.style.fitted is not None else result.settings
    print("style parameters of the folder (what --model applies):")
    for line in style_overrides(fitted) or ["(none: the model as generated)"]:
        print(f"  {line}")
    if fitted != result.settings:
        print("the style alone on the packaged model (what the console's learn my style applies):")
        for line in style_overrides(result.settings) or ["(none: the model as generated)"]:
            print(f"  {line}")
    print(f"use it: audio2pose run --model {result.folder}")
    return 0


def command_evaluate_style(args: argparse.Namespace) -> int:
    """Enroll on the start of each source, score on the rest: the SI-vs-SD table."""
    from audio2pose_ros.learning.style_card import write_card_section
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.style.evaluation import evaluate_sources, source_spec
    from audio2pose_ros.style.personal import MAX_ENROLL_S

    table = evaluate_sources(
        [source_spec(d) for d in args.data],
        load_robot(),
        enroll_s=args.enroll_seconds,
        progress=lambda line: print(f"evaluate-style: {line}", file=sys.stderr, flush=True),
    )
    print(table)
    if args.card:
        # the command as parsed (not the process's argv: main may be called with its own)
        command = ["audio2pose", "evaluate-style", *args.data]
        if args.enroll_seconds != MAX_ENROLL_S:
            command += ["--enroll-seconds", f"{args.enroll_seconds:g}"]
        command += ["--card", args.card]
        write_card_section(Path(args.card), table, shlex.join(command))
        print(f"wrote the section into {args.card}")
    return 0


def register(verbs: Verbs) -> None:
    """Add the ``enroll`` and ``evaluate-style`` verbs."""
    from audio2pose_ros.style.personal import MAX_ENROLL_S

    enroll = verbs.add_parser(
        "enroll", help="learn a person's speaking style from a video (or data set): a model folder"
    )
    enroll.add_argument(
        "recording", metavar="VIDEO|DATASET", help="a video with speech, or an imported data set"
    )
    enroll.add_argument("-o", "--output", required=True, metavar="DIR", help="model folder")
    enroll.add_argument(
        "--max-seconds",
        type=bounded_float(5.0, 600.0),
        default=MAX_ENROLL_S,
        help="use at most this much of the recording (%(default)s s)",
    )
    enroll.add_argument("--force", action="store_true", help="replace the folder's style")
    enroll.set_defaults(func=command_enroll)

    evaluate = verbs.add_parser(
        "evaluate-style",
        help="enroll on each source's start, score default vs enrolled on the rest",
    )
    evaluate.add_argument(
        "data",
        nargs="+",
        metavar="[NAME=]DATASET",
        help="imported data sets: sources by clip id, or NAME=DATASET for one source of them all",
    )
    evaluate.add_argument(
        "--enroll-seconds",
        type=bounded_float(5.0, 600.0),
        default=MAX_ENROLL_S,
        help="enroll on at most this much of each source (%(default)s s)",
    )
    evaluate.add_argument("--card", metavar="MODEL_CARD.md", help="write the table into a card")
    evaluate.set_defaults(func=command_evaluate_style)
