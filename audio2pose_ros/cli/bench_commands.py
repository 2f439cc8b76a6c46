"""``audio2pose bench``: the per-frame cost of the streaming path, and the live graph's.

Stages and model families are timed in this process on one core; ``--graph``, ``--console`` and
``--sim`` run the live graph (:mod:`audio2pose_ros.ros.tools.graph_bench`,
:mod:`audio2pose_ros.ros.tools.console_bench`), beside ``--busy-loops`` spinning processes when
asked. ``--json`` prints one object whose layout is versioned (:data:`BENCH_SCHEMA_VERSION`).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from typing import Any

from audio2pose_ros.cli.options import Verbs, bounded_float, bounded_int
from audio2pose_ros.timebase import FRAME_PERIOD_S, duration_s

__all__ = ["BENCH_SCHEMA_VERSION", "command_bench", "register"]

# 1: unversioned; 2: graph modes; 3: floor; 4: floor executor; 5: paced; 6: voice;
# 7: the graph's first command beside a robot that reports its pose, the voice's calibration time
BENCH_SCHEMA_VERSION = 7


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
                    speech,
                    duration_s=args.duration,
                    single_process=single,
                    with_floor=True,
                    floor_executor=args.floor_executor,
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
    if args.voice:  # the voice against the motion at the simulated Pepper, at two latencies
        from audio2pose_ros.ros.tools.graph_bench import bundled_speech
        from audio2pose_ros.ros.tools.voice_bench import (
            BENCH_EXECUTION_LATENCIES_S,
            measure_voice,
            voice_report,
        )

        results["voice"] = [
            voice_report(measure_voice(bundled_speech(), latency, duration_s=args.voice_duration))
            for latency in BENCH_EXECUTION_LATENCIES_S
        ]


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
    period_s = FRAME_PERIOD_S if args.paced else 0.0
    timings = streaming_costs(
        checkpoint, MotionFilter(robot), signal, n_frames=args.frames, period_s=period_s
    )
    reference = reference_feature_cost(signal, n_frames=min(args.frames, 1000), period_s=period_s)
    results["stages_paced"] = bool(args.paced)
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
    how = "one every 10 ms, as the nodes run them" if results["stages_paced"] else "back to back"
    print(f"per-frame cost on one core, {frames} frames of real speech (10 ms each), {how}")
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
    if "voice" in results:
        _print_voice(results["voice"])
    if "busy_loops" in results:
        loops = results["busy_loops"]
        print(f"\n(--graph, --console, --sim, --voice measured beside {loops} busy loops)")


def _print_voice(runs: list[dict[str, Any]]) -> None:
    """The voice against the motion at the simulated Pepper: motion - heard, per latency."""
    print(
        "\nvoice vs motion at the simulated Pepper (motion - heard; window -80 .. +20 ms), "
        f"{runs[0]['audio_s']:.0f} s of speech after calibration"
    )
    for run in runs:
        after = run["calibrated_after_s"]
        calibration = (
            f"calibrated after {after:.0f} s of speech"
            if after is not None
            else "NOT calibrated after the longest calibration: measured anyway"
        )
        print(f"  at {run['execution_latency_ms']} ms the voice node was {calibration}")
    print(f"{'execution latency':<20}{'windows':>8}{'p5 ms':>8}{'p50 ms':>8}{'p95 ms':>8}  delay")
    for run in runs:
        print(
            f"{run['execution_latency_ms']:>17} ms{run['windows']:>8}{run['offset_p5_ms']:>8.0f}"
            f"{run['offset_p50_ms']:>8.0f}{run['offset_p95_ms']:>8.0f}  "
            f"{run['voice_delay_ms']} ms (graph {run['graph_latency']}, execution "
            f"{run['execution_latency']}, loudspeaker {run['loudspeaker_latency']})"
        )


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
                relays = name if name.startswith("relays") else f"relay for {name}"
                row(
                    f"bare rclpy {relays}: CPU, MB",
                    [f"({cpu:.3f}), {floor['rss_mb'][name]:.0f}" if r is run else "" for r in runs],
                )
            spun = FLOOR_EXECUTOR_WORDS[floor.get("executor", "plain")]
            print(
                f"{run['mode']}: the nodes' steady CPU is {floor['steady_cpu_ratio']:.2f}x the bare"
                f" rclpy relays' (the floor: the same topology and QoS, {spun}, no work), "
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


FLOOR_EXECUTOR_WORDS = {
    "plain": "spun by rclpy.spin's default executor",
    "node": "spun by the nodes' own executors",
}


def register(verbs: Verbs) -> None:
    """Add the ``bench`` verb."""
    bench = verbs.add_parser("bench", help="per-frame cost of the streaming path")
    bench.add_argument("--model", help="checkpoint (default: packaged model)")
    bench.add_argument(
        "--frames",
        type=bounded_int(10, 1_000_000),
        default=3000,
        help="frames to time, 10 to 1e6 (default 3000)",
    )
    bench.add_argument(
        "--paced",
        action="store_true",
        help="time the stages one frame every 10 ms, as the nodes run them (caches cold), "
        "instead of back to back; --frames 500 takes about 20 s",
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
        "--voice",
        action="store_true",
        help="also play the voice at the simulated Pepper (fake ALAudioDevice over NAOqi's "
        "protocol) at execution latencies of 0 and 150 ms: the voice-to-motion offset's p5, p50 "
        "and p95 (--voice-duration seconds after calibration)",
    )
    bench.add_argument(
        "--voice-duration",
        type=bounded_float(10.0, 600.0),
        default=60.0,
        help="seconds of speech --voice measures at each latency (default 60)",
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
        help="run N busy-loop processes beside --graph, --console, --sim and --voice (other work "
        "on the machine), 0 to 16 (default 0)",
    )
    bench.add_argument(
        "--floor-executor",
        choices=tuple(FLOOR_EXECUTOR_WORDS),
        default="plain",
        help="executor of --graph's bare rclpy relays: rclpy.spin's default (plain, default) "
        "or the one each node spins in (node)",
    )
    bench.add_argument("--json", action="store_true", help="print the figures as JSON")
    bench.set_defaults(func=command_bench)
