"""``audio2pose``: the command line of audio2pose_ros.

Verbs: ``run`` (start the node graph, optionally play a WAV and record a bag), ``demo`` (run on
the bundled speech clip with the default model), ``synth`` (offline synthesis to CSV), ``bench``
(per-frame cost of the streaming path), ``distill-prosody`` (rebuild the default model). Each verb
is a function ``command_<verb>(args) -> int``; the library raises typed errors, reported here as
one line on stderr with exit code 1.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

DEFAULT_OUT = Path("out")


def command_run(args: argparse.Namespace) -> int:
    """Start the graph as processes; with --play, play a WAV in real time and record commands."""
    from audio2pose_ros.cli.graph import run_graph, summarize

    if args.record and args.play is None:
        raise ValueError("--record needs --play (recording stops when the file ends)")
    if args.record and Path(args.record).exists():
        raise ValueError(f"{args.record} exists already; rosbag2 output must be a new directory")
    overrides = [f"model_path:={Path(args.model).resolve()}"] if args.model else []
    result = run_graph(
        Path(args.play) if args.play else None,
        Path(args.record) if args.record else None,
        Path(args.params_file) if args.params_file else None,
        overrides,
        Path(args.log_dir) if args.log_dir else None,
        rate=args.rate,
    )
    if result is not None:
        print(summarize(result))
    return 0


def command_demo(args: argparse.Namespace) -> int:
    """The main job on the embedded defaults: bundled speech through the live graph.

    Writes the recorded commands (MCAP), a video of the robot performing them with the speech,
    the filter plot and the offline trajectory of the same clip, and says where they are.
    """
    from audio2pose_ros.cli.graph import run_graph, summarize
    from audio2pose_ros.resources import bundled_speech_path

    wav = bundled_speech_path()
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


def _read_speech(path: Path):  # noqa: ANN202 - numpy imported lazily
    """16 kHz mono samples of a WAV file, or of a bag's audio topics."""
    from audio2pose_ros.audio.pcm import read_wav
    from audio2pose_ros.bag import read_bag_audio

    return read_wav(path)[0] if path.suffix.lower() == ".wav" else read_bag_audio(path)


def _synthesize_to_csv(wav: Path, out: Path, model: str | None, smooth: bool) -> Path:
    from audio2pose_ros.models.checkpoint import load_checkpoint
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot import load_robot
    from audio2pose_ros.synthesis import synthesize, write_trajectory_csv

    checkpoint = load_checkpoint(model or default_checkpoint_path(), robot=load_robot())
    times, angles = synthesize(checkpoint, _read_speech(wav), smooth=smooth)
    return write_trajectory_csv(out, times, angles, checkpoint.robot.names)


def command_synth(args: argparse.Namespace) -> int:
    """Offline synthesis of a WAV to a CSV of joint angles at 100 Hz."""
    out = _synthesize_to_csv(Path(args.wav), Path(args.output), args.model, not args.no_smooth)
    print(f"wrote {out}")
    return 0


def command_bench(args: argparse.Namespace) -> int:
    """Per-frame cost of each streaming stage on one core; with --graph, the live graph too."""
    import json

    import torch

    from audio2pose_ros.audio.pcm import read_wav
    from audio2pose_ros.benchmark import model_costs, reference_feature_cost, streaming_costs
    from audio2pose_ros.models.checkpoint import load_checkpoint
    from audio2pose_ros.motion.filter import MotionFilter
    from audio2pose_ros.resources import bundled_speech_path, default_checkpoint_path
    from audio2pose_ros.robot import load_robot

    results: dict[str, object] = {}
    if args.graph:  # before pinning this process to one core: the nodes need the machine
        from audio2pose_ros.cli.graph_bench import bundled_speech, measure_graph, report

        results["graph"] = report(measure_graph(bundled_speech(), duration_s=args.duration))
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
                "offline_x_real_time": cost.offline_audio_s_per_s,
            }
            for cost in model_costs(signal, robot, n_frames=min(args.frames, 2000))
        }
    if args.json:
        print(json.dumps(results, indent=1))
        return 0
    _print_bench(results, args.frames, len(signal) / 16000)
    return 0


