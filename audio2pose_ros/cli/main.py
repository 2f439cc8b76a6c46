"""``audio2pose``: the command line of audio2pose_ros.

Verbs: ``run`` (start the node graph, optionally play a WAV and record a bag), ``demo`` (run on
the bundled speech clip with the default model), ``synth`` (offline synthesis to CSV), the body,
head and arm checks, ``plot-filter`` (raw model output against the online filter),
``distill-prosody`` (an MLP imitating the prosody rule); the ``*_commands`` modules add
``train``, ``evaluate``, ``dataset``, ``bag``, ``render``, ``faults``, ``console``, ``enroll``,
``evaluate-style`` and ``bench``. Each verb is a function ``command_<verb>(args) -> int`` that
parses and checks its options and calls the layer that does the work.

Errors and exit status: the package raises :class:`~audio2pose_ros.errors.Audio2PoseError` for
what a user can fix, and only those are reported as ``audio2pose <verb>: error: ...``, one line
on stderr: exit status 2 for a bad option (argparse's own errors included,
:class:`~audio2pose_ros.errors.UsageError`), 1 for bad data (a file, a bag, a checkpoint).
Any other exception is a bug: one line ``audio2pose <verb>: internal error (a bug): ...`` and
exit status 70 (``EX_SOFTWARE``); the traceback is printed only with the global ``--debug``.
"""

from __future__ import annotations

import argparse
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

    from audio2pose_ros.motion.style import StyleSettings

from audio2pose_ros.cli.options import (
    MAX_SEED,
    OneLineParser,
    Verbs,
    add_force,
    add_voice_out_option,
    bounded_float,
    bounded_int,
    check_robot_options,
    input_bag,
    input_dir,
    input_file,
    new_dir,
    output_file,
    report,
)
from audio2pose_ros.cli.style_commands import add_style_options, graph_overrides
from audio2pose_ros.errors import Audio2PoseError, InputError, UsageError

DEFAULT_OUT = Path("out")
EXIT_DATA_ERROR = 1
EXIT_USAGE_ERROR = 2
EXIT_INTERNAL_ERROR = 70  # sysexits.h EX_SOFTWARE: a bug
MAX_PLAYBACK_RATE = 100.0  # --rate: playback at most 100x real time


def command_run(args: argparse.Namespace) -> int:
    """Start the graph as processes; with --play, play a WAV in real time and record commands."""
    from audio2pose_ros.ros.run_command import run_graph, summarize

    if args.record and args.play is None:
        raise UsageError("--record needs --play (recording stops when the file ends)")
    check_robot_options(args)
    play = _speech_input(args.play) if args.play else None
    record = new_dir(args.record, "--record") if args.record else None
    params = input_file(args.params_file, "parameters file") if args.params_file else None
    log_dir = Path(args.log_dir) if args.log_dir else None
    if log_dir is not None and log_dir.exists() and not log_dir.is_dir():
        raise UsageError(f"--log-dir {log_dir}: exists and is not a directory")
    overrides = graph_overrides(args)
    result = run_graph(
        play,
        record,
        params,
        overrides,
        log_dir,
        rate=args.rate,
        single_process=args.single_process,
        sim=args.sim,
        no_robot=args.no_robot,
        voice_out=args.voice_out or "",
    )
    if result is not None:
        print(summarize(result))
    return 0


