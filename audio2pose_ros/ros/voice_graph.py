"""``--voice-out``: the voice node's process beside the graph, and what the simulated Pepper serves.

``audio2pose run`` and ``audio2pose console`` take ``--voice-out naoqi:tcp://HOST:PORT``
(Pepper's loudspeakers through NAOqi), ``--voice-out topic`` (``audio_out`` for audio_common's
audio_play) or, with ``--sim``, ``--voice-out naoqi`` alone: the simulated Pepper then serves
its fake ALAudioDevice on a free port of 127.0.0.1 and the voice node is pointed at it. A NAOqi
address on 127.0.0.1 with ``--sim`` is served by the simulated Pepper too.
"""

from __future__ import annotations

import socket
from collections.abc import Callable

from audio2pose_ros.errors import UsageError
from audio2pose_ros.voice.naoqi import parse_voice_out

__all__ = ["VOICE_NODE", "free_local_url", "voice_out_processes"]

VOICE_NODE = "voice_out_node"
LOOPBACK = "tcp://127.0.0.1:"


def free_local_url() -> str:
    """``tcp://127.0.0.1:PORT`` with a port free now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return f"{LOOPBACK}{probe.getsockname()[1]}"


def voice_out_processes(
    voice_out: str,
    sim: bool,
    command: Callable[[str], list[str]],
    sim_latencies_s: tuple[float, float] | None = None,
) -> tuple[dict[str, list[str]], list[str]]:
    """The voice node's command and the simulated Pepper's extra ROS arguments.

    Args:
        voice_out: the ``--voice-out`` value.
        sim: whether the simulated Pepper runs.
        command: the command of a node executable, by name.
        sim_latencies_s: the simulated Pepper's (execution, loudspeaker) latencies, if not its
            defaults.

    Raises:
        UsageError: the value is not understood, or ``naoqi`` without an address and no
            ``--sim``.
    """
    sim_args: list[str] = []
    if voice_out == "naoqi":
        if not sim:
            raise UsageError("--voice-out naoqi needs NAOqi's address (naoqi:tcp://HOST:9559)")
        voice_out = f"naoqi:{free_local_url()}"
    try:
        destination = parse_voice_out(voice_out)
    except Exception as exc:
        raise UsageError(f"--voice-out: {exc}") from None
    if sim and destination.kind == "naoqi" and destination.url.startswith(LOOPBACK):
        sim_args += ["-p", f"naoqi_url:={destination.url}"]
    if sim and sim_latencies_s is not None:
        execution, loudspeaker = sim_latencies_s
        sim_args += [
            "-p",
            f"execution_latency_s:={execution}",
            "-p",
            f"loudspeaker_latency_s:={loudspeaker}",
        ]
    voice = [*command(VOICE_NODE), "--ros-args", "-p", f"voice_out:={voice_out}"]
    return {VOICE_NODE: voice}, sim_args