def _print_bench(results: dict, frames: int, clip_s: float) -> None:
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
        print(f"{'model':<14}{'step median us':>16}{'step p99 us':>14}{'offline x real time':>22}")
        for name, cost in results["models"].items():
            step = (
                f"{cost['step_median_us']:>16.1f}{cost['step_p99_us']:>14.1f}"
                if cost["step_median_us"] is not None
                else f"{'offline only':>16}{'':>14}"
            )
            print(f"{name:<14}{step}{cost['offline_x_real_time']:>22.0f}")
    if "graph" in results:
        graph = results["graph"]
        print(
            f"\nlive graph (3 node processes over DDS), {graph['audio_s']:.0f} s of speech in "
            "10 ms chunks"
        )
        for key in ("latency_audio_to_raw_pose", "latency_audio_to_joint_angles"):
            s = graph[key]
            print(
                f"  {key}: p50 {s['p50_ms']:.2f} ms, p99 {s['p99_ms']:.2f} ms, "
                f"max {s['max_ms']:.2f} ms ({s['n']} chunks)"
            )
        print(
            f"  start-up: first command {graph['startup_first_command_s']:.2f} s, first "
            f"response to audio {graph['startup_first_response_to_audio_s']:.2f} s"
        )
        for node, cpu in graph["cpu_ms_per_frame"].items():
            print(f"  {node}: {cpu:.3f} ms CPU per frame, {graph['rss_mb'][node]:.0f} MB resident")


def _filter_from_params(params_file: Path | None):  # noqa: ANN202 - heavy types imported lazily
    """A MotionFilter configured like motion_filter_node from a ROS parameter file."""
    from dataclasses import fields

    import yaml

    from audio2pose_ros.motion.filter import MotionFilter, MotionFilterSettings
    from audio2pose_ros.motion.limits import LimitSettings
    from audio2pose_ros.resources import share_path
    from audio2pose_ros.robot import load_robot

    path = params_file or share_path("config", "pepper.yaml")
    data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    params = (data.get("motion_filter_node") or {}).get("ros__parameters") or {}
    shared = (data.get("/**") or {}).get("ros__parameters") or {}
    robot = load_robot(params.get("robot_description") or shared.get("robot_description"))

    def pick(cls: type) -> object:
        return cls(**{f.name: params[f.name] for f in fields(cls) if f.name in params})

    return MotionFilter(robot, pick(MotionFilterSettings), pick(LimitSettings))


