"""The voice to Pepper's loudspeakers over NAOqi's own protocol (``qi``, ALAudioDevice).

:class:`NaoqiVoiceOut` owns a thread that connects a ``qi.Session`` to the robot, sets
ALAudioDevice's ``outputSampleRate`` and sends every block the caller queued with
``sendRemoteBufferToOutput(nframes, buffer)`` (:mod:`audio2pose_ros.voice.framing`). The caller
never waits for the robot:

- :meth:`NaoqiVoiceOut.send` only queues, and the queue holds at most ``max_queue_s`` seconds;
  older audio beyond it is dropped and counted (``dropped_s``);
- a lost connection (a failed call, or the session found disconnected while idle) is reported
  in :meth:`NaoqiVoiceOut.status`, the audio queued meanwhile is dropped and counted (late
  voice would play out of step with the motion), and the thread connects again after a
  back-off that doubles from ``retry_s`` up to ``MAX_RETRY_S``;
- :meth:`NaoqiVoiceOut.flush` (a mute) drops what is queued here and has the thread call
  ALAudioDevice's ``flushAudioOutputs()``, which drops what the robot has queued and not played.

This module does not import rclpy.
"""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.voice.framing import check_output_rate, stereo_blocks

__all__ = [
    "MAX_RETRY_S",
    "NaoqiVoiceOut",
    "VoiceLinkStatus",
    "VoiceOut",
    "parse_voice_out",
]

MAX_RETRY_S = 8.0  # longest wait between two connection attempts (s)
IDLE_CHECK_S = 0.5  # an idle connection is checked this often (s)
SERVICE = "ALAudioDevice"


@dataclass(frozen=True)
class VoiceOut:
    """Where the voice goes: ``off``, ``topic`` (``audio_out``) or ``naoqi`` (with its URL)."""

    kind: str
    url: str = ""

    def describe(self) -> str:
        """``naoqi:tcp://host:9559``, ``topic`` or ``off``."""
        return f"naoqi:{self.url}" if self.kind == "naoqi" else self.kind


def parse_voice_out(text: str) -> VoiceOut:
    """Parse ``off``, ``topic``, ``naoqi:tcp://HOST:PORT`` (or ``naoqi:HOST``, port 9559).

    Raises:
        ConfigurationError: anything else (the message says what is accepted).
    """
    text = text.strip()
    if text in ("off", "topic"):
        return VoiceOut(text)
    kind, sep, url = text.partition(":")
    if kind == "naoqi" and sep and url.strip():
        url = url.strip()
        if "://" not in url:
            url = f"tcp://{url}" if ":" in url else f"tcp://{url}:9559"
        scheme, _, address = url.partition("://")
        host, colon, port = address.rpartition(":")
        if scheme in ("tcp", "tcps") and colon and host and port.isdigit() and int(port) < 65536:
            return VoiceOut("naoqi", url)
    raise ConfigurationError(
        f"voice out {text!r}: expected 'off', 'topic' or 'naoqi:tcp://HOST:PORT' "
        "(NAOqi's address, port 9559 on a robot)"
    )


@dataclass(frozen=True)
class VoiceLinkStatus:
    """What the link to ALAudioDevice did so far."""

    url: str
    connected: bool
    connections: int  # successful connections (1 after the first)
    failures: int  # failed attempts and lost connections
    calls: int  # sendRemoteBufferToOutput calls that returned
    frames_sent: int
    queued_s: float
    dropped_s: float  # audio dropped: queue over its bound, queued while disconnected, or flushed
    flushes: int  # flushAudioOutputs calls that returned
    last_error: str


def qi_device(url: str, rate_hz: int) -> tuple[Any, Any]:
    """A connected ``qi.Session`` and its ALAudioDevice, at ``rate_hz`` output."""
    import qi

    session = qi.Session()
    session.connect(url)
    device = session.service(SERVICE)
    device.setParameter("outputSampleRate", rate_hz)
    return session, device


