"""voice_out_node: the operator's voice out of the robot, held back to be heard with the motion.

Subscriptions:
    audio/audio (audio_common_msgs/AudioData, best effort), audio/audio_info (AudioInfo,
        latched): the operator's voice, as the features node takes it.
    raw_trajectory (trajectory_msgs/JointTrajectory), commanded_joint_states and joint_states
        (sensor_msgs/JointState): the motion made from it, as computed, commanded and measured.
    audio (naoqi_bridge_msgs/AudioBuffer, best effort): the robot's microphones, as
        naoqi_driver publishes them (the simulated Pepper does the same).
Publications:
    audio_out (audio_common_msgs/AudioData, S16LE mono at ``output_rate_hz``) and
        audio_out_info (AudioInfo, latched), with ``voice_out: topic``: for audio_common's
        audio_play on any speaker.
    /diagnostics (diagnostic_msgs/DiagnosticArray): heartbeat every 0.5 s with the link to
        NAOqi, the three measured latencies, the delay applied and the resulting offset.

With ``voice_out: naoqi:tcp://HOST:PORT`` the voice goes to Pepper's loudspeakers through
NAOqi's ALAudioDevice (:class:`~audio2pose_ros.voice.naoqi.NaoqiVoiceOut`, a thread of its own
with a bounded queue: a robot that does not answer never holds this node, and the motion graph
does not depend on this node at all). A lost connection is reported as ERROR on /diagnostics and
retried. Every chunk is held back by the delay of :class:`~audio2pose_ros.voice.sync.SyncEstimator`,
measured while the operator talks; pauses between words are cut while the loudspeaker's queue
is long, and any chunk is skipped while it is longer than the motion filter lets its own backlog
be (:class:`~audio2pose_ros.voice.delay.SpeakerQueue`), so bursts do not leave the voice late;
both are counted on /diagnostics. ``muted`` (the operator's choice, live) drops the voice, and what
NAOqi has queued and not played yet (``flushAudioOutputs``); the motion is not touched by it, nor
by anything here.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticStatus
from naoqi_bridge_msgs.msg import AudioBuffer
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.audio.pcm import PcmFormat, encode_pcm
from audio2pose_ros.audio.source import AudioInput, AudioInputSettings
from audio2pose_ros.errors import ConfigurationError, InputError
from audio2pose_ros.parameters import (
    ParameterValue,
    param,
    settings_from,
    specs_of,
    validate_settings,
)
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.messages import stamp_s, trajectory_bytes_cap
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS
from audio2pose_ros.ros.spin import run_node
from audio2pose_ros.timebase import FRAME_PERIOD_S
from audio2pose_ros.voice.delay import DelayLine, SpeakerQueue
from audio2pose_ros.voice.framing import OUTPUT_RATES_HZ, check_output_rate
from audio2pose_ros.voice.naoqi import NaoqiVoiceOut, parse_voice_out
from audio2pose_ros.voice.sync import WINDOW_EARLY_S, WINDOW_LATE_S, SyncEstimator, measure

RELEASE_PERIOD_S = 0.01  # the delay line is served this often (s)
CALIBRATE_PERIOD_S = 1.0  # the latencies are measured this often (s)
MAX_STATE_BYTES = 64 * 1024  # a JointState of a few dozen joints; larger ones are dropped
MAX_MIC_BYTES = 1 << 20
MAX_RAW_POINTS, MAX_RAW_JOINTS = (
    1000,
    64,
)  # the largest pose message read  # an AudioBuffer of 170 ms at 48 kHz x 4 is 64 KiB


@dataclasses.dataclass(frozen=True)
class VoiceOutSettings:
    """The voice node's parameters."""

    voice_out: str = dataclasses.field(
        default="topic",
        metadata=param(
            "where the voice goes: 'naoqi:tcp://HOST:PORT' (Pepper's loudspeakers through "
            "NAOqi's ALAudioDevice), 'topic' (audio_out, for audio_common's audio_play) or 'off'",
            read_only=True,
        ),
    )
    output_rate_hz: int = dataclasses.field(
        default=16000,
        metadata=param(
            "rate of the voice sent (ALAudioDevice plays 16000, 22050, 44100 or 48000)",
            minimum=16000,
            maximum=48000,
            unit="Hz",
            read_only=True,
        ),
    )
    muted: bool = dataclasses.field(
        default=False,
        metadata=param("the operator muted the voice (the motion goes on)"),
    )
    calibrate: bool = dataclasses.field(
        default=True,
        metadata=param(
            "measure the latencies while the operator talks (false: the documented defaults)"
        ),
    )
    max_queue_s: float = dataclasses.field(
        default=1.0,
        metadata=param(
            "most voice waiting for NAOqi; older is dropped and counted",
            minimum=0.1,
            maximum=10.0,
            unit="s",
            read_only=True,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field; the destination and the rate must be usable."""
        validate_settings(self)
        parse_voice_out(self.voice_out)
        if self.output_rate_hz not in OUTPUT_RATES_HZ:
            raise ConfigurationError(
                f"parameter output_rate_hz: {self.output_rate_hz} is not one of {OUTPUT_RATES_HZ}"
            )


PARAMETERS = specs_of(VoiceOutSettings)


def _now_s(node: DiagnosedNode) -> float:
    return float(node.get_clock().now().nanoseconds) * 1e-9


class VoiceOutNode(DiagnosedNode):
    """Hold the voice back by the measured motion latency and send it to the robot."""

    def __init__(self) -> None:
        """Declare parameters, start the link to NAOqi (if any), wire topics and timers.

        Raises:
            ConfigurationError: a parameter is refused (the node exits, not respawned).
        """
        super().__init__("voice_out_node")
        self.params = NodeParameters(self, PARAMETERS, apply=self.apply_parameters)
        self.settings = settings_from(VoiceOutSettings, self.params.values)
        self.destination = parse_voice_out(self.settings.voice_out)
        self.rate_hz = check_output_rate(self.settings.output_rate_hz)
        self.input = AudioInput(AudioInputSettings(), target_rate_hz=self.rate_hz)
        self.delay_line = DelayLine(self.rate_hz)
        self.speaker_queue = SpeakerQueue(self.rate_hz)
        self.sync = SyncEstimator(self.rate_hz)
        self.joint_names: list[str] = []  # the commands' order, which the motion is compared in
        self.released_s = 0.0
        self.muted_s = 0.0
        self.muted_now = self.settings.muted
        self.naoqi: NaoqiVoiceOut | None = None
        self.measurer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="voice-calibration")
        self.measuring: Future[dict[str, float]] | None = None
        if self.destination.kind == "naoqi":
            self.naoqi = NaoqiVoiceOut(
                self.destination.url,
                self.rate_hz,
                max_queue_s=self.settings.max_queue_s,
            )
            self.naoqi.start()
        if self.destination.kind == "topic":
            self.out_pub = self.create_publisher(AudioData, topics.AUDIO_OUT, 100)
            info_pub = self.create_publisher(AudioInfo, topics.AUDIO_OUT_INFO, LATCHED_QOS)
            info_pub.publish(
                AudioInfo(
                    channels=1,
                    sample_rate=self.rate_hz,
                    sample_format="S16LE",
                    bitrate=16 * self.rate_hz,
                    coding_format="wave",
                )
            )
            self.out_format = PcmFormat(sample_rate_hz=self.rate_hz, channels=1)
        self.create_subscription(
            AudioInfo, topics.AUDIO_INFO, self.guarded(self.on_audio_info), LATCHED_QOS
        )
        self.create_subscription(AudioData, topics.AUDIO, self.guarded(self.on_audio), AUDIO_QOS)
        self.create_bounded_subscription(
            JointTrajectory, topics.RAW_TRAJECTORY, self.on_raw, 100,
            trajectory_bytes_cap(MAX_RAW_POINTS, MAX_RAW_JOINTS),
        )  # fmt: skip
        self.create_bounded_subscription(
            JointState, topics.COMMANDED_JOINT_STATES, self.on_commanded, 100, MAX_STATE_BYTES
        )
        self.create_bounded_subscription(
            JointState, topics.JOINT_STATES, self.on_measured, 100, MAX_STATE_BYTES
        )
        self.create_bounded_subscription(
            AudioBuffer, topics.ROBOT_MICROPHONES, self.on_microphones, AUDIO_QOS, MAX_MIC_BYTES
        )
        self.create_paced_timer(RELEASE_PERIOD_S, self.release)
        self.create_timer(CALIBRATE_PERIOD_S, self.guarded(self.calibrate))
        self.get_logger().info(
            f"voice out: {self.destination.describe()} at {self.rate_hz} Hz, held back by the "
            "measured motion latency"
        )

    def apply_parameters(self, changes: Mapping[str, ParameterValue]) -> None:
        """``muted`` and ``calibrate`` change live."""
        self.settings = dataclasses.replace(self.settings, **changes)  # type: ignore[arg-type]
        if self.settings.muted and not self.muted_now:
            # what waits here is dropped, and what NAOqi queued is flushed (audio_play's own
            # queue, with ``voice_out: topic``, is out of reach: at most its buffer plays on)
            self.muted_s += self.delay_line.clear()
            if self.naoqi is not None:
                self.naoqi.flush()
                self.speaker_queue.flushed()
        self.muted_now = self.settings.muted

    # --- the voice ------------------------------------------------------------------------------

    def on_audio_info(self, msg: AudioInfo) -> None:
        """Adopt the voice's format (a refused one is reported until a valid one arrives)."""
        try:
            self.input.set_audio_info(
                msg.channels, msg.sample_rate, msg.sample_format, msg.coding_format
            )
        except InputError as exc:
            self.report_problem("format", DiagnosticStatus.ERROR, f"voice not played: {exc}")
            return
        self.clear_problem("format")

    def on_audio(self, msg: AudioData) -> None:
        """Decode a chunk and hold it back from its arrival."""
        now = _now_s(self)
        self.sync.on_chunk(now)
        try:
            samples = self.input.decode_audio_data(msg.data)
        except InputError as exc:
            self.report_problem("audio_dropped", DiagnosticStatus.WARN, str(exc))
            return
        if self.settings.muted:
            self.muted_s += len(samples) / self.rate_hz
            return
        self.delay_line.push(samples, now)

    def release(self) -> None:
        """Send the chunks whose delay is over."""
        now = _now_s(self)
        asked_s = self.sync.line_delay_s(self.speaker_queue.standing_s(now))
        for chunk in self.delay_line.due(now, asked_s):
            queued = self.speaker_queue.offer(now, chunk.samples)
            if queued is None:
                continue  # skipped: the loudspeaker's queue is too long (counted)
            self.released_s += len(queued.samples) / self.rate_hz
            if self.naoqi is not None:
                self.naoqi.send(queued.samples)
            elif self.destination.kind == "topic":
                self.out_pub.publish(AudioData(data=encode_pcm(queued.samples, self.out_format)))
            # the loudspeaker latency counts from when the chunk should start playing; its wait
            # there is taken off the delay line's
            self.sync.on_sent(queued.start_s, queued.samples, queued.start_s - now)

    # --- the motion and the microphones -----------------------------------------------------------

    def _order(self, names: list[str], values: list[float] | np.ndarray) -> np.ndarray | None:
        if not self.joint_names:
            return None
        index = {name: i for i, name in enumerate(names)}
        if any(name not in index for name in self.joint_names) or len(values) != len(names):
            return None
        row = np.array([values[index[name]] for name in self.joint_names], dtype=np.float64)
        return row if np.isfinite(row).all() else None

    def on_raw(self, msg: JointTrajectory) -> None:
        """Pose messages: paired with the chunk they answer; their poses as the model made them."""
        now = _now_s(self)
        names = list(msg.joint_names)
        stamp = stamp_s(msg.header.stamp)
        for i, point in enumerate(msg.points):
            row = self._order(names, np.asarray(point.positions, dtype=np.float64))
            if row is not None:
                self.sync.raw.add(stamp + i * FRAME_PERIOD_S, row)
        self.sync.pairing.poses(now)

    def on_commanded(self, msg: JointState) -> None:
        """The commands; their joint order is the one every trajectory is compared in."""
        if not self.joint_names:
            self.joint_names = list(msg.name)
        row = self._order(list(msg.name), list(msg.position))
        if row is not None:
            self.sync.on_commanded(stamp_s(msg.header.stamp), row)

    def on_measured(self, msg: JointState) -> None:
        """The robot's measured joint states."""
        row = self._order(list(msg.name), list(msg.position))
        if row is not None:
            self.sync.on_measured(stamp_s(msg.header.stamp), row)

    def on_microphones(self, msg: AudioBuffer) -> None:
        """The robot's microphones (stamped with their last sample), averaged to mono."""
        channels = max(1, len(msg.channel_map))
        data = np.asarray(msg.data, dtype=np.int16)
        if not msg.frequency or len(data) % channels:
            raise InputError(f"AudioBuffer of {len(data)} samples for {channels} channels")
        mono = data.reshape(-1, channels).mean(axis=1) / 32768.0
        first_s = stamp_s(msg.header.stamp) - (len(mono) - 1) / msg.frequency
        self.sync.on_heard(first_s, mono, int(msg.frequency))

    def calibrate(self) -> None:
        """Measure the latencies over the recent past on a thread; move the delay towards them.

        The measurement (cross-correlations over seconds of motion and sound) runs beside the
        executor, so the delay line keeps being served on time; its results are applied by the
        next call. One measurement at a time.
        """
        if self.measuring is not None and self.measuring.done():
            self.sync.apply(self.measuring.result())  # a failure is raised here: guarded
            self.measuring = None
        if self.settings.calibrate and self.measuring is None:
            self.measuring = self.measurer.submit(measure, self.sync.snapshot())

    # --- diagnostics ------------------------------------------------------------------------------

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """ERROR while NAOqi is unreachable; WARN when the voice path is slower than the motion."""
        where = self.destination.describe()
        if self.naoqi is not None:
            link = self.naoqi.status()
            if not link.connected:
                return DiagnosticStatus.ERROR, (
                    f"NAOqi at {link.url} unreachable ({link.last_error or 'connecting'}); "
                    "retrying; the motion goes on without the voice"
                )
        offset = self.sync.expected_offset_s(self.delay_in_force_s())
        if not -WINDOW_EARLY_S <= offset <= WINDOW_LATE_S:
            return DiagnosticStatus.WARN, (
                f"voice to {where}: motion {offset * 1e3:+.0f} ms from the voice, outside "
                f"[-{WINDOW_EARLY_S * 1e3:.0f}, +{WINDOW_LATE_S * 1e3:.0f}] ms"
                + ("" if self.sync.calibrated(self.delay_in_force_s()) else " (calibrating)")
            )
        muted = " (muted)" if self.settings.muted else ""
        return DiagnosticStatus.OK, f"voice to {where}{muted}, in step with the motion"

    def delay_in_force_s(self) -> float:
        """How long the voice is held back now: the delay line's delay and the loudspeaker's wait.

        Before any voice, the delay called for.
        """
        in_force = self.delay_line.delay_s
        return self.sync.delay_s if in_force is None else in_force + self.sync.waited_s

    def diagnostic_values(self) -> dict[str, object]:
        """The latencies, the delay, the offset and the link's counters."""
        _, graph_measured = self.sync.graph_s()
        parts = self.sync.parts
        values: dict[str, object] = {
            "voice_out": self.destination.describe(),
            "muted": self.settings.muted,
            "graph_latency": parts["graph"].describe(),
            "execution_latency": parts["execution"].describe(),
            "loudspeaker_latency": parts["loudspeaker"].describe(),
            "voice_delay_ms": f"{self.delay_in_force_s() * 1e3:.0f}",
            "voice_delay_target_ms": f"{self.sync.delay_s * 1e3:.0f}",
            "loudspeaker_queue_ms": f"{self.sync.waited_s * 1e3:.0f}",
            "calibrated": self.sync.calibrated(self.delay_in_force_s()),
            "offset_ms": f"{self.sync.expected_offset_s(self.delay_in_force_s()) * 1e3:+.0f}",
            "voice_released_s": f"{self.released_s:.2f}",
            "voice_muted_s": f"{self.muted_s:.2f}",
            "voice_dropped_in_delay_line_s": f"{self.delay_line.dropped_s:.2f}",
            "voice_stretched_frames": self.delay_line.stretched_samples,
            "pauses_skipped_frames": self.speaker_queue.skipped_samples,
            "speech_skipped_frames": self.speaker_queue.speech_skipped_samples,
            "format": self.input.format or self.input.format_problem,
        }
        if not graph_measured:
            values["graph_latency_note"] = "needs raw_trajectory and commanded_joint_states"
        if self.naoqi is not None:
            link = self.naoqi.status()
            values.update(
                naoqi_connected=link.connected,
                naoqi_connections=link.connections,
                naoqi_failures=link.failures,
                naoqi_calls=link.calls,
                naoqi_frames_sent=link.frames_sent,
                naoqi_queued_s=f"{link.queued_s:.2f}",
                naoqi_dropped_s=f"{link.dropped_s:.2f}",
                naoqi_last_error=link.last_error,
            )
        return values

    def destroy_node(self) -> None:
        """Stop the link to NAOqi with the node."""
        if self.naoqi is not None:
            self.naoqi.stop()
        self.measurer.shutdown(wait=True, cancel_futures=True)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(VoiceOutNode, "voice_out_node", args)


if __name__ == "__main__":
    main()