def command_plot_filter(args: argparse.Namespace) -> int:
    """Draw raw model output against the online motion filter for a speech file."""
    from audio2pose_ros.audio.pcm import read_wav
    from audio2pose_ros.filter_plot import plot_raw_vs_filtered
    from audio2pose_ros.models.checkpoint import load_checkpoint
    from audio2pose_ros.resources import default_checkpoint_path

    filt = _filter_from_params(Path(args.params_file) if args.params_file else None)
    checkpoint = load_checkpoint(args.model or default_checkpoint_path(), robot=filt.robot)
    signal, _ = read_wav(args.wav)
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
    """Rebuild the default model: an MLP trained to imitate the prosody rule on the given WAVs."""
    from audio2pose_ros.cli.model_card import write_prosody_model_card
    from audio2pose_ros.prosody_distillation import distill_prosody
    from audio2pose_ros.robot import load_robot
    from audio2pose_ros.training import TrainSettings

    wavs = [Path(w) for w in args.wavs]
    checkpoint, report, metrics = distill_prosody(
        wavs,
        Path(args.output),
        load_robot(),
        validation=args.validation,
        settings=TrainSettings(seed=args.seed, max_epochs=args.max_epochs),
    )
    card = write_prosody_model_card(Path(args.output), checkpoint, report, metrics, wavs)
    for key, value in metrics.items():
        print(f"{key}: {value:.2f}")
    print(f"wrote {args.output} and {card}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with one sub-parser per verb."""
    parser = argparse.ArgumentParser(prog="audio2pose", description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True)

    run = verbs.add_parser("run", help="start the node graph (what pepper.launch.py starts)")
    run.add_argument(
        "--play", metavar="FILE.wav|BAG", help="play a WAV or a bag's audio in real time, then exit"
    )
    run.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    run.add_argument("--record", metavar="OUT", help="record the commands to this rosbag2 (MCAP)")
    run.add_argument("--model", help="checkpoint for the graph (default: packaged model)")
    run.add_argument("--params-file", help="ROS parameter YAML (default: config/pepper.yaml)")
    run.add_argument("--log-dir", help="write each node's output to <dir>/<node>.log")
    run.set_defaults(func=command_run)

    demo = verbs.add_parser("demo", help="bundled speech -> live graph -> recorded bag and CSV")
    demo.add_argument("--out", default=str(DEFAULT_OUT), help="output folder (default: out/)")
    demo.set_defaults(func=command_demo)

    synth = verbs.add_parser("synth", help="offline synthesis of a WAV to CSV (100 Hz, radians)")
    synth.add_argument("wav", metavar="FILE.wav|BAG", help="a WAV file or a bag with audio")
    synth.add_argument("-o", "--output", required=True, metavar="OUT.csv")
    synth.add_argument("--model", help="checkpoint (default: packaged model)")
    synth.add_argument("--no-smooth", action="store_true", help="skip the 4 Hz Butterworth filter")
    synth.set_defaults(func=command_synth)

    bench = verbs.add_parser("bench", help="per-frame cost of the streaming path")
    bench.add_argument("--model", help="checkpoint (default: packaged model)")
    bench.add_argument("--frames", type=int, default=3000, help="frames to time (default 3000)")
    bench.add_argument("--skip-models", action="store_true", help="skip the per-model table")
    bench.add_argument(
        "--graph",
        action="store_true",
        help="also run the live graph: latency, CPU, memory, start-up",
    )
    bench.add_argument(
        "--duration", type=float, default=60.0, help="seconds of speech for --graph (default 60)"
    )
    bench.add_argument("--json", action="store_true", help="print the figures as JSON")
    bench.set_defaults(func=command_bench)

    plot = verbs.add_parser("plot-filter", help="PNG of raw model output vs the motion filter")
    plot.add_argument("wav", metavar="FILE.wav")
    plot.add_argument("-o", "--output", required=True, metavar="OUT.png")
    plot.add_argument("--model", help="checkpoint (default: packaged model)")
    plot.add_argument("--params-file", help="ROS parameter YAML (default: config/pepper.yaml)")
    plot.set_defaults(func=command_plot_filter)

    distill = verbs.add_parser(
        "distill-prosody", help="train the default model on the prosody rule"
    )
    distill.add_argument("wavs", nargs="+", metavar="FILE.wav")
    distill.add_argument("-o", "--output", required=True, metavar="OUT.safetensors")
    distill.add_argument(
        "--validation",
        nargs="*",
        default=[],
        metavar="STEM",
        help="file stems held out for validation (default: the last file)",
    )
    distill.add_argument("--seed", type=int, default=0)
    distill.add_argument("--max-epochs", type=int, default=500)
    distill.set_defaults(func=command_distill_prosody)
    for register in _command_modules():
        register(verbs)
    return parser


def _command_modules() -> list[Callable[[argparse._SubParsersAction], None]]:
    """``register(verbs)`` functions of the verbs that live in their own modules."""
    from audio2pose_ros.cli import bag_commands, dataset_commands, model_commands, render_commands

    return [
        model_commands.register,
        dataset_commands.register,
        bag_commands.register,
        render_commands.register,
    ]


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``audio2pose`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, OSError, TimeoutError) as exc:  # includes the library's typed errors
        print(f"audio2pose {args.verb}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