def command_demo(args: argparse.Namespace) -> int:
    """The main job on the embedded defaults: bundled speech through the live graph.

    Writes the recorded commands (MCAP), a video of the robot performing them with the speech,
    the filter plot and the offline trajectory of the same clip, and says where they are.
    """
    from audio2pose_ros.resources import bundled_speech_path
    from audio2pose_ros.ros.run_command import run_graph, summarize

    wav = bundled_speech_path()
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise UsageError(f"--out {args.out}: exists and is not a directory")
    out_dir = Path(args.out) / time.strftime("demo_%Y%m%d_%H%M%S")
    bag = out_dir / "commands_mcap"
    print(
        f"playing {wav.name} (LibriVox, public domain; see data/speech/SOURCES.md) into the "
        "node graph in real time ...",
        flush=True,
    )
    result = run_graph(wav, bag, None, [], out_dir / "logs", no_robot=True)  # recorded only
    if result is None:
        raise RuntimeError("the graph ran without playing the clip")
    print(summarize(result))
    video = out_dir / "robot.mp4"
    render_command = [
        "render",
        str(wav),
        "--bag",
        str(bag),
        "-o",
        str(video),
        "--side",
        "--no-progress",
    ]
    if main(render_command) != 0:
        return 1
    plot = out_dir / "filter.png"
    if main(["plot-filter", str(wav), "-o", str(plot)]) != 0:
        return 1
    csv_path = _synthesize_to_csv(wav, out_dir / "offline_trajectory.csv", None, smooth=True)
    print(f"\nresults in {out_dir.resolve()}:")
    print(f"  {video.name}: the robot performing the recorded commands, with the speech")
    print(f"  {plot.name}: raw model output against the motion filter, per joint")
    print(f"  {bag.name}/: rosbag2 (MCAP) of every command and of the audio (Foxglove, rosbags)")
    print(f"  {csv_path.name}: offline synthesis of the same clip (100 Hz, radians)")
    print("  logs/: the three nodes' output")
    return 0


def _speech_input(name: str) -> Path:
    """A speech input: a WAV file, or a rosbag2 (a folder, or one .mcap / .db3 file)."""
    path = Path(name)
    return input_file(path, "WAV file") if path.suffix.lower() == ".wav" else input_bag(path)


def _read_speech(path: Path) -> np.ndarray:
    """16 kHz mono samples of a WAV file, or of a bag's audio topics."""
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.data.bag import read_bag_audio

    path = _speech_input(str(path))
    return read_wav(path)[0] if path.suffix.lower() == ".wav" else read_bag_audio(path)


def _synthesize_to_csv(
    wav: Path,
    out: Path,
    model: str | None,
    smooth: bool,
    seed: int = 0,
    force: bool = False,
    style: StyleSettings | None = None,
) -> Path:
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.synthesis import synthesize, write_trajectory_csv
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot.description import load_robot

    output_file(out, "-o", inputs=(wav, model), force=force)
    checkpoint = load_checkpoint(model or default_checkpoint_path(), robot=load_robot())
    times, angles = synthesize(checkpoint, _read_speech(wav), smooth=smooth, seed=seed, style=style)
    try:
        return write_trajectory_csv(out, times, angles, checkpoint.robot.names)
    except OSError as exc:
        raise InputError(f"{out}: cannot write ({exc.strerror or exc})") from None


def command_synth(args: argparse.Namespace) -> int:
    """Offline synthesis of a WAV to a CSV of joint angles at 100 Hz, in a style if asked."""
    from audio2pose_ros.cli.style_commands import model_and_style_settings
    from audio2pose_ros.robot.description import load_robot

    checkpoint, style = model_and_style_settings(args, load_robot())
    out = _synthesize_to_csv(
        Path(args.wav),
        Path(args.output),
        str(checkpoint),
        not args.no_smooth,
        seed=args.seed,
        force=args.force,
        style=style,
    )
    print(f"wrote {out}")
    return 0


