"""``audio2pose bench --voice``: the voice against the motion at the simulated Pepper.

The graph runs with the simulated Pepper (emulated execution and loudspeaker latencies) and
the voice node sending to its fake ALAudioDevice over NAOqi's real protocol. An observer
(:class:`VoiceObserver`) plays speech into the graph as the console does (20 ms chunks) while
the voice node calibrates: at least ``calibrate_s``, and on until the node reports itself
calibrated on /diagnostics (every latency measured, the voice's delay where they call for), at
most ``MAX_CALIBRATION_S``. It then records ``duration_s`` of what the robot reports: the raw
poses, the measured ``joint_states`` and the robot's microphones. The offset ``motion - heard``
is measured from those in 2 s windows (:func:`~audio2pose_ros.voice.offset.window_offsets`),
independently of the voice node's own estimates, and summarised as p5 / p50 / p95.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from audio_common_msgs.msg import AudioData
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import AudioBuffer
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    BagMessage,
    Chunking,
    audio_messages,
)
from audio2pose_ros.errors import Audio2PoseError
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.player import MessagePlayer, rclpy_session, silence_message, spin_until
from audio2pose_ros.ros.supervisor import NodeSupervisor, executable_command, node_graph
from audio2pose_ros.ros.voice_graph import VOICE_NODE, voice_out_processes
from audio2pose_ros.timebase import FRAME_PERIOD_S, SAMPLE_RATE_HZ
from audio2pose_ros.voice.offset import VoiceMotionRecord, percentiles_ms, window_offsets

__all__ = [
    "BENCH_EXECUTION_LATENCIES_S",
    "VoiceBenchResult",
    "VoiceObserver",
    "measure_voice",
    "voice_report",
]

BENCH_EXECUTION_LATENCIES_S = (0.0, 0.15)  # the simulated robot's, measured by the bench
CHUNK_BYTES = 640  # 20 ms of 16 kHz S16LE, as the console sends the operator's voice
READY_TIMEOUT_S = 90.0  # the graph, the simulated robot and the NAOqi link come up within this
MAX_CALIBRATION_S = 60.0  # speech played at most while the voice node calibrates


@dataclass
class VoiceBenchResult:
    """One run of the voice against the motion."""

    execution_latency_s: float
    loudspeaker_latency_s: float
    audio_s: float
    offsets_s: list[float]
    samples_published: int  # voice samples the observer published (warm-up included)
    calibrated_after_s: float | None  # speech played until calibrated (None: it never was)
    voice_node: dict[str, str] = field(default_factory=dict)  # its last /diagnostics values
    # the voice node's delay in force, the delay asked for and the loudspeaker's queue (ms), at
    # each of its heartbeats while the measured speech played (the estimate may move later, with
    # no voice to follow it)
    delays_while_playing_ms: list[tuple[int, int, int]] = field(default_factory=list)
    robot: dict[str, str] = field(default_factory=dict)  # the simulated Pepper's
    restarts: int = 0

    @property
    def percentiles_ms(self) -> tuple[float, float, float]:
        """p5, p50, p95 of ``motion - heard`` (ms)."""
        return percentiles_ms(self.offsets_s)


class VoiceObserver(Node):
    """Plays the voice in, records what the robot reports (see the module text)."""

    def __init__(self) -> None:
        super().__init__("audio2pose_voice_observer")
        self.names = list(load_robot().names)
        self.record = VoiceMotionRecord()
        self.recording = False  # the motion, the voice and what was heard are kept
        self.playing = False  # the measured speech is being published
        self.samples_published = 0
        self.raw_seen = 0
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.delays_while_playing_ms: list[tuple[int, int, int]] = []
        self.levels: dict[str, list[int]] = {}
        self.player = MessagePlayer(
            self, [(AUDIO_TOPIC, AUDIO_DATA_TYPE), (AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE)]
        )
        best_effort = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(
            JointTrajectory, topics.absolute(topics.RAW_TRAJECTORY), self.on_raw, 100
        )
        self.create_subscription(
            JointState, topics.absolute(topics.JOINT_STATES), self.on_measured, 100
        )
        self.create_subscription(
            AudioBuffer, topics.absolute(topics.ROBOT_MICROPHONES), self.on_heard, best_effort
        )
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self.on_diagnostics, 100)

    def _row(self, names: list[str], values: list[float]) -> np.ndarray | None:
        index = {name: i for i, name in enumerate(names)}
        if any(name not in index for name in self.names):
            return None
        return np.array([values[index[name]] for name in self.names])

    def on_raw(self, msg: JointTrajectory) -> None:
        """A pose message: its arrival and its poses (at the stamp, 10 ms apart)."""
        self.raw_seen += 1
        if not self.recording:
            return
        self.record.raw_arrivals.append(time.time())
        stamp = stamp_s(msg.header.stamp)
        for i, point in enumerate(msg.points):
            row = self._row(list(msg.joint_names), list(point.positions))
            if row is not None:
                self.record.raw_poses.append((stamp + i * FRAME_PERIOD_S, row))

    def on_measured(self, msg: JointState) -> None:
        """The robot's measured joint states."""
        row = self._row(list(msg.name), list(msg.position))
        if self.recording and row is not None:
            stamp = stamp_s(msg.header.stamp)
            self.record.measured.append((stamp, row))

    def on_heard(self, msg: AudioBuffer) -> None:
        """The robot's microphones, stamped with their last sample."""
        if not self.recording:
            return
        channels = max(1, len(msg.channel_map))
        mono = np.asarray(msg.data, dtype=np.int16).reshape(-1, channels).mean(axis=1) / 32768
        stamp = stamp_s(msg.header.stamp)
        self.record.heard_rate_hz = int(msg.frequency)
        self.record.heard.append((stamp - (len(mono) - 1) / msg.frequency, mono))

    def on_diagnostics(self, msg: DiagnosticArray) -> None:
        """The last key-values and every level of each node."""
        for status in msg.status:
            name = status.name.rsplit("/", 1)[-1]
            values = self.diagnostics[name] = {kv.key: kv.value for kv in status.values}
            if self.playing and name == VOICE_NODE and "voice_delay_target_ms" in values:
                self.delays_while_playing_ms.append(
                    (
                        int(values["voice_delay_ms"]),
                        int(values["voice_delay_target_ms"]),
                        int(values["loudspeaker_queue_ms"]),
                    )
                )
            self.levels.setdefault(name, []).append(int.from_bytes(status.level, "little"))

    def on_publish(self, message: BagMessage) -> None:
        """Count (and, while recording, keep) each voice chunk published."""
        if message.topic != AUDIO_TOPIC:
            return
        data = bytes(deserialize_message(message.data, AudioData).data)
        self.samples_published += len(data) // 2
        if self.recording:
            samples = np.frombuffer(data, dtype="<i2") / 32768.0
            self.record.voice.append((time.time(), samples))

    def publish(self, message: BagMessage) -> None:
        """Publish one message now (counted as :meth:`on_publish` says)."""
        self.player.publish(message)
        self.on_publish(message)

    def wait(self, condition: object, timeout_s: float, what: str) -> None:
        """Spin until ``condition()``; raise naming ``what`` after ``timeout_s``."""
        if not spin_until(self, time.monotonic() + timeout_s, condition):  # type: ignore[arg-type]
            raise Audio2PoseError(f"voice bench: {what} within {timeout_s:.0f} s (see the logs)")

    def warm_up(self) -> None:
        """Send a frame of silence every 20 ms until poses come back (each link has matched)."""
        silence = silence_message(AUDIO_TOPIC)
        deadline = time.monotonic() + READY_TIMEOUT_S
        while not self.raw_seen:
            if time.monotonic() > deadline:
                raise Audio2PoseError("voice bench: the graph did not answer (see the logs)")
            self.publish(silence)
            spin_until(self, time.monotonic() + 0.02)

    def voice_ready(self) -> bool:
        """The voice node is connected to NAOqi and decodes the voice's format."""
        values = self.diagnostics.get(VOICE_NODE, {})
        connected = values.get("naoqi_connected") == "True"
        return connected and not values.get("format", "no").startswith("no ")

    def calibrated(self) -> bool:
        """The voice node's last heartbeat says it is calibrated."""
        return self.diagnostics.get(VOICE_NODE, {}).get("calibrated") == "True"

    def calibrate(self, messages: list[BagMessage], at_least_s: float) -> float | None:
        """Play ``messages`` at their pace: ``at_least_s``, then until :meth:`calibrated`.

        Returns:
            The seconds of speech played until calibrated, or None when all were played first.
        """
        start, first_ns = time.monotonic(), messages[0].timestamp_ns
        for message in messages:
            played_s = (message.timestamp_ns - first_ns) * 1e-9
            spin_until(self, start + played_s)
            self.publish(message)
            if played_s >= at_least_s and self.calibrated():
                return played_s
        return None


