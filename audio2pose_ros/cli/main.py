"""``audio2pose``: the command line of audio2pose_ros.

Verbs: ``run`` (start the node graph, optionally play a WAV and record a bag), ``demo`` (run on
the bundled speech clip with the default model), ``synth`` (offline synthesis to CSV), ``bench``
(per-frame cost of the streaming path and of the live graph), ``plot-filter`` (raw model output
against the online filter), ``distill-prosody`` (an MLP imitating the prosody rule); the
``*_commands`` modules add ``train``, ``evaluate``, ``dataset``, ``bag``, ``render`` and
``faults``. Each verb is a function ``command_<verb>(args) -> int`` that parses and checks its
options and calls the layer that does the work.

Errors and exit status: the package raises :class:`~audio2pose_ros.errors.Audio2PoseError` for
what a user can fix, and only those are reported as ``audio2pose <verb>: error: ...``, one line
on stderr: exit status 2 for a bad option (argparse's own errors included,
:class:`~audio2pose_ros.errors.UsageError`), 1 for bad data (a file, a bag, a checkpoint).
Any other exception is a bug: one line ``audio2pose <verb>: internal error (a bug): ...`` and
exit status 70 (``EX_SOFTWARE``); the traceback is printed only with the global ``--debug``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from audio2pose_ros.motion.style import StyleSettings

from audio2pose_ros.cli.options import (
    MAX_SEED,
    OneLineParser,
    Verbs,
    add_force,
    bounded_float,
    bounded_int,
    input_bag,
    input_dir,
    input_file,
    new_dir,
    output_file,
    report,
)
from audio2pose_ros.cli.style_commands import add_style_options, graph_overrides
from audio2pose_ros.errors import Audio2PoseError, InputError, UsageError
from audio2pose_ros.timebase import duration_s

DEFAULT_OUT = Path("out")
EXIT_DATA_ERROR = 1
EXIT_USAGE_ERROR = 2
EXIT_INTERNAL_ERROR = 70  # sysexits.h EX_SOFTWARE: a bug
MAX_PLAYBACK_RATE = 100.0  # --rate: playback at most 100x real time


def command_run(args: argparse.Namespace) -> int:
    """Start the graph as processes; with --play, play a WAV in real time and record commands."""
    from audio2pose_ros.ros.graph import run_graph, summarize

    if args.record and args.play is None:
        raise UsageError("--record needs --play (recording stops when the file ends)")
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
    from audio2pose_ros.ros.graph import run_graph, summarize

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
    result = run_graph(wav, bag, None, [], out_dir / "logs")
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


BENCH_SCHEMA_VERSION = 3  # 1: before versioning; 2: graph figures a list of modes; 3: floor


def _bench_live(args: argparse.Namespace, results: dict[str, object]) -> None:
    """The live parts of ``bench``: --console, --graph and --sim, into ``results``."""
    if args.console:  # the operator's voice through the web console to /joint_angles
        from audio2pose_ros.ros.tools.console_bench import console_report, measure_console
        from audio2pose_ros.ros.tools.graph_bench import bundled_speech

        results["console"] = console_report(measure_console(bundled_speech(), args.duration))
    if args.graph:  # before pinning this process to one core: the nodes need the machine
        from audio2pose_ros.ros.tools.graph_bench import bundled_speech, measure_graph, report

        speech = bundled_speech()
        results["graph"] = [
            report(
                measure_graph(
                    speech, duration_s=args.duration, single_process=single, with_floor=True
                )
            )
            for single in {"three": [False], "single": [True], "both": [False, True]}[
                args.graph_mode
            ]
        ]
    if args.sim:  # the graph against the simulated Pepper: commanded vs executed
        from audio2pose_ros.ros.tools.graph_bench import bundled_speech, measure_sim_tracking

        tracking = measure_sim_tracking(bundled_speech(), duration_s=min(args.duration, 60.0))
        results["sim_tracking"] = dataclasses.asdict(tracking)


def command_bench(args: argparse.Namespace) -> int:
    """Per-frame cost of each streaming stage on one core; with --graph, the live graph too."""
    import json

    import torch

    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.motion.filter import MotionFilter
    from audio2pose_ros.offline.benchmark import (
        model_costs,
        reference_feature_cost,
        streaming_costs,
    )
    from audio2pose_ros.resources import bundled_speech_path, default_checkpoint_path
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.ros.tools.process_stats import busy_loops

    # --json: one object; its layout is versioned, and a change of it is in CHANGELOG.md
    results: dict[str, object] = {"schema_version": BENCH_SCHEMA_VERSION}
    with busy_loops(args.busy_loops) as busy:  # other work beside the live graph
        if busy:
            results["busy_loops"] = len(busy)
        _bench_live(args, results)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    torch.set_num_threads(1)
    robot = load_robot()
    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=robot)
    signal, _ = read_wav(bundled_speech_path())
    timings = streaming_costs(checkpoint, MotionFilter(robot), signal, n_frames=args.frames)
    reference = reference_feature_cost(signal, n_frames=min(args.frames, 1000))
    results["stages_us"] = {
        t.name: {"median": t.median_us, "p99": t.p99_us} for t in [*timings, reference]
    }
    results["features_speedup_vs_python_speech_features"] = (
        reference.median_us / timings[0].median_us
    )
    if not args.skip_models:
        results["models"] = {
            cost.name: {
                "step_median_us": cost.step.median_us if cost.step else None,
                "step_p99_us": cost.step.p99_us if cost.step else None,
                "numpy_kernel_step_median_us": (
                    cost.kernel_step.median_us if cost.kernel_step else None
                ),
                "torch_step_median_us": cost.torch_step.median_us if cost.torch_step else None,
                "offline_x_real_time": cost.offline_audio_s_per_s,
            }
            for cost in model_costs(signal, robot, n_frames=min(args.frames, 2000))
        }
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    _print_bench(results, args.frames, duration_s(len(signal)))
    return 0


def _print_bench(results: dict[str, Any], frames: int, clip_s: float) -> None:
    print(f"per-frame cost on one core, {frames} frames of real speech (10 ms each)")
    print(f"{'stage':<52}{'median us':>12}{'p99 us':>12}")
    for name, timing in results["stages_us"].items():
        print(f"{name:<52}{timing['median']:>12.1f}{timing['p99']:>12.1f}")
    ratio = results["features_speedup_vs_python_speech_features"]
    print(f"streaming features vs python_speech_features per window: {ratio:.0f}x faster (median)")
    total = results["stages_us"]["whole online frame"]["median"]
    print(f"whole online frame: {total:.1f} us median = {total / 100:.2f} % of the 10 ms period")
    if "models" in results:
        print(
            f"\nevery model family (untrained weights; cost does not depend on them), "
            f"{clip_s:.1f} s clip"
        )
        print(
            f"{'model':<14}{'step median us':>16}{'step p99 us':>14}{'no-torch kernel us':>20}"
            f"{'torch call us':>15}{'offline x real time':>22}"
        )
        for name, cost in results["models"].items():
            step = (
                f"{cost['step_median_us']:>16.1f}{cost['step_p99_us']:>14.1f}"
                if cost["step_median_us"] is not None
                else f"{'offline only':>16}{'':>14}"
            )
            kernel, call = cost["numpy_kernel_step_median_us"], cost["torch_step_median_us"]
            step += f"{kernel:>20.1f}" if kernel is not None else f"{'-':>20}"
            step += f"{call:>15.1f}" if call is not None else f"{'-':>15}"
            print(f"{name:<14}{step}{cost['offline_x_real_time']:>22.0f}")
    if "graph" in results:
        _print_graph(results["graph"])
    if "sim_tracking" in results:
        sim = results["sim_tracking"]
        print(
            f"\nagainst the simulated Pepper, {sim['audio_s']:.0f} s of speech: commanded vs "
            f"executed error median {sim['error_median_deg']:.2f} deg, p95 "
            f"{sim['error_p95_deg']:.2f} deg (largest joint per measured pose); self-collisions "
            f"executed: {sim['executed_self_collision_steps']} steps "
            f"({sim['measured_inside_body']} measured poses inside the body)"
        )
    if "console" in results:
        _print_console(results["console"])
    if "busy_loops" in results:
        print(f"\n(--graph, --console, --sim measured beside {results['busy_loops']} busy loops)")


def _print_console(console: dict[str, Any]) -> None:
    """The console's figures: browser chunk to /joint_angles, and the console node's cost."""
    latency = console["latency_browser_to_joint_angles"]
    print(
        f"\noperator console over WebSocket and DDS, {console['audio_s']:.0f} s of speech in "
        "the page's 20 ms chunks"
    )
    if latency["n"]:
        print(
            f"  browser chunk -> /joint_angles p50 / p99: {latency['p50_ms']:.1f} / "
            f"{latency['p99_ms']:.1f} ms ({latency['n']} of {console['chunks']} chunks, "
            f"{console['ambiguous_pairs']} paired ambiguously; the chunk's own 20 ms and the "
            "25 ms feature window come on top)"
        )
    else:
        print("  browser chunk -> /joint_angles: no command matched a chunk's poses")
    if console.get("chunks_lost"):
        print(
            f"  {console['chunks_lost']} of {console['chunks']} chunks never reached audio/audio "
            "(best-effort audio QoS drops under load; the page's voice had gaps)"
        )
    lag = console["motion_lag_behind_sound"]
    if lag["n"]:
        print(
            f"  /joint_angles behind the same chunk on audio/audio (what audio_play plays) "
            f"p50 / p99: {lag['p50_ms']:.1f} / {lag['p99_ms']:.1f} ms (minus the player's output "
            "buffering, not measured here)"
        )
    live = console["console_live_estimate_ms"]
    if live:
        print(f"  the page's live estimate: p50 {live.get('p50')} / p99 {live.get('p99')} ms")
    print(
        f"  console_node: {console['console_node_cpu_ms_per_audio_s']:.1f} ms CPU per second of "
        f"audio ({console['console_node_cpu_percent']:.1f} % of a core), "
        f"{console['console_node_rss_mb']:.0f} MB resident"
    )


def _print_graph(runs: list[dict[str, Any]]) -> None:
    """The graph figures of each mode side by side, then the targets met or not."""
    modes = [run["mode"] for run in runs]
    print(f"\nlive graph over DDS, {runs[0]['audio_s']:.0f} s of speech in 10 ms chunks")
    print(f"{'':<44}" + "".join(f"{mode:>20}" for mode in modes))

    def row(label: str, values: list[str]) -> None:
        print(f"{label:<44}" + "".join(f"{v:>20}" for v in values))

    for key in ("latency_audio_to_raw_pose", "latency_audio_to_joint_angles"):
        row(
            f"{key.removeprefix('latency_')} p50/p99 ms",
            [f"{run[key]['p50_ms']:.2f} / {run[key]['p99_ms']:.2f}" for run in runs],
        )
    row(
        "first command / first response s",
        [
            f"{run['startup_first_command_s']:.2f} / {run['startup_first_response_to_audio_s']:.2f}"
            for run in runs
        ],
    )
    processes = sorted({name for run in runs for name in run["rss_mb"]})
    for name in processes:
        row(
            f"{name}: CPU ms/frame (steady), MB",
            [
                f"{run['cpu_ms_per_frame'][name]:.3f} ({run['steady_cpu_ms_per_frame'][name]:.3f}),"
                f" {run['rss_mb'][name]:.0f}"
                if name in run["rss_mb"]
                else "-"
                for run in runs
            ],
        )
    for run in runs:
        floor = run.get("floor")
        if floor:
            for name, cpu in floor["steady_cpu_ms_per_frame"].items():
                row(
                    f"bare rclpy relay for {name}: CPU, MB",
                    [f"({cpu:.3f}), {floor['rss_mb'][name]:.0f}"],
                )
            print(
                f"{run['mode']}: the nodes' steady CPU is {floor['steady_cpu_ratio']:.2f}x the bare"
                " rclpy relays' (the floor: the same topology, QoS and executors, no work), "
                f"{sum(run['rss_mb'].values()):.0f} MB against their "
                f"{sum(floor['rss_mb'].values()):.0f} MB"
            )
    print("footprint targets")
    for run in runs:
        for target in run["targets"]:
            verdict = "met" if target["met"] else "NOT MET"
            print(
                f"  {run['mode']:<16}{target['figure']:<52}{target['value']:>9.2f} "
                f"<= {target['target']:g} {target['unit']:<3} {verdict}"
            )


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

    bench = verbs.add_parser("bench", help="per-frame cost of the streaming path")
    bench.add_argument("--model", help="checkpoint (default: packaged model)")
    bench.add_argument(
        "--frames",
        type=bounded_int(10, 1_000_000),
        default=3000,
        help="frames to time, 10 to 1e6 (default 3000)",
    )
    bench.add_argument("--skip-models", action="store_true", help="skip the per-model table")
    bench.add_argument(
        "--graph",
        action="store_true",
        help="also run the live graph: latency, CPU, memory, start-up",
    )
    bench.add_argument(
        "--duration",
        type=bounded_float(1.0, 3600.0),
        default=60.0,
        help="seconds of speech for --graph and --console, 1 to 3600 (default 60)",
    )
    bench.add_argument(
        "--graph-mode",
        choices=("three", "single", "both"),
        default="both",
        help="--graph runs three node processes, one process, or both in turn (default both)",
    )
    bench.add_argument(
        "--sim",
        action="store_true",
        help="also run the graph against the simulated Pepper: tracking error commanded vs "
        "executed and self-collisions executed (--duration, at most 60 s)",
    )
    bench.add_argument(
        "--console",
        action="store_true",
        help="also stream speech through the operator console: browser to /joint_angles "
        "latency, console node CPU and memory (--duration seconds)",
    )
    bench.add_argument(
        "--busy-loops",
        type=bounded_int(0, 16),
        default=0,
        help="run N busy-loop processes beside --graph, --console and --sim (other work on the "
        "machine), 0 to 16 (default 0)",
    )
    bench.add_argument("--json", action="store_true", help="print the figures as JSON")
    bench.set_defaults(func=command_bench)

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
