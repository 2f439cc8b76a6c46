"""``audio2pose bench --console``: the operator's voice through the console to ``/joint_angles``.

The graph and ``console_node`` run as processes (as ``audio2pose console`` starts them), with the
graph benchmark's parameters (:mod:`audio2pose_ros.ros.tools.graph_bench`: smoothing off, limits
wide open, so a command equals the raw pose it carries and identifies it). This process plays the
page: a WebSocket client that says hello, takes the floor and sends real speech in the page's 20 ms
chunks (16 kHz S16LE) in real time, each stamped when it is sent, as the page stamps a chunk when
its last sample is captured. A chunk completes two feature frames, hence one ``raw_trajectory``
message of two poses (:func:`pair_chunks` finds which); its latency runs from its stamp to the
arrival of the first ``/joint_angles`` command carrying one of them (``/joint_angles`` runs at 50
Hz, the poses at 100 Hz: every other pose is commanded).

Reported: that latency's p50 / p99, the console's own live estimate of it (what the page shows,
from ``/diagnostics``: :mod:`audio2pose_ros.console.latency`), how far the command lags the
chunk's sound on ``audio/audio`` (its arrival at a subscriber, as audio_common's ``audio_play``
receives it to play it at the robot; the player's own output buffering is not included), and
the console node's CPU per second of audio and resident memory while it streams. The chunk's
own 20 ms in the browser and the microphone's buffering come on top, as the 25 ms feature
window does.
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import socket
import tempfile
import threading
import time
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path

import aiohttp
import numpy as np
from audio_common_msgs.msg import AudioData
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.console.protocol import audio_frame
from audio2pose_ros.ros.console_runner import CONSOLE_NODE, console_command
from audio2pose_ros.ros.diagnosed_node import status_name
from audio2pose_ros.ros.player import rclpy_session, spin_until
from audio2pose_ros.ros.supervisor import GraphTimeoutError, node_graph
from audio2pose_ros.ros.tools.graph_bench import (
    MATCH_TOLERANCE_RAD,
    STEADY_SKIP_S,
    _bench_params,
    latency_stats,
)
from audio2pose_ros.ros.tools.process_stats import cpu_s, rss_mb
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

__all__ = ["ConsoleFigures", "console_report", "measure_console"]

CHUNK_S = 0.02  # what the page sends
CHUNK_SAMPLES = round(CHUNK_S * SAMPLE_RATE_HZ)
WARM_UP_CHUNKS = 50  # 1 s of speech before the measured stream: every link has matched
READY_TIMEOUT_S = 60.0


@dataclass
class ConsoleFigures:
    """What the console benchmark measured."""

    audio_s: float
    latency_ms: np.ndarray  # chunk stamp -> the /joint_angles command carrying its pose
    lag_behind_sound_ms: np.ndarray  # chunk on audio/audio -> that command
    chunks: int = 0  # chunks measured
    lost: int = 0  # of those, chunks never heard on audio/audio (best-effort audio under load)
    ambiguous: int = 0  # raw messages paired after several unanswered chunks (pair_chunks)
    live_estimate: dict[str, str] = field(default_factory=dict)  # console_node's own figures
    cpu_ms_per_audio_s: float = float("nan")
    cpu_percent: float = float("nan")
    rss_mb: float = float("nan")


class _Listener(Node):
    """Stamps raw pose messages and commands on arrival; keeps the console's diagnostics."""

    def __init__(self) -> None:
        super().__init__("audio2pose_console_bench")
        self.raw: list[tuple[float, np.ndarray]] = []
        self.sound: list[float] = []  # arrivals on audio/audio, as audio_play receives them
        self.sound_digests: list[bytes] = []  # which chunk each arrival carried
        self.commands: list[tuple[float, np.ndarray]] = []
        self.console_values: dict[str, str] = {}
        self.create_subscription(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), self._on_raw, 1000
        )
        self.create_subscription(
            JointAnglesWithSpeed, topics.absolute(topics.JOINT_ANGLES), self._on_command, 1000
        )
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 50)
        self.create_subscription(
            AudioData, topics.absolute(topics.AUDIO), self._on_sound, 1000, raw=True
        )

    def _on_sound(self, data: bytes) -> None:
        self.sound.append(time.time())
        # CDR: a 4-byte encapsulation header, then AudioData's uint8[] (uint32 length, bytes)
        size = int.from_bytes(data[4:8], "little")
        self.sound_digests.append(chunk_digest(data[8 : 8 + size]))

    def _on_raw(self, msg: JointTrajectory) -> None:
        now = time.time()
        self.raw.append((now, np.array([p.positions for p in msg.points])))

    def _on_command(self, msg: JointAnglesWithSpeed) -> None:
        self.commands.append((time.time(), np.asarray(msg.joint_angles, dtype=np.float64)))

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == status_name(f"/{CONSOLE_NODE}"):
                self.console_values = {kv.key: kv.value for kv in status.values}


