"""``audio2pose render``: a video (and a Foxglove bag) of what the robot would do for a WAV.

The trajectory comes from offline synthesis with a checkpoint, from a bag recorded by
``audio2pose run --record``, or, side by side, from two checkpoints or from a checkpoint and a
data set clip's ground truth; ``--executed`` adds, beside the first, what a simulated Pepper does
with it.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from audio2pose_ros.cli.options import (
    MAX_SEED,
    NamedPath,
    Verbs,
    add_force,
    bag_dir,
    bag_inputs,
    bounded_float,
    bounded_int,
    check_apart,
    input_bag,
    input_dir,
    input_file,
    output_file,
    remove_bag_dir,
)
from audio2pose_ros.cli.style_commands import add_style_options
from audio2pose_ros.errors import UsageError
from audio2pose_ros.viz.render import MAX_FPS, MAX_VIEW_PX, MIN_SIZE_PX, RenderSettings

# Each size option and the RenderSettings field it sets (the field's bounds are the option's).
SIZE_OPTIONS = {
    "--view-width": "view_width_px",
    "--view-height": "view_height_px",
    "--curves-height": "curves_height_px",
}


def _bag_path(args: argparse.Namespace) -> Path:
    out = Path(args.output)
    return Path(args.mcap) if args.mcap else out.with_name(f"{out.stem}_mcap")


def _inputs(args: argparse.Namespace) -> list[NamedPath]:
    """Every file or folder the render reads, described by the option that names it."""
    named: list[NamedPath] = [
        (f"the input {args.wav}", args.wav),
        (f"the input --model {args.model}", args.model),
        (f"the input --data {args.data}", args.data),
        *((f"the input --compare {c}", c) for c in args.compare or []),
    ]
    return [*named, *bag_inputs("the input --bag", args.bag)]


def _check_outputs(args: argparse.Namespace) -> Path:
    """Check the MP4 and the bag folder may be written; return the bag folder.

    Neither may be, contain or lie inside an input (a bag folder replaced with ``--force`` is
    deleted before the new one is written; a video written into a bag folder spoils it), and the
    bag may not be, contain or lie inside the MP4. This runs before any work starts.

    Raises:
        UsageError: naming the output, the path it overlaps and how.
    """
    inputs = _inputs(args)
    video = output_file(args.output, "-o", inputs=[path for _, path in inputs], force=args.force)
    check_apart(video, "-o", inputs, "another output file")
    bag_path = _bag_path(args)
    option = "--mcap" if args.mcap else "--mcap (default OUT_mcap)"
    check_apart(
        bag_path, option, [*inputs, (f"the output -o {video}", video)], "another --mcap folder"
    )
    return bag_dir(bag_path, option, args.force)


def command_render(args: argparse.Namespace) -> int:
    """Render the requested trajectories to an MP4 with audio; write the first one as MCAP."""
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.cli.style_commands import model_and_style_settings
    from audio2pose_ros.motion.limits import LimitSettings
    from audio2pose_ros.offline.trajectory import (
        bag_trajectory,
        clip_trajectory,
        executed_trajectory,
        synthesized_trajectory,
    )
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.robot.description import load_robot
    from audio2pose_ros.robot.kinematics import RobotKinematics
    from audio2pose_ros.viz.foxglove_bag import write_foxglove_bag
    from audio2pose_ros.viz.render import render_video

    if (args.data is None) != (args.clip is None):
        raise UsageError("--data and --clip go together")
    if (args.wav is None) == (args.data is None):
        raise UsageError("give either FILE.wav or --data DIR --clip ID")
    for name in ("view_width", "view_height", "curves_height"):
        if getattr(args, name) % 2:
            raise UsageError(f"--{name.replace('_', '-')} {getattr(args, name)} must be even")
    bag_out = _check_outputs(args)
    for checkpoint in [
        *([args.model] if args.model and not Path(args.model).is_dir() else []),
        *(args.compare or []),
    ]:
        if checkpoint:
            input_file(checkpoint, "checkpoint")
    if args.bag:
        input_bag(args.bag)
    if args.data:
        input_dir(args.data, "data set folder")
    settings = RenderSettings(
        fps=args.fps,
        view_width_px=args.view_width,
        view_height_px=args.view_height,
        curves_height_px=args.curves_height,
        side_view=args.side,
    )
    robot = load_robot()
    model, style = model_and_style_settings(args, robot)
    if args.data is not None:
        truth, audio = clip_trajectory(args.data, args.clip, robot)
        trajectories = [synthesized_trajectory(model, audio, robot, style, seed=args.seed), truth]
        if args.beside_default:
            default = synthesized_trajectory(
                default_checkpoint_path(), audio, robot, label="default model", seed=args.seed
            )
            trajectories = [truth, default, replace(trajectories[0], label="styled model")]
    else:
        audio, _ = read_wav(input_file(args.wav, "WAV file"))
        if args.bag:
            trajectories = [bag_trajectory(args.bag, robot)]
        else:
            trajectories = (
                [synthesized_trajectory(c, audio, robot, seed=args.seed) for c in args.compare]
                if args.compare
                else [synthesized_trajectory(model, audio, robot, style, seed=args.seed)]
            )
            if args.compare:  # the two checkpoints may share a file name
                trajectories = [
                    replace(t, label=f"{tag}: {t.label}")
                    for tag, t in zip("AB", trajectories, strict=True)
                ]
    if args.executed:  # the first trajectory as a simulated Pepper executes it, beside it
        execution = executed_trajectory(trajectories[0], robot, LimitSettings().velocity_fraction)
        trajectories = [trajectories[0], execution.trajectory]
        print(
            f"simulated Pepper: commanded vs executed, largest joint error median "
            f"{np.degrees(np.median(execution.error_rad)):.2f} deg, p95 "
            f"{np.degrees(np.percentile(execution.error_rad, 95)):.2f} deg; "
            f"self-collisions executed: {execution.self_collision_steps} steps"
        )
    kinematics = RobotKinematics()
    result = render_video(
        args.output,
        trajectories,
        audio,
        kinematics,
        {j.name: j.group for j in robot.joints},
        settings,
        progress=not args.no_progress,
    )
    print(
        f"wrote {result.path}: {result.n_frames} frames, {result.duration_s:.2f} s at "
        f"{settings.fps:g} fps, rendered in {result.wall_time_s:.1f} s"
    )
    remove_bag_dir(bag_out)  # an old bag, replaced with --force now that the video is written
    bag = write_foxglove_bag(bag_out, trajectories[0], kinematics)
    print(f"wrote {bag} (/robot_description, /joint_states, /tf of {trajectories[0].label})")
    return 0


def register(verbs: Verbs) -> None:
    """Add the ``render`` verb to the ``audio2pose`` parser."""
    render = verbs.add_parser(
        "render", help="video of the robot moving for a WAV (+ MCAP bag for Foxglove)"
    )
    render.add_argument("wav", nargs="?", metavar="FILE.wav", help="speech (not with --data)")
    render.add_argument("-o", "--output", required=True, metavar="OUT.mp4")
    add_force(render)
    render.add_argument(
        "--model", help="checkpoint or personal model folder (default: packaged model)"
    )
    add_style_options(render)
    render.add_argument(
        "--beside-default",
        action="store_true",
        help="with --data: the person, the default model and the styled --model side by side",
    )
    source = render.add_mutually_exclusive_group()
    source.add_argument("--bag", help="render the joint angles recorded in this rosbag2")
    source.add_argument(
        "--compare", nargs=2, metavar=("CKPT_A", "CKPT_B"), help="two models side by side"
    )
    source.add_argument("--data", metavar="DIR", help="data set: --model next to a clip's truth")
    render.add_argument("--clip", metavar="ID", help="clip id in the --data set")
    render.add_argument(
        "--seed",
        type=bounded_int(0, MAX_SEED),
        default=0,
        help="noise seed of a sampling model (default 0)",
    )
    render.add_argument("--side", action="store_true", help="add a side view")
    render.add_argument(
        "--executed",
        action="store_true",
        help="beside the (first) trajectory, the robot as a simulated Pepper executes it "
        "(setAngles at the filter's default speed)",
    )
    render.add_argument(
        "--mcap", metavar="PATH", help="bag directory to write (default: OUT_mcap next to OUT.mp4)"
    )
    defaults = RenderSettings()
    render.add_argument(
        "--fps",
        type=bounded_float(0.0, MAX_FPS, low_inclusive=False),
        default=defaults.fps,
        help=f"frame rate in (0, {MAX_FPS:g}] (%(default)s)",
    )
    for option, field in SIZE_OPTIONS.items():
        low = MIN_SIZE_PX[field]
        render.add_argument(
            option,
            type=bounded_int(low, MAX_VIEW_PX),
            default=getattr(defaults, field),
            help=f"even px, {low} to {MAX_VIEW_PX} (%(default)s)",
        )
    render.add_argument("--no-progress", action="store_true", help="no progress bar")
    render.set_defaults(func=command_render)
