"""Parameters of ``console_node``, declared once (``ros2 param describe`` shows each one).

The audio bounds are those of the features node's input (:mod:`audio2pose_ros.audio.source`),
made tighter for a live microphone and capped at the features node's defaults, so nothing the
console publishes is refused downstream: a chunk is at most ``max_browser_chunk_s`` (0.1 s: the
page sends 20 ms) and a talker at most ``max_browser_audio_s_per_s`` seconds of audio per second
(1.5: a voice is 1 s/s, the rest absorbs network jitter). Whether the bind needs a token and a
certificate is decided by :func:`audio2pose_ros.console.access.resolve_access`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from audio2pose_ros.audio.source import AudioInputSettings
from audio2pose_ros.parameters import param, validate_settings
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

__all__ = ["BYTES_PER_SECOND", "ConsoleSettings"]

BYTES_PER_SECOND = 2 * SAMPLE_RATE_HZ  # 16 kHz S16LE mono, what the page sends
_FEATURES_INPUT = AudioInputSettings()  # the features node's default input bounds


@dataclass(frozen=True)
class ConsoleSettings:
    """Settings of the console: where it listens, who may use it, what a browser may send."""

    host: str = field(
        default="127.0.0.1",
        metadata=param(
            "address the console listens on; anything but a loopback address needs certfile, "
            "keyfile and a token",
            read_only=True,
        ),
    )
    port: int = field(
        default=8765,
        metadata=param(
            "TCP port of the page and its WebSocket (0 = any free port, printed at start)",
            minimum=0,
            maximum=65535,
            read_only=True,
        ),
    )
    token: str = field(
        default="",
        metadata=param(
            "access token the page must present ('' = none on a loopback bind; on a network "
            "bind a random one is made and printed); at least 16 characters on a network",
            read_only=True,
        ),
    )
    certfile: str = field(
        default="",
        metadata=param(
            "PEM certificate for HTTPS ('' = plain HTTP, loopback only)", read_only=True
        ),
    )
    keyfile: str = field(
        default="",
        metadata=param("PEM private key of certfile", read_only=True),
    )
    max_clients: int = field(
        default=8,
        metadata=param(
            "operators (WebSockets with their token) at once; more are refused",
            minimum=1,
            maximum=64,
            read_only=True,
        ),
    )
    max_browser_chunk_s: float = field(
        default=0.1,
        metadata=param(
            "longest audio chunk a browser may send; longer ones are dropped and counted "
            f"(at most the features node's {_FEATURES_INPUT.max_chunk_s:g} s)",
            minimum=0.01,
            maximum=_FEATURES_INPUT.max_chunk_s,
            read_only=True,
            unit="s",
        ),
    )
    max_browser_audio_s_per_s: float = field(
        default=1.5,
        metadata=param(
            "seconds of audio per second of wall-clock time a talker may send; beyond it audio "
            f"is dropped and counted (at most the features node's "
            f"{_FEATURES_INPUT.max_audio_s_per_s:g})",
            minimum=1.0,
            maximum=_FEATURES_INPUT.max_audio_s_per_s,
            read_only=True,
            unit="s/s",
        ),
    )
    max_messages_per_s: float = field(
        default=20.0,
        metadata=param(
            "control messages (text frames) per second a connection may send; a connection "
            "that keeps exceeding it is closed",
            minimum=1.0,
            maximum=1000.0,
            read_only=True,
            unit="1/s",
        ),
    )
    pose_rate_hz: float = field(
        default=30.0,
        metadata=param(
            "rate of the pose sent to each page for the 3D view",
            minimum=1.0,
            maximum=60.0,
            read_only=True,
            unit="Hz",
        ),
    )
    filter_node: str = field(
        default="motion_filter_node",
        metadata=param(
            "motion filter node whose gains the page sets (its set_parameters service)",
            read_only=True,
        ),
    )
    inference_node: str = field(
        default="inference_node",
        metadata=param(
            "inference node that runs a learned personal model (its model_path, set through "
            "its set_parameters service)",
            read_only=True,
        ),
    )
    voice_node: str = field(
        default="voice_out_node",
        metadata=param(
            "voice node whose 'muted' the page sets (its set_parameters service) and whose "
            "latencies it shows (its /diagnostics status)",
            read_only=True,
        ),
    )
    auth_timeout_s: float = field(
        default=5.0,
        metadata=param(
            "a connection that has not presented its token within this time is closed",
            minimum=0.5,
            maximum=60.0,
            read_only=True,
            unit="s",
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)

    @property
    def max_chunk_bytes(self) -> int:
        """Largest PCM payload of one chunk (bytes of 16 kHz S16LE mono)."""
        return int(self.max_browser_chunk_s * BYTES_PER_SECOND)