class _Page(threading.Thread):
    """The page's part: hello, Talk, then chunks in real time, each stamped as it is sent."""

    def __init__(self, url: str, payload: bytes) -> None:
        super().__init__(name="console-bench-page", daemon=True)
        self.url = url
        self.payload = payload
        self.sent: list[float] = []  # stamps (s since the epoch) of every chunk, in order
        self.digests: list[bytes] = []  # each chunk's chunk_digest
        self.streaming = threading.Event()
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            asyncio.run(self._talk())
        except BaseException as exc:  # reported by measure_console
            self.error = exc

    async def _talk(self) -> None:
        step = 2 * CHUNK_SAMPLES
        async with (
            aiohttp.ClientSession() as session,
            session.ws_connect(
                f"{self.url.replace('http', 'ws', 1)}ws", origin=self.url[:-1]
            ) as ws,
        ):
            await ws.send_str(json.dumps({"type": "hello", "token": "", "name": "bench"}))
            await ws.send_str(json.dumps({"type": "talk", "on": True}))
            while True:
                message = json.loads((await ws.receive(timeout=10.0)).data)
                if message["type"] == "floor" and message["you"]:
                    break
            start = time.monotonic()
            for j, offset in enumerate(range(0, len(self.payload), step)):
                delay = start + j * CHUNK_S - time.monotonic()
                if delay > 0:
                    await asyncio.sleep(delay)
                if j == WARM_UP_CHUNKS:
                    self.streaming.set()
                stamp = time.time()
                pcm = self.payload[offset : offset + step]
                await ws.send_bytes(audio_frame(j, stamp * 1e3, pcm))
                self.sent.append(stamp)
                self.digests.append(chunk_digest(pcm))
            await ws.send_str(json.dumps({"type": "talk", "on": False}))


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _serves(url: str) -> bool:
    """Whether the console answers ``url``."""
    try:
        with urllib.request.urlopen(url, timeout=0.5) as response:
            return bool(response.status == 200)
    except OSError:
        return False


def chunk_digest(pcm: bytes) -> bytes:
    """A short fingerprint of one chunk's PCM, to recognise it on audio/audio."""
    return hashlib.blake2b(pcm, digest_size=8).digest()


def match_heard(sent: list[bytes], heard: list[bytes]) -> list[int | None]:
    """For each chunk heard on audio/audio, the index of the chunk sent that it is, or None.

    Chunks arrive in order, some may be lost (audio is best effort), and equal chunks (digital
    silence) occur: each heard chunk is the next sent chunk with its content after the last one
    matched.
    """
    out: list[int | None] = []
    later: dict[bytes, list[int]] = {}
    for i in range(len(sent) - 1, -1, -1):  # per content, its indices in order (popped)
        later.setdefault(sent[i], []).append(i)
    after = -1
    for digest in heard:
        indices = later.get(digest, [])
        while indices and indices[-1] <= after:
            indices.pop()
        if not indices:
            out.append(None)
            continue
        after = indices.pop()
        out.append(after)
    return out


def pair_chunks(heard: list[float], raw_s: list[float]) -> tuple[list[tuple[int, int]], int]:
    """Pair raw_trajectory messages with the chunks that caused them, by arrival time.

    A raw message belongs to the newest chunk heard on audio/audio before it that has none yet:
    the graph answers a chunk within a few ms, well inside the 20 ms until the next one, and a
    chunk that the features node dropped has no answer. A raw message preceded by several
    unanswered chunks is counted as ambiguous: either those were dropped, or the graph ran more
    than a chunk behind and its latency is underestimated by multiples of 20 ms.

    Returns:
        ``(chunk index, raw index)`` pairs, and the number of ambiguous ones.
    """
    pairs: list[tuple[int, int]] = []
    ambiguous = 0
    unanswered = 0  # the oldest chunk without a raw message
    newest = -1
    for k, arrival in enumerate(raw_s):
        while newest + 1 < len(heard) and heard[newest + 1] <= arrival:
            newest += 1
        if newest < unanswered:
            continue  # no chunk waits for an answer: not caused by a measured chunk
        ambiguous += newest > unanswered
        pairs.append((newest, k))
        unanswered = newest + 1
    return pairs, ambiguous


def _first_commands(
    raw: list[tuple[float, np.ndarray]], commands: list[tuple[float, np.ndarray]]
) -> list[float | None]:
    """Per raw message, the arrival of the first command (in order) equal to one of its poses."""
    out: list[float | None] = []
    c = 0
    for _, poses in raw:
        window = commands[c : c + 100]
        match = next(
            (
                i
                for i, (_, command) in enumerate(window)
                if np.abs(poses - command).max(axis=1).min() <= MATCH_TOLERANCE_RAD
            ),
            None,
        )
        out.append(None if match is None else window[match][0])
        if match is not None:
            c += match + 1
    return out


