"""``audio2pose run``: start the node graph, play a WAV or a bag into it, record its output.

The graph is the supervisor's (:func:`~audio2pose_ros.ros.supervisor.node_graph`), the playing
and recording :func:`~audio2pose_ros.ros.recorder.play_and_record`'s.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.ros.player import rclpy_session
from audio2pose_ros.ros.recorder import PlaybackResult, audio_source, play_and_record
from audio2pose_ros.ros.supervisor import NodeSupervisor, executable_command, node_graph
from audio2pose_ros.ros.voice_graph import voice_out_processes


def run_graph(
    play: Path | None,
    record: Path | None,
    params_file: Path | None,
    overrides: Sequence[str],
    log_dir: Path | None,
    rate: float = 1.0,
    single_process: bool = False,
    sim: bool = False,
    no_robot: bool = False,
    voice_out: str = "",
) -> PlaybackResult | None:
    """Start the graph; with ``play`` (a WAV or a bag) play it and return what was recorded.

    Without ``play`` the graph runs until Ctrl-C. ``single_process`` runs the three nodes in one
    process, ``sim`` adds the simulated Pepper, ``no_robot`` says no robot publishes
    ``joint_states`` (:func:`node_graph`).

    Raises:
        ConfigurationError: the supervisor gave up on a node (it refused its configuration, or
            failed again and again): the graph cannot command the robot, so it is stopped and
            the command fails instead of running on without that node.
    """
    messages = audio_source(play) if play is not None else None
    voice_nodes, sim_args = (
        voice_out_processes(voice_out, sim, executable_command) if voice_out else ({}, [])
    )
    with node_graph(
        params_file,
        overrides,
        log_dir,
        single_process=single_process,
        sim=sim,
        no_robot=no_robot,
        more_nodes=voice_nodes,
        sim_args=sim_args,
    ) as supervisor:
        if messages is None:
            try:
                while not supervisor.given_up:
                    time.sleep(0.2)
            except KeyboardInterrupt:
                return None
            raise _stopped(supervisor)
        with rclpy_session():
            result = play_and_record(messages, record, rate=rate)
        if supervisor.given_up:
            raise _stopped(supervisor)
        return result


def _stopped(supervisor: NodeSupervisor) -> ConfigurationError:
    """The error of a graph whose supervisor gave up on some nodes (named, sorted)."""
    names = ", ".join(sorted(supervisor.given_up))
    return ConfigurationError(f"the graph stopped: gave up on {names}: see the lines above")


def summarize(result: PlaybackResult) -> str:
    """Human-readable summary of a playback."""
    lines = [
        f"played {result.audio_s:.2f} s of audio in {result.chunks_sent} messages; recorded "
        f"{result.recorded_s:.2f} s (speech and {result.recorded_s - result.audio_s:.1f} s after)"
    ]
    for topic, count in result.counts.items():
        lines.append(f"  {topic}: {count} messages ({count / result.recorded_s:.0f} Hz)")
    if result.bag is not None:
        lines.append(f"recorded to {result.bag}")
    return "\n".join(lines)