def command_check_body(args: argparse.Namespace) -> int:
    """Per clip: how often the model's raw motion needs the self-collision guard, and after it."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.body_check import HEADER, check_glides, check_trajectory
    from audio2pose_ros.offline.synthesis import synthesize
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot.body import BodyModel
    from audio2pose_ros.robot.description import load_robot

    if not args.inputs and args.glides is None:
        raise UsageError("give speech (FILE.wav|BAG ...), --glides N, or both")
    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=load_robot())
    body = BodyModel.load(checkpoint.robot)
    inputs = [_speech_input(name) for name in args.inputs]
    print(f"margin {args.margin * 100:.1f} cm, seed {args.seed}")
    if args.glides is not None:
        print(check_glides(body, args.glides, args.seed, args.margin).row())
    if inputs:
        print(f"{'clip':<40}{'motion':<9}{HEADER}")
    for path in inputs:
        signal = _read_speech(path)
        for label, margin in (("raw", None), ("guarded", args.margin)):
            _, angles = synthesize(checkpoint, signal, seed=args.seed, body_margin_m=margin)
            report = check_trajectory(body, angles, args.margin)
            print(f"{path.stem[:39]:<40}{label:<9}{report.row()}")
    return 0


def command_check_head(args: argparse.Namespace) -> int:
    """How the model's head moves on the speech, at several seeds, beside real head motion."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.data.dataset import Clip, Dataset
    from audio2pose_ros.learning.speech_style import head_style_rows, head_style_table
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot.description import load_robot

    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=load_robot())
    robot = checkpoint.robot
    speech = {str(path): _read_speech(path) for path in map(_speech_input, args.inputs)}
    head = robot.group_mask("head")
    real: dict[str, list[Clip]] = {}
    if args.data is not None:
        dataset = Dataset.open(input_dir(args.data, "data set folder"), robot)
        for info in dataset.clips:
            clip = dataset.load(info.clip_id)
            if clip.mask[:, head].any():
                real.setdefault(info.speaker, []).append(clip)
        if not real:
            raise InputError(f"{args.data}: no clip of the data set labels the head")
    label = f"model, {len(speech)} input(s), seeds 0..{args.seeds - 1}"
    rows = head_style_rows(checkpoint, robot, speech, range(args.seeds), real, label)
    print(head_style_table(rows, [name for name, on in zip(robot.names, head, strict=True) if on]))
    return 0


