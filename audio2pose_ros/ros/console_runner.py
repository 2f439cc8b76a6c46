"""``audio2pose console``: the operator's console next to the node graph, without a ROS distro.

What ``ros2 launch audio2pose_ros pepper.launch.py console:=true`` does, for machines without a
distro: the three nodes (:func:`~audio2pose_ros.ros.supervisor.node_graph`) and ``console_node``,
each a supervised process reading the same parameters file; the console's own settings given
on the command line are written to a parameters file of their own that names the node, so
they win over the file's ``console_node`` section (as :func:`graph.overrides_file` does for the
graph). Without the graph (``--no-graph``), only the console runs, for a graph started
elsewhere on this machine's DDS domain.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path

import yaml

from audio2pose_ros.console.access import resolve_access
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.offline.parameters_file import node_parameters
from audio2pose_ros.parameters import settings_from
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.launch_support import CONSOLE_EXECUTABLE
from audio2pose_ros.ros.supervisor import (
    HeartbeatMonitor,
    NodeSupervisor,
    executable_command,
    node_graph,
)
from audio2pose_ros.ros.voice_graph import voice_out_processes

__all__ = ["CONSOLE_NODE", "check_console_settings", "console_command", "run_console"]

CONSOLE_NODE = CONSOLE_EXECUTABLE


def console_command(
    params_file: Path | None, values: Mapping[str, object], directory: Path
) -> list[str]:
    """The command line of ``console_node`` with ``values`` over the parameters file.

    Args:
        params_file: ROS parameter YAML (default: the package's config/pepper.yaml).
        values: console parameters (``host``, ``port``, ``token``, ...) that win over the file.
        directory: where the parameters file of ``values`` is written.
    """
    params = params_file or share_path("config", "pepper.yaml")
    command = [*executable_command(CONSOLE_NODE), "--ros-args", "--params-file", str(params)]
    if values:
        path = directory / "console_parameters.yaml"
        path.write_text(
            yaml.safe_dump({CONSOLE_NODE: {"ros__parameters": dict(values)}}), encoding="utf-8"
        )
        command += ["--params-file", str(path)]
    return command


def check_console_settings(params_file: Path | None, values: Mapping[str, object]) -> None:
    """Check the console's settings as console_node will, before any process starts.

    The settings are the parameters file's ``console_node`` parameters (its ``/**`` section,
    then its own, as rcl resolves them), then ``values`` over them. The file is read as the
    package's other parameters files are
    (:func:`~audio2pose_ros.offline.parameters_file.node_parameters`: bounded, UTF-8, no YAML
    aliases, sections that are mappings).

    Raises:
        ConfigurationError: an unreadable or malformed file, a refused value, bind, certificate
            or token (one line).
    """
    params = params_file or share_path("config", "pepper.yaml")
    try:
        section = node_parameters(params, CONSOLE_NODE)
    except InputError as exc:
        raise ConfigurationError(str(exc)) from None
    resolve_access(settings_from(ConsoleSettings, {**section, **values}))


def run_console(
    params_file: Path | None,
    values: Mapping[str, object],
    directory: Path,
    overrides: Sequence[str] = (),
    log_dir: Path | None = None,
    graph: bool = True,
    single_process: bool = False,
    sim: bool = False,
    voice_out: str = "",
    no_robot: bool = False,
) -> None:
    """Run the console (and the graph) until Ctrl-C or until every process has given up.

    ``sim`` adds the simulated Pepper (what the page shows of the room is then its camera and
    microphones) and ``voice_out`` the voice node to the graph
    (:func:`~audio2pose_ros.ros.voice_graph.voice_out_processes`); ``no_robot``: no robot publishes
    ``joint_states`` (:func:`node_graph`).
    """
    command = console_command(params_file, values, directory)
    voice_nodes, sim_args = (
        voice_out_processes(voice_out, sim, executable_command) if voice_out else ({}, [])
    )
    with ExitStack() as stack:
        if graph:
            supervisor = stack.enter_context(
                node_graph(
                    params_file,
                    overrides,
                    log_dir,
                    single_process=single_process,
                    sim=sim,
                    more_nodes={CONSOLE_NODE: command, **voice_nodes},
                    sim_args=sim_args,
                    no_robot=no_robot,
                )
            )
        else:
            supervisor = NodeSupervisor({CONSOLE_NODE: command}, log_dir)
            stack.callback(supervisor.stop)
            supervisor.start()
            stack.callback(HeartbeatMonitor(supervisor).close)
        try:
            while supervisor.running and CONSOLE_NODE not in supervisor.given_up:
                time.sleep(0.2)
        except KeyboardInterrupt:
            return
        if CONSOLE_NODE in supervisor.given_up:
            raise ConfigurationError("console_node stopped: see its line above")
