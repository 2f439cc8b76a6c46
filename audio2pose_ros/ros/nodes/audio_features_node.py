"""audio_features_node: microphone audio in, streaming LogFB/MFCC feature frames out.

Subscriptions (``input_type`` chooses one of two inputs):
    audio_common (default):
        audio/audio (audio_common_msgs/AudioData, best effort): raw PCM chunks of any size.
        audio/audio_info (audio_common_msgs/AudioInfo, transient local): how to decode them.
    naoqi:
        audio/audio (naoqi_bridge_msgs/AudioBuffer, best effort): the robot's microphones as
        naoqi_driver publishes them (remap it to naoqi_driver's ``audio`` topic).
Publications:
    features (std_msgs/Float32MultiArray): frames x features, un-normalised, at 100 frames/s
        of audio, one message per audio chunk (while something subscribes to it); dim[1].label
        names the feature set (e.g. ``logfbank26``) and dim[0].label ``frames from N`` the
        index of the message's first frame since the node started, so a receiver counts the
        frames lost on the way.
    voice_activity (std_msgs/Bool): energy-based voice activity, published when it changes and
        at least every ``VOICE_REFRESH_S`` (0.5 s) while audio arrives (while something
        subscribes to it); a value holds until the next one.
    /diagnostics (diagnostic_msgs/DiagnosticArray): a heartbeat every 0.5 s.

Parameters: the fields of :class:`FeaturesNodeSettings` (model_path) and of
:class:`~audio2pose_ros.audio.source.AudioInputSettings` (``ros2 param describe`` shows each with
its range); all but input_type and model_path can change live.

AudioData chunks shorter than ``ACCUMULATE_S`` (10 ms) of audio are accumulated and decoded
together (``audio_decodes`` counts the decodes), so a flood of tiny chunks costs a copy per
chunk, not a decode; they wait at most ``FLUSH_PERIOD_S`` for more (a timer armed by the first
chunk that waits, so no timer wakes the node while no audio waits).

Audio that cannot be used (no or a rejected format, a message over a limit, NaN samples) is
dropped, counted and reported on /diagnostics while it happens; a rejected AudioInfo is
reported with its reason until a valid AudioInfo arrives, and decoding resumes at once then.
Any other exception in a callback is caught at the node boundary
(:meth:`~audio2pose_ros.ros.diagnosed_node.DiagnosedNode.guarded`) and the node keeps serving.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticStatus
from naoqi_bridge_msgs.msg import AudioBuffer
from std_msgs.msg import Bool, Float32MultiArray

from audio2pose_ros import topics
from audio2pose_ros.audio.source import AudioInput, AudioInputSettings
from audio2pose_ros.audio.streaming import StreamingFeatureExtractor
from audio2pose_ros.audio.vad import EnergyVad
from audio2pose_ros.checkpoints.format import feature_spec_of
from audio2pose_ros.checkpoints.switch import resolve_model_path
from audio2pose_ros.errors import InputError
from audio2pose_ros.parameters import (
    ParameterValue,
    param,
    settings_from,
    settings_with,
    specs_of,
    validate_settings,
)
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.messages import features_to_msg
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.spin import run_node


@dataclasses.dataclass(frozen=True)
class FeaturesNodeSettings:
    """The features node's own parameter; its audio input's are :class:`AudioInputSettings`."""

    model_path: str = dataclasses.field(
        default="",
        metadata=param(
            "checkpoint the graph runs ('' = packaged default): audio_features_node computes "
            "its features; inference_node runs it, and a checkpoint set on it live is blended "
            "in over 1 s (one for other features is refused)",
            read_only=True,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)


PARAMETERS = (*specs_of(FeaturesNodeSettings), *specs_of(AudioInputSettings))
VOICE_REFRESH_S = 0.5  # voice_activity is republished unchanged this often (a late subscriber)
# AudioData chunks shorter than this are accumulated and decoded together: the work per chunk
# (decode, features, voice activity) costs as much for a byte as for a frame hop of audio.
ACCUMULATE_S = 0.01
FLUSH_PERIOD_S = 0.02  # accumulated audio waits at most about this long for more


class AudioFeaturesNode(DiagnosedNode):
    """Decode audio messages within limits and publish feature frames."""

    def __init__(self) -> None:
        """Declare parameters, build the extractor, wire topics (the heartbeat is the base's).

        Raises:
            ConfigurationError: a parameter is refused, or ``model_path`` is not a usable
                checkpoint (the node exits and is not respawned).
        """
        super().__init__("audio_features_node")
        self.params = NodeParameters(self, PARAMETERS, apply=self.apply_parameters)
        settings = settings_from(FeaturesNodeSettings, self.params.values)
        self.spec = feature_spec_of(resolve_model_path(settings.model_path))
        self.label = self.spec.label
        self.input = AudioInput(
            settings_from(AudioInputSettings, self.params.values),
            target_rate_hz=self.spec.sample_rate_hz,
        )
        self.extractor = StreamingFeatureExtractor(self.spec)
        self.vad = EnergyVad()
        self.frames_out = 0
        self.voice_sent: bool | None = None  # the voice activity last published, and when
        self.voice_sent_s = -math.inf
        # In single-process mode the next nodes are called directly (nodes.single_process);
        # the topics are then published only for other subscribers.
        self.features_sink: Callable[[np.ndarray], None] | None = None
        self.voice_sink: Callable[[bool], None] | None = None
        self.pending: list[bytes] = []  # small AudioData payloads not decoded yet
        self.pending_bytes = 0
        self.audio_batches = 0  # decodes of audio_common audio (one per chunk or accumulation)

        self.features_pub = self.create_publisher(Float32MultiArray, topics.FEATURES, STREAM_QOS)
        self.voice_pub = self.create_publisher(Bool, topics.VOICE_ACTIVITY, STREAM_QOS)
        if self.input.settings.input_type == "naoqi":
            self.create_subscription(
                AudioBuffer, topics.AUDIO, self.guarded(self.on_audio_buffer), AUDIO_QOS
            )
        else:
            self.create_subscription(
                AudioInfo, topics.AUDIO_INFO, self.guarded(self.on_audio_info), LATCHED_QOS
            )
            self.create_subscription(
                AudioData, topics.AUDIO, self.guarded(self.on_audio_data), AUDIO_QOS
            )
            # armed only while audio waits (on_audio_data): an idle node is never woken for it
            self.flush_timer = self.create_timer(FLUSH_PERIOD_S, self.guarded(self._flush_due))
            self.flush_timer.cancel()
        self.get_logger().info(
            f"computing {self.label} features ({self.spec.to_dict()}) from "
            f"{self.input.settings.input_type} audio, {self.input.settings.selection.describe()}"
        )

    def apply_parameters(self, changes: Mapping[str, ParameterValue]) -> None:
        """Validate the combination, then apply it from the next message on."""
        self.input.update_settings(settings_with(self.input.settings, changes))

    # --- audio_common ---------------------------------------------------------------------------

    def on_audio_info(self, msg: AudioInfo) -> None:
        """Adopt a new format (a change restarts features); keep a refusal's reason on show.

        Audio accumulated before it is decoded in the format it came in.
        """
        self.flush_audio()
        try:
            changed = self.input.set_audio_info(
                msg.channels, msg.sample_rate, msg.sample_format, msg.coding_format
            )
        except InputError as exc:  # shown by diagnostic_summary until a valid AudioInfo
            self.get_logger().error(f"{exc}; audio is dropped until a valid AudioInfo arrives")
            return
        self.clear_problem("format")
        if changed:
            self.get_logger().info(f"audio format: {self.input.format}")
            self._restart()

    def on_audio_data(self, msg: AudioData) -> None:
        """Decode one AudioData and publish what became available.

        A chunk shorter than ``ACCUMULATE_S`` of audio is accumulated instead, and decoded
        with the ones after it once they make ``ACCUMULATE_S`` (or after ``FLUSH_PERIOD_S``):
        a flood of one-byte chunks costs the node a copy per chunk, not a decode.
        """
        fmt = self.input.format
        batch_bytes = 0 if fmt is None else fmt.frame_bytes * fmt.sample_rate_hz * ACCUMULATE_S
        if len(msg.data) >= batch_bytes and not self.pending:
            self._decode([msg.data])
            return
        if not self.pending:
            self.flush_timer.reset()  # the first chunk waits at most FLUSH_PERIOD_S
        self.pending.append(msg.data)
        self.pending_bytes += len(msg.data)
        if self.pending_bytes >= batch_bytes:
            self.flush_audio()

    def flush_audio(self) -> None:
        """Decode the accumulated chunks at once, if any."""
        if self.pending:
            chunks, self.pending, self.pending_bytes = self.pending, [], 0
            self._decode(chunks)

    def _flush_due(self) -> None:
        """The flush timer: ``FLUSH_PERIOD_S`` after audio began to wait; it is then disarmed."""
        self.flush_timer.cancel()
        self.flush_audio()

    def _decode(self, chunks: list[bytes]) -> None:
        self.audio_batches += 1
        try:
            data = chunks[0] if len(chunks) == 1 else b"".join(chunks)
            samples = self.input.decode_audio_data(data, chunks=len(chunks))
        except InputError as exc:
            self._report_dropped(exc)
            return
        self._publish(samples)

    # --- naoqi ----------------------------------------------------------------------------------

    def on_audio_buffer(self, msg: AudioBuffer) -> None:
        """Decode one AudioBuffer (its own format) and publish what became available."""
        try:
            samples, changed = self.input.decode_audio_buffer(
                msg.frequency, msg.channel_map, msg.data
            )
        except InputError as exc:
            self._report_dropped(exc)
            return
        self.clear_problem("format")
        if changed:
            self.get_logger().info(
                f"audio format: {self.input.format}, channel_map {list(msg.channel_map)}"
            )
            self._restart()
        self._publish(samples)

    # --- shared ---------------------------------------------------------------------------------

    def _restart(self) -> None:
        """A new stream: forget partial frames and the noise floor."""
        self.extractor.reset()
        self.vad.reset()

    def _report_dropped(self, exc: InputError) -> None:
        """Report a dropped message while such drops go on (a refused AudioInfo: the summary)."""
        if self.input.info_rejected:
            return
        key = "format" if self.input.format is None else "audio_dropped"
        self.report_problem(key, DiagnosticStatus.WARN, str(exc))

    def _publish(self, samples: np.ndarray) -> None:
        frames = self.extractor.push(samples)
        if len(samples):
            active = self.vad.push(samples)
            now = time.monotonic()
            # A change at once; the same value again only as a refresh for a subscriber that
            # (re)started meanwhile: not one message per chunk.
            if active != self.voice_sent or now - self.voice_sent_s >= VOICE_REFRESH_S:
                self.voice_sent, self.voice_sent_s = active, now
                if self.voice_sink is not None:
                    self.voice_sink(active)
                if self.voice_pub.get_subscription_count():  # no message for nobody
                    self.voice_pub.publish(Bool(data=active))
        if len(frames):
            first = self.frames_out  # numbered: the receiver counts frames lost on the way
            self.frames_out += len(frames)
            batch = np.asarray(frames, dtype=np.float32)  # what the topic carries, either way
            if self.features_pub.get_subscription_count():
                self.features_pub.publish(features_to_msg(batch, self.label, first))
            if self.features_sink is not None:
                self.features_sink(batch)

    # --- diagnostics ----------------------------------------------------------------------------

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """ERROR while the declared AudioInfo is refused, else OK with what is decoded.

        Audio dropped for another reason (none yet, a limit) is a reported problem, shown
        while it happens.
        """
        if self.input.info_rejected:
            return DiagnosticStatus.ERROR, self.input.format_problem
        if self.input.format is None:
            return DiagnosticStatus.OK, f"waiting: {self.input.format_problem}"
        return DiagnosticStatus.OK, f"decoding {self.input.format}"

    def diagnostic_values(self) -> dict[str, object]:
        """Counters, the format and the limits in force."""
        settings = dataclasses.asdict(self.input.settings)
        return {
            "format": self.input.format or self.input.format_problem,
            "channels_used": self.input.channels_used or "all",
            "features": self.label,
            "chunks_received": self.input.chunks,
            "audio_decodes": self.audio_batches,
            "chunks_dropped": self.input.dropped_chunks,
            "dropped_bytes": self.input.dropped_bytes,
            "frames_published": self.frames_out,
            "voice_active": self.vad.active,
            **settings,
        }


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(AudioFeaturesNode, "audio_features_node", args)


if __name__ == "__main__":
    main()