def command_check_arms(args: argparse.Namespace) -> int:
    """How calm the model's commanded arms are on the speech, beside the people's figures."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.learning.arm_calm import arm_calm_table, model_calm, people_row
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot.description import load_robot

    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=load_robot())
    speech = {str(path): _read_speech(path) for path in map(_speech_input, args.inputs)}
    label = f"model, {len(speech)} input(s), seeds 0..{args.seeds - 1}, commanded"
    people = people_row(checkpoint)
    rows = [people] if people is not None else []
    rows.append(model_calm(checkpoint, speech, range(args.seeds), label))
    print(arm_calm_table(rows))
    return 0


def command_plot_filter(args: argparse.Namespace) -> int:
    """Draw raw model output against the online motion filter for a speech file."""
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.offline.parameters_file import motion_filter_from_file
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.viz.filter_plot import plot_raw_vs_filtered

    output_file(
        args.output, "-o", inputs=(args.wav, args.model, args.params_file), force=args.force
    )
    filt = motion_filter_from_file(
        input_file(args.params_file, "parameters file") if args.params_file else None
    )
    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=filt.robot)
    signal, _ = read_wav(input_file(args.wav, "WAV file"))
    figures = plot_raw_vs_filtered(
        checkpoint,
        filt,
        signal,
        Path(args.output),
        title=f"{Path(args.wav).name}: raw model output vs filter",
    )
    print(f"wrote {args.output}")
    for key, value in figures.items():
        print(f"{key}: {value:.3f}")
    return 0


def command_distill_prosody(args: argparse.Namespace) -> int:
    """Train an MLP to imitate the prosody rule on the given WAVs and write its model card."""
    from audio2pose_ros.learning.distillation import distill_prosody, write_prosody_model_card
    from audio2pose_ros.learning.training import TrainSettings
    from audio2pose_ros.robot.description import load_robot

    wavs = [input_file(w, "WAV file") for w in args.wavs]
    output_file(args.output, "-o", inputs=wavs, force=args.force)
    checkpoint, fit_report, metrics = distill_prosody(
        wavs,
        Path(args.output),
        load_robot(),
        validation=args.validation,
        settings=TrainSettings(seed=args.seed, max_epochs=args.max_epochs),
    )
    card = write_prosody_model_card(Path(args.output), checkpoint, fit_report, metrics, wavs)
    for key, value in metrics.items():
        print(f"{key}: {value:.2f}")
    print(f"wrote {args.output} and {card}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with one sub-parser per verb."""
    parser = OneLineParser(prog="audio2pose", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--debug", action="store_true", help="print the traceback of an internal error"
    )
    verbs = parser.add_subparsers(dest="verb", required=True)
    rate = bounded_float(0.0, MAX_PLAYBACK_RATE, low_inclusive=False)
    seed = bounded_int(0, MAX_SEED)

    run = verbs.add_parser("run", help="start the node graph (what pepper.launch.py starts)")
    run.add_argument(
        "--play", metavar="FILE.wav|BAG", help="play a WAV or a bag's audio in real time, then exit"
    )
    run.add_argument(
        "--rate", type=rate, default=1.0, help="playback speed factor in (0, 100] (default 1)"
    )
    run.add_argument("--record", metavar="OUT", help="record the commands to this rosbag2 (MCAP)")
    run.add_argument(
        "--model", help="checkpoint or personal model folder (default: packaged model)"
    )
    add_style_options(run)
    run.add_argument("--params-file", help="ROS parameter YAML (default: config/pepper.yaml)")
    run.add_argument("--log-dir", help="write each node's output to <dir>/<node>.log")
    run.add_argument(
        "--single-process",
        action="store_true",
        help="run the three nodes in one process and one executor (smallest footprint)",
    )
    run.add_argument(
        "--sim",
        action="store_true",
        help="also run a simulated Pepper (pybullet) that follows joint_angles and publishes "
        "the measured joint_states",
    )
    run.add_argument(
        "--no-robot",
        action="store_true",
        help="no robot publishes joint_states (only --record takes the commands): start from "
        "the saved pose or neutral instead of waiting for the robot's measured pose",
    )
    add_voice_out_option(run)
    run.set_defaults(func=command_run)

    demo = verbs.add_parser("demo", help="bundled speech -> live graph -> recorded bag and CSV")
    demo.add_argument("--out", default=str(DEFAULT_OUT), help="output folder (default: out/)")
    demo.set_defaults(func=command_demo)

    synth = verbs.add_parser("synth", help="offline synthesis of a WAV to CSV (100 Hz, radians)")
    synth.add_argument("wav", metavar="FILE.wav|BAG", help="a WAV file or a bag with audio")
    synth.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    add_force(synth)
    synth.add_argument(
        "--model", help="checkpoint or personal model folder (default: packaged model)"
    )
    add_style_options(synth)
    synth.add_argument("--no-smooth", action="store_true", help="skip the 4 Hz Butterworth filter")
    synth.add_argument(
        "--seed", type=seed, default=0, help="noise seed of a sampling model (default 0)"
    )
    synth.set_defaults(func=command_synth)

    check = verbs.add_parser(
        "check-body", help="how often the model's motion needs the self-collision guard"
    )
    check.add_argument("inputs", nargs="*", metavar="FILE.wav|BAG", help="speech to synthesize")
    check.add_argument("--model", help="checkpoint (default: packaged model)")
    check.add_argument(
        "--seed", type=seed, default=0, help="noise seed of a sampling model (default 0)"
    )
    check.add_argument(
        "--margin",
        type=bounded_float(0.0, 0.1),
        default=0.02,
        help="clearance from the body (m), as the filter's body_margin_m (default 0.02)",
    )
    check.add_argument(
        "--glides",
        type=bounded_int(1, 10000),
        metavar="N",
        help="also start the filter at N random poses clear of the body (--seed) and count how "
        "many glide to neutral within 4 s (the guard going round the body)",
    )
    check.set_defaults(func=command_check_body)

    head = verbs.add_parser(
        "check-head", help="speed, acceleration and size of the model's head motion on speech"
    )
    head.add_argument("inputs", nargs="+", metavar="FILE.wav|BAG", help="speech to synthesize")
    head.add_argument("--model", help="checkpoint (default: packaged model)")
    head.add_argument(
        "--seeds",
        type=bounded_int(1, 100),
        default=8,
        help="sample at seeds 0..N-1 (default 8)",
    )
    head.add_argument(
        "--data",
        metavar="DIR",
        help="a data set (audio2pose dataset ...): its real head motion, per speaker, beside it",
    )
    head.set_defaults(func=command_check_head)

    arms = verbs.add_parser(
        "check-arms",
        help="how often the commanded arms hit the acceleration limit or rise above the shoulders",
    )
    arms.add_argument("inputs", nargs="+", metavar="FILE.wav|BAG", help="speech to synthesize")
    arms.add_argument("--model", help="checkpoint (default: packaged model)")
    arms.add_argument(
        "--seeds",
        type=bounded_int(1, 100),
        default=4,
        help="sample at seeds 0..N-1 (default 4)",
    )
    arms.set_defaults(func=command_check_arms)

    plot = verbs.add_parser("plot-filter", help="PNG of raw model output vs the motion filter")
    plot.add_argument("wav", metavar="FILE.wav")
    plot.add_argument("-o", "--output", required=True, metavar="OUT.png")
    add_force(plot)
    plot.add_argument("--model", help="checkpoint (default: packaged model)")
    plot.add_argument("--params-file", help="ROS parameter YAML (default: config/pepper.yaml)")
    plot.set_defaults(func=command_plot_filter)

    distill = verbs.add_parser(
        "distill-prosody", help="train the default model on the prosody rule"
    )
    distill.add_argument("wavs", nargs="+", metavar="FILE.wav")
    distill.add_argument("-o", "--output", required=True, metavar="OUT.safetensors")
    add_force(distill)
    distill.add_argument(
        "--validation",
        nargs="*",
        default=[],
        metavar="STEM",
        help="file stems held out for validation (default: the last file)",
    )
    distill.add_argument("--seed", type=seed, default=0)
    distill.add_argument("--max-epochs", type=bounded_int(1, 100_000), default=500)
    distill.set_defaults(func=command_distill_prosody)
    for register in _command_modules():
        register(verbs)
    return parser