def speech_messages(speech: np.ndarray, seconds: float) -> list[BagMessage]:
    """``seconds`` of ``speech`` (looped) in 20 ms AudioData chunks with periodic AudioInfo."""
    n = int(seconds * SAMPLE_RATE_HZ)
    signal = np.resize(speech, n)
    return audio_messages(
        signal, Chunking(min_bytes=CHUNK_BYTES, max_bytes=CHUNK_BYTES, jitter_s=0)
    )


def measure_voice(
    speech: np.ndarray,
    execution_latency_s: float,
    loudspeaker_latency_s: float = 0.05,
    duration_s: float = 60.0,
    calibrate_s: float = 20.0,
    log_dir: Path | None = None,
    observe: Callable[[VoiceObserver], None] | None = None,
) -> VoiceBenchResult:
    """Run the graph, the simulated Pepper and the voice node; measure the offset at the robot.

    Args:
        speech: 16 kHz mono speech (looped to length).
        execution_latency_s: the simulated Pepper's motion execution latency (s).
        loudspeaker_latency_s: its loudspeaker latency (s).
        duration_s: speech measured after calibration (s).
        calibrate_s: speech the voice node calibrates on first, at least (s).
        log_dir: where the node logs go (default: a temporary directory, so that the nodes'
            output, libqi's included, stays out of the bench's own, such as its JSON).
        observe: called with the observer between calibration and measurement (tests).

    Raises:
        Audio2PoseError: the graph, the robot or the NAOqi link did not come up.
    """
    voice_nodes, sim_args = voice_out_processes(
        "naoqi", True, executable_command, (execution_latency_s, loudspeaker_latency_s)
    )
    calibration = speech_messages(speech, max(calibrate_s, MAX_CALIBRATION_S))
    measured = speech_messages(np.roll(speech, SAMPLE_RATE_HZ * 3), duration_s)
    with ExitStack() as stack:
        logs = log_dir or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        return _measure(
            stack.enter_context(
                node_graph(log_dir=logs, sim=True, more_nodes=voice_nodes, sim_args=sim_args)
            ),
            calibration,
            measured,
            execution_latency_s,
            loudspeaker_latency_s,
            duration_s,
            calibrate_s,
            observe,
        )


