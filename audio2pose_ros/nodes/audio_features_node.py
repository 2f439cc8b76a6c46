"""audio_features_node: audio_common_msgs audio in, streaming LogFB/MFCC feature frames out.

Subscriptions:
    audio/audio (audio_common_msgs/AudioData, best effort): raw PCM chunks of any size.
    audio/audio_info (audio_common_msgs/AudioInfo, transient local): how to decode the chunks.
Publications:
    features (std_msgs/Float32MultiArray): frames x features, un-normalised, at 100 frames/s
        of audio; dim[1].label names the feature set (e.g. ``logfbank26``).
    voice_activity (std_msgs/Bool): energy-based voice activity after each audio chunk.
    /diagnostics (diagnostic_msgs/DiagnosticArray)

Parameters
----------
    model_path (str): checkpoint whose feature specification to compute ('' = packaged default).

Audio that cannot be decoded (no AudioInfo yet, unsupported format, NaN samples) is dropped
with a throttled warning and counted in /diagnostics; the node keeps running.

"""

from __future__ import annotations

import numpy as np
from audio_common_msgs.msg import AudioData, AudioInfo
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from std_msgs.msg import Bool, Float32MultiArray

from audio2pose_ros.audio.features import StreamingFeatureExtractor
from audio2pose_ros.audio.pcm import InvalidAudio, PcmDecoder, PcmFormat, UnsupportedAudioFormat
from audio2pose_ros.audio.vad import EnergyVad
from audio2pose_ros.checkpoint_format import feature_spec_of
from audio2pose_ros.nodes.common import (
    AUDIO_QOS,
    DIAGNOSTICS_PERIOD_S,
    LATCHED_QOS,
    STREAM_QOS,
    StartupError,
    diagnostic_array,
    features_to_msg,
    run_node,
)
from audio2pose_ros.resources import default_checkpoint_path

WARN_THROTTLE_S = 5.0


class AudioFeaturesNode(Node):
    """Decode audio chunks as AudioInfo describes them and publish feature frames."""

    def __init__(self) -> None:
        """Declare parameters, build the extractor, wire topics and the diagnostics timer."""
        super().__init__("audio_features_node")
        model_path = self.declare_parameter("model_path", "").value
        self.max_chunk_bytes = int(self.declare_parameter("max_chunk_bytes", 1 << 20).value)
        try:
            self.spec = feature_spec_of(model_path or default_checkpoint_path())
        except (OSError, ValueError) as exc:
            raise StartupError(str(exc)) from None
        self.label = f"{self.spec.kind}{self.spec.dim}"
        self.extractor = StreamingFeatureExtractor(self.spec)
        self.vad = EnergyVad()
        self.decoder: PcmDecoder | None = None
        self.format: PcmFormat | None = None
        self.chunks = 0
        self.frames_out = 0
        self.dropped_bytes = 0
        self.last_problem = ""

        self.features_pub = self.create_publisher(Float32MultiArray, "features", STREAM_QOS)
        self.voice_pub = self.create_publisher(Bool, "voice_activity", STREAM_QOS)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(AudioInfo, "audio/audio_info", self.on_audio_info, LATCHED_QOS)
        self.create_subscription(AudioData, "audio/audio", self.on_audio, AUDIO_QOS)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)
        self.get_logger().info(f"computing {self.label} features ({self.spec.to_dict()})")

    def on_audio_info(self, msg: AudioInfo) -> None:
        """Adopt a new audio format; a changed format restarts decoding and features."""
        try:
            fmt = PcmFormat.from_audio_info(
                msg.channels, msg.sample_rate, msg.sample_format, msg.coding_format
            )
        except UnsupportedAudioFormat as exc:
            self.decoder, self.format = None, None
            self.last_problem = f"AudioInfo rejected, audio will be dropped: {exc}"
            self.get_logger().error(self.last_problem)  # once per AudioInfo (every 5 s at most)
            return
        if fmt == self.format:
            return
        self.get_logger().info(f"audio format: {fmt}")
        self.format = fmt
        self.decoder = PcmDecoder(fmt, target_rate_hz=self.spec.sample_rate_hz)
        self.extractor.reset()
        self.vad.reset()

    def on_audio(self, msg: AudioData) -> None:
        """Decode one chunk, push its samples, publish the frames that became complete."""
        self.chunks += 1
        if len(msg.data) > self.max_chunk_bytes:
            self.dropped_bytes += len(msg.data)
            self.last_problem = (
                f"dropped an AudioData message of {len(msg.data)} bytes "
                f"(max_chunk_bytes {self.max_chunk_bytes})"
            )
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        data = bytes(msg.data)
        if self.decoder is None:
            self.dropped_bytes += len(data)
            self.last_problem = (
                "no usable AudioInfo received yet on audio/audio_info: dropping audio"
            )
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        try:
            samples = self.decoder.feed(data)
        except InvalidAudio as exc:
            self.dropped_bytes += len(data)
            self.last_problem = f"dropped an audio chunk: {exc}"
            self.get_logger().warning(self.last_problem, throttle_duration_sec=WARN_THROTTLE_S)
            return
        frames = self.extractor.push(samples)
        if len(samples):
            self.voice_pub.publish(Bool(data=self.vad.push(samples)))
        if len(frames):
            self.frames_out += len(frames)
            self.features_pub.publish(features_to_msg(np.asarray(frames), self.label))

    def publish_diagnostics(self) -> None:
        """Publish counters; WARN while audio is being dropped."""
        level = DiagnosticStatus.WARN if self.dropped_bytes else DiagnosticStatus.OK
        self.diagnostics_pub.publish(
            diagnostic_array(
                self,
                level,
                self.last_problem or "ok",
                {
                    "format": self.format,
                    "features": self.label,
                    "chunks_received": self.chunks,
                    "frames_published": self.frames_out,
                    "dropped_bytes": self.dropped_bytes,
                    "voice_active": self.vad.active,
                },
            )
        )


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(AudioFeaturesNode, "audio_features_node", args)


if __name__ == "__main__":
    main()