def measure_console(speech_16k: np.ndarray, duration_s: float = 60.0) -> ConsoleFigures:
    """Stream ``duration_s`` of ``speech_16k`` (repeated) through the console and measure it.

    Raises:
        GraphTimeoutError: the graph or the console did not answer within 60 s.
    """
    n_chunks = WARM_UP_CHUNKS + int(duration_s / CHUNK_S)
    audio = np.resize(speech_16k, n_chunks * CHUNK_SAMPLES)
    payload = encode_pcm(audio, S16LE_MONO_16K)
    with tempfile.TemporaryDirectory() as tmp, rclpy_session():
        directory = Path(tmp)
        params = _bench_params(directory)
        port = _free_port()
        command = console_command(params, {"port": port}, directory)
        listener = _Listener()
        with node_graph(
            params,
            log_dir=directory / "logs",
            more_nodes={CONSOLE_NODE: command},
            no_robot=True,  # the bench takes the commands: no robot reports its pose
        ) as graph:
            deadline = time.monotonic() + READY_TIMEOUT_S
            if not spin_until(listener, deadline, lambda: bool(listener.commands)):
                raise GraphTimeoutError("no /joint_angles command within 60 s (see the logs)")
            url = f"http://127.0.0.1:{port}/"
            if not spin_until(listener, deadline, lambda: _serves(url)):
                raise GraphTimeoutError(f"the console did not serve {url} within 60 s")
            pid = graph.processes[CONSOLE_NODE].pid
            page = _Page(url, payload)
            page.start()
            if not spin_until(listener, deadline, page.streaming.is_set):
                raise GraphTimeoutError(f"the console did not take the audio: {page.error!r}")
            spin_until(listener, time.monotonic() + STEADY_SKIP_S)
            cpu_start, cpu_from = cpu_s(pid), time.monotonic()
            spin_until(listener, time.monotonic() + duration_s + 5.0, lambda: not page.is_alive())
            cpu_used, cpu_span = cpu_s(pid) - cpu_start, time.monotonic() - cpu_from
            memory = rss_mb(pid)
            spin_until(listener, time.monotonic() + 1.5)  # the live estimate is published
        listener.destroy_node()
    if page.error is not None:
        raise GraphTimeoutError(f"the page's stream failed: {page.error!r}")
    which = match_heard(page.digests, listener.sound_digests)
    pairs, ambiguous = pair_chunks(listener.sound, [t for t, _ in listener.raw])
    answered = _first_commands(listener.raw, listener.commands)
    latency, lag = [], []
    for j, k in pairs:
        command_s, i = answered[k], which[j]
        if i is not None and i >= WARM_UP_CHUNKS and command_s is not None:
            latency.append((command_s - page.sent[i]) * 1e3)
            lag.append((command_s - listener.sound[j]) * 1e3)
    measured = [i for i in which if i is not None and i >= WARM_UP_CHUNKS]
    return ConsoleFigures(
        audio_s=(len(page.sent) - WARM_UP_CHUNKS) * CHUNK_S,
        latency_ms=np.array(latency),
        lag_behind_sound_ms=np.array(lag),
        chunks=len(page.sent) - WARM_UP_CHUNKS,
        lost=len(page.sent) - WARM_UP_CHUNKS - len(set(measured)),
        ambiguous=ambiguous,
        live_estimate={
            k.removeprefix("latency_"): v
            for k, v in listener.console_values.items()
            if k.startswith("latency_")
        },
        cpu_ms_per_audio_s=1e3 * cpu_used / max(cpu_span, 1e-9),
        cpu_percent=100.0 * cpu_used / max(cpu_span, 1e-9),
        rss_mb=memory,
    )


def console_report(figures: ConsoleFigures) -> dict[str, object]:
    """Summary statistics (also the ``--json`` output)."""
    return {
        "audio_s": figures.audio_s,
        "chunks": figures.chunks,
        "chunks_lost": figures.lost,
        "ambiguous_pairs": figures.ambiguous,
        "latency_browser_to_joint_angles": latency_stats(figures.latency_ms),
        "motion_lag_behind_sound": latency_stats(figures.lag_behind_sound_ms),
        "console_live_estimate_ms": figures.live_estimate,
        "console_node_cpu_ms_per_audio_s": figures.cpu_ms_per_audio_s,
        "console_node_cpu_percent": figures.cpu_percent,
        "console_node_rss_mb": figures.rss_mb,
    }