def _measure(
    graph: NodeSupervisor,
    calibration: list[BagMessage],
    measured: list[BagMessage],
    execution_latency_s: float,
    loudspeaker_latency_s: float,
    duration_s: float,
    calibrate_s: float,
    observe: Callable[[VoiceObserver], None] | None,
) -> VoiceBenchResult:
    """:func:`measure_voice` once the graph runs (its logs kept out of the bench's output)."""
    with rclpy_session():
        observer = VoiceObserver()
        observer.publish(calibration[0])  # the AudioInfo
        observer.wait(observer.voice_ready, READY_TIMEOUT_S, "the voice node did not connect")
        observer.warm_up()
        calibrated_after_s = observer.calibrate(calibration, calibrate_s)
        if observe is not None:
            observe(observer)
        observer.recording = observer.playing = True
        observer.player.play(measured, on_publish=observer.on_publish)
        observer.playing = False
        spin_until(observer, time.monotonic() + 2.0)
        observer.recording = False
        spin_until(observer, time.monotonic() + 1.5)  # the last heartbeats
        result = VoiceBenchResult(
            execution_latency_s=execution_latency_s,
            loudspeaker_latency_s=loudspeaker_latency_s,
            audio_s=duration_s,
            offsets_s=window_offsets(observer.record),
            samples_published=observer.samples_published,
            calibrated_after_s=calibrated_after_s,
            voice_node=observer.diagnostics.get(VOICE_NODE, {}),
            delays_while_playing_ms=observer.delays_while_playing_ms,
            robot=observer.diagnostics.get("pepper_sim_node", {}),
            restarts=sum(len(r) for r in graph.restarts.values()),
        )
        observer.destroy_node()
    return result


def voice_report(result: VoiceBenchResult) -> dict[str, object]:
    """The figures of a run, for ``--json`` and the table."""
    p5, p50, p95 = result.percentiles_ms
    voice = result.voice_node
    return {
        "execution_latency_ms": round(result.execution_latency_s * 1e3),
        "loudspeaker_latency_ms": round(result.loudspeaker_latency_s * 1e3),
        "audio_s": result.audio_s,
        "calibrated_after_s": result.calibrated_after_s,
        "windows": len(result.offsets_s),
        "offset_p5_ms": p5,
        "offset_p50_ms": p50,
        "offset_p95_ms": p95,
        "voice_delay_ms": voice.get("voice_delay_ms", ""),
        "graph_latency": voice.get("graph_latency", ""),
        "execution_latency": voice.get("execution_latency", ""),
        "loudspeaker_latency": voice.get("loudspeaker_latency", ""),
        "naoqi_frames_sent": voice.get("naoqi_frames_sent", ""),
        "robot_frames_played": result.robot.get("voice_frames_played", ""),
        "node_restarts": result.restarts,
    }