class NaoqiVoiceOut:
    """Send the voice to ALAudioDevice from a thread of its own (see the module text).

    Args:
        url: NAOqi's address (``tcp://HOST:9559``).
        rate_hz: output rate, one of ALAudioDevice's.
        max_queue_s: most audio waiting to be sent (s).
        retry_s: first wait before connecting again (s).
        connect: returns ``(session, device)`` (default: :func:`qi_device`).
    """

    def __init__(
        self,
        url: str,
        rate_hz: int,
        max_queue_s: float = 1.0,
        retry_s: float = 0.5,
        connect: Callable[[str, int], tuple[Any, Any]] = qi_device,
    ) -> None:
        self.url = url
        self.rate_hz = check_output_rate(rate_hz)
        self.max_queue = int(max_queue_s * rate_hz)
        self.retry_s = retry_s
        self._connect = connect
        self._queue: deque[np.ndarray] = deque()
        self._queued = 0
        self._cond = threading.Condition()
        self._stopping = False
        self._connected = False
        self._connections = self._failures = self._calls = self._frames = self._flushes = 0
        self._flush_pending = False
        self._dropped = 0
        self._last_error = ""
        self._session: Any = None
        self._thread = threading.Thread(target=self._run, name="naoqi-voice", daemon=True)

    def start(self) -> None:
        """Start the sending thread (it connects, and reconnects, by itself)."""
        self._thread.start()

    def send(self, mono: np.ndarray) -> None:
        """Queue mono samples at the output rate; never waits. Beyond the bound, oldest dropped."""
        if not len(mono):
            return
        with self._cond:
            self._queue.append(mono)
            self._queued += len(mono)
            while self._queued > self.max_queue and len(self._queue) > 1:
                self._drop(self._queue.popleft())
            self._cond.notify()

    def flush(self) -> None:
        """Drop the voice queued here and, on the thread, what the robot queued (never waits)."""
        with self._cond:
            while self._queue:
                self._drop(self._queue.popleft())
            self._flush_pending = True
            self._cond.notify()

    def _drop(self, mono: np.ndarray) -> None:
        self._queued -= len(mono)
        self._dropped += len(mono)

    def status(self) -> VoiceLinkStatus:
        """A consistent snapshot of the link."""
        with self._cond:
            return VoiceLinkStatus(
                url=self.url,
                connected=self._connected,
                connections=self._connections,
                failures=self._failures,
                calls=self._calls,
                frames_sent=self._frames,
                queued_s=self._queued / self.rate_hz,
                dropped_s=self._dropped / self.rate_hz,
                flushes=self._flushes,
                last_error=self._last_error,
            )

    def stop(self) -> None:
        """Stop the thread and close the session."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self._close()

    # --- the thread -----------------------------------------------------------------------------

    def _run(self) -> None:
        wait_s = self.retry_s
        while not self._stopped():
            try:
                device = self._open()
                wait_s = self.retry_s
                self._serve(device)
            except Exception as exc:  # any failure of the robot's side: reported, retried
                self._lost(f"{type(exc).__name__}: {exc}")
                with self._cond:
                    self._cond.wait_for(lambda: self._stopping, timeout=wait_s)
                wait_s = min(wait_s * 2.0, MAX_RETRY_S)
        self._close()

    def _stopped(self) -> bool:
        with self._cond:
            return self._stopping

    def _open(self) -> Any:
        self._close()
        session, device = self._connect(self.url, self.rate_hz)
        with self._cond:
            self._session = session
            self._connected = True
            self._connections += 1
            self._last_error = ""
            # what waited while there was no connection is too late to play in step
            while self._queue:
                self._drop(self._queue.popleft())
        return device

    def _serve(self, device: Any) -> None:
        """Send what is queued until stopped; raise when the connection is lost."""
        while True:
            with self._cond:
                self._cond.wait_for(
                    lambda: self._stopping or self._flush_pending or bool(self._queue),
                    IDLE_CHECK_S,
                )
                if self._stopping:
                    return
                flush, self._flush_pending = self._flush_pending, False
                mono = self._queue.popleft() if self._queue else None
                if mono is not None:
                    self._queued -= len(mono)
                session = self._session
            if flush:
                device.flushAudioOutputs()
                with self._cond:
                    self._flushes += 1
            if mono is None:
                if not flush and session is not None and not session.isConnected():
                    raise ConnectionError(f"the session to {self.url} was disconnected")
                continue
            for nframes, buffer in stereo_blocks(mono):
                device.sendRemoteBufferToOutput(nframes, buffer)
                with self._cond:
                    self._calls += 1
                    self._frames += nframes

    def _lost(self, why: str) -> None:
        with self._cond:
            self._connected = False
            self._failures += 1
            self._last_error = why
            while self._queue:
                self._drop(self._queue.popleft())

    def _close(self) -> None:
        with self._cond:
            session, self._session = self._session, None
        if session is not None:
            with contextlib.suppress(Exception):  # closing a broken session: nothing more to do
                session.close()
