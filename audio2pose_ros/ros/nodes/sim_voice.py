"""The simulated Pepper's voice: a fake ALAudioDevice over real libqi, loudspeakers, microphones.

``pepper_sim_node`` builds a :class:`SimVoice` from its :class:`SimVoiceSettings` parameters:

- with ``naoqi_url`` set (``tcp://127.0.0.1:0`` picks a free port; the address served is logged
  and shown on /diagnostics as ``naoqi_url_served``), a real ``qi.Session`` serves
  :class:`~audio2pose_ros.voice.robot_double.FakeAudioDevice` as ``ALAudioDevice`` there, from
  a process of its own;
- what it receives is played after ``loudspeaker_latency_s`` and mixed with the room's sound into
  the robot's microphones, published on ``audio`` as naoqi_driver publishes them
  (naoqi_bridge_msgs/AudioBuffer, 48 kHz, 4 interleaved int16 channels, 8192 frames, about
  170 ms a message, stamped with the time of the last sample);
- ``execution_latency_s`` holds every joint command back before the simulated motors take it
  (:class:`~audio2pose_ros.voice.robot_double.DelayedCommands`, used by the node).
"""

from __future__ import annotations

import array
import contextlib
import multiprocessing
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess

from naoqi_bridge_msgs.msg import AudioBuffer

from audio2pose_ros import topics
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.parameters import param, validate_settings
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.voice.framing import MIC_RATE_HZ

MIC_PERIOD_S = 0.02  # the microphones' buffers are checked this often (s)
START_TIMEOUT_S = 30.0  # the audio process serves ALAudioDevice within this (imports)
CHANNEL_MAP = [
    AudioBuffer.CHANNEL_FRONT_LEFT,
    AudioBuffer.CHANNEL_FRONT_RIGHT,
    AudioBuffer.CHANNEL_REAR_LEFT,
    AudioBuffer.CHANNEL_REAR_RIGHT,
]


@dataclass(frozen=True)
class SimVoiceSettings:
    """The simulated robot's voice and latency parameters."""

    naoqi_url: str = field(
        default="",
        metadata=param(
            "where the fake ALAudioDevice listens (NAOqi's protocol), e.g. tcp://127.0.0.1:0 "
            "(a free port); '' serves none",
            read_only=True,
        ),
    )
    execution_latency_s: float = field(
        default=0.0,
        metadata=param(
            "emulated motion execution latency: joint commands are taken this long after "
            "they arrive",
            minimum=0.0,
            maximum=1.0,
            unit="s",
            read_only=True,
        ),
    )
    loudspeaker_latency_s: float = field(
        default=0.05,
        metadata=param(
            "emulated loudspeaker latency: the voice is heard this long after it is played",
            minimum=0.0,
            maximum=1.0,
            unit="s",
            read_only=True,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)
        if self.naoqi_url and not self.naoqi_url.startswith("tcp://127.0.0.1:"):
            raise ConfigurationError(
                f"parameter naoqi_url: {self.naoqi_url!r}: the simulated Pepper serves only on "
                "tcp://127.0.0.1:PORT"
            )


class SimVoice:
    """The voice side of the simulated robot, on ``node`` (see the module text).

    The device, its loudspeaker and the microphones run in a process of their own
    (:func:`~audio2pose_ros.voice.robot_double.run_robot_audio`), as on a robot, so the physics
    of the simulation does not hold up the voice; this side publishes what it sends.
    """

    def __init__(self, node: DiagnosedNode, settings: SimVoiceSettings) -> None:
        self.node = node
        self.settings = settings
        self.url_served = ""
        self.buffers = 0
        self.counts: dict[str, int] = {}
        self.process: BaseProcess | None = None
        if not settings.naoqi_url:
            return
        self.mic_pub = node.create_publisher(AudioBuffer, topics.ROBOT_MICROPHONES, 10)
        from audio2pose_ros.voice.robot_double import run_robot_audio  # qi, only when serving

        context = multiprocessing.get_context("spawn")
        self.conn, child = context.Pipe()
        self.process = context.Process(
            target=run_robot_audio,
            args=(settings.naoqi_url, settings.loudspeaker_latency_s, child),
            name="robot-audio",
            daemon=True,
        )
        self.process.start()
        child.close()
        if not self.conn.poll(START_TIMEOUT_S):
            raise ConfigurationError(
                f"the simulated Pepper's audio device did not start at {settings.naoqi_url}"
            )
        _, self.url_served = self.conn.recv()
        node.get_logger().info(f"fake ALAudioDevice (NAOqi protocol) at {self.url_served}")
        node.create_paced_timer(MIC_PERIOD_S, self.publish_microphones)

    def publish_microphones(self) -> None:
        """Publish every microphone buffer the audio process made; keep its counts."""
        while self.conn.poll():
            message = self.conn.recv()
            if message[0] == "counts":
                self.counts = message[1]
                continue
            _, stamp_s, data = message
            msg = AudioBuffer()
            msg.header.stamp.sec = int(stamp_s)
            msg.header.stamp.nanosec = int((stamp_s - int(stamp_s)) * 1e9)
            msg.frequency = MIC_RATE_HZ
            msg.channel_map = CHANNEL_MAP
            msg.data = array.array("h", data)
            self.mic_pub.publish(msg)
            self.buffers += 1

    def diagnostic_values(self) -> dict[str, object]:
        """What the fake ALAudioDevice received and the microphones published."""
        return {
            "naoqi_url_served": self.url_served or "none",
            **self.counts,
            "microphone_buffers": self.buffers,
            "execution_latency_s": self.settings.execution_latency_s,
            "loudspeaker_latency_s": self.settings.loudspeaker_latency_s,
        }

    def close(self) -> None:
        """Stop the audio process (it also stops when this process is gone)."""
        if self.process is None:
            return
        with contextlib.suppress(OSError):
            self.conn.send("stop")
        self.process.join(timeout=2.0)
        if self.process.is_alive():
            self.process.kill()
        self.process = None
