"""``audio2pose console``: the operator's web console and the node graph (``console_runner``)."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from audio2pose_ros.cli.options import (
    Verbs,
    add_voice_out_option,
    bounded_int,
    check_robot_options,
    input_file,
)
from audio2pose_ros.cli.style_commands import add_style_options, graph_overrides


def command_console(args: argparse.Namespace) -> int:
    """Start the graph and the console; run until Ctrl-C."""
    from audio2pose_ros.ros.console_runner import check_console_settings, run_console

    values: dict[str, object] = {}
    for name in ("host", "port", "token"):
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    for name in ("certfile", "keyfile"):
        if getattr(args, name):
            values[name] = str(input_file(getattr(args, name), f"--{name}").resolve())
    check_robot_options(args)
    params = input_file(args.params_file, "parameters file") if args.params_file else None
    overrides = graph_overrides(args)
    check_console_settings(params, values)  # a refused bind or token stops before anything runs
    with tempfile.TemporaryDirectory(prefix="audio2pose_console_") as tmp:
        run_console(
            params,
            values,
            Path(tmp),
            overrides,
            Path(args.log_dir) if args.log_dir else None,
            graph=not args.no_graph,
            single_process=args.single_process,
            no_robot=args.no_robot,
            sim=args.sim,
            voice_out=args.voice_out or ("naoqi" if args.sim else ""),
        )
    return 0


def register(verbs: Verbs) -> None:
    """Add ``audio2pose console``."""
    console = verbs.add_parser(
        "console",
        help="the operator's web console (talk, 3D view, stop) with the node graph",
        description="Start the node graph and the operator's web console; open the address it "
        "prints and press Talk. It listens on 127.0.0.1 unless --host says otherwise; any other "
        "address needs --certfile, --keyfile and a token (made and printed if not given).",
    )
    console.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    console.add_argument(
        "--port", type=bounded_int(0, 65535), help="TCP port (default 8765; 0: any free port)"
    )
    console.add_argument(
        "--token", help="access token (default: none on localhost, a random one on a network)"
    )
    console.add_argument("--certfile", help="PEM certificate for HTTPS")
    console.add_argument("--keyfile", help="PEM private key of --certfile")
    console.add_argument(
        "--no-graph", action="store_true", help="only the console: the graph runs elsewhere"
    )
    console.add_argument(
        "--model", help="checkpoint or personal model folder (default: packaged model)"
    )
    add_style_options(console)
    console.add_argument("--params-file", help="ROS parameter YAML (default: config/pepper.yaml)")
    console.add_argument("--log-dir", help="write each node's output to <dir>/<node>.log")
    console.add_argument(
        "--single-process", action="store_true", help="run the three graph nodes in one process"
    )
    console.add_argument(
        "--no-robot",
        action="store_true",
        help="no robot publishes joint_states (the 3D view only): start from the saved pose or "
        "neutral instead of waiting for the robot's measured pose",
    )
    console.add_argument(
        "--sim",
        action="store_true",
        help="also run a simulated Pepper (pybullet): the page shows its moves, its head "
        "camera's view of a small room and plays its microphones",
    )
    add_voice_out_option(console)
    console.set_defaults(func=command_console)