def _command_modules() -> list[Callable[[Verbs], None]]:
    """``register(verbs)`` functions of the verbs that live in their own modules."""
    from audio2pose_ros.cli import (
        bag_commands,
        bench_commands,
        console_commands,
        dataset_commands,
        fault_commands,
        model_commands,
        render_commands,
        style_commands,
    )

    return [
        model_commands.register,
        dataset_commands.register,
        bag_commands.register,
        render_commands.register,
        fault_commands.register,
        console_commands.register,
        style_commands.register,
        bench_commands.register,
    ]


def _verb_name(args: argparse.Namespace) -> str:
    """``audio2pose <verb> [<sub-verb>]`` as typed, for messages."""
    sub = getattr(args, "bag_verb", None) or getattr(args, "dataset_verb", None)
    return " ".join(["audio2pose", args.verb, *([sub] if sub else [])])


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``audio2pose`` console script; returns the exit status.

    Exit status: 0 done, 1 bad data, 2 bad options, 70 internal error (a bug), 130 Ctrl-C.
    """
    args = build_parser().parse_args(argv)
    prog = _verb_name(args)
    try:
        return args.func(args)
    except UsageError as exc:
        report(prog, f"error: {exc}")
        return EXIT_USAGE_ERROR
    except Audio2PoseError as exc:
        report(prog, f"error: {exc}")
        return EXIT_DATA_ERROR
    except KeyboardInterrupt:
        report(prog, "interrupted")
        return 130
    except Exception as exc:
        if args.debug:
            traceback.print_exc()
        hint = "" if args.debug else "; run with --debug for the traceback"
        report(prog, f"internal error (a bug): {type(exc).__name__}: {exc}{hint}")
        return EXIT_INTERNAL_ERROR


if __name__ == "__main__":
    sys.exit(main())
