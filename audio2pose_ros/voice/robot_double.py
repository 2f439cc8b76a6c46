"""The robot's side of the voice, for the simulated Pepper: ALAudioDevice, speaker, microphones.

Pepper cannot run here, so the simulated Pepper (``pepper_sim_node``) stands in for what the
voice meets on the robot:

- :class:`FakeAudioDevice`, served as ``ALAudioDevice`` by a real ``qi.Session`` listening on
  127.0.0.1 (:func:`serve_audio_device`): the voice node reaches it through NAOqi's real
  protocol. Its methods are declared with their types (``qi.bind``), as NAOqi's are, so a
  buffer arrives as the bytes sent. It refuses what ALAudioDevice refuses: an output rate it
  does not play, more than 16384 frames a call, a buffer that is not ``nframes`` 16-bit stereo
  frames;
- :class:`RobotLoudspeaker`: plays the blocks back to back, each heard ``latency_s`` after it
  started (the emulated loudspeaker latency);
- :class:`RobotMicrophones`: what Pepper's four microphones record, the room's sound with the
  loudspeaker's voice mixed in, cut into naoqi_driver's ``AudioBuffer`` shape (48 kHz, 4
  interleaved int16 channels, 8192 frames, about 170 ms a message);
- :class:`~audio2pose_ros.voice.delay.DelayedCommands`: joint commands applied ``latency_s``
  after they arrived (the emulated motion execution latency).

Everything is on one clock (seconds, ``time.time`` in the node). This module does not import
rclpy.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import qi

from audio2pose_ros.voice.framing import (
    BYTES_PER_FRAME,
    MAX_FRAMES_PER_CALL,
    MIC_CHANNELS,
    MIC_FRAMES,
    MIC_RATE_HZ,
    OUTPUT_RATES_HZ,
)

__all__ = [
    "FakeAudioDevice",
    "RobotLoudspeaker",
    "RobotMicrophones",
    "run_robot_audio",
    "serve_audio_device",
]

ROOM_RMS = 0.004  # the room's own sound at the microphones (full scale 1)
VOICE_GAIN = 0.5  # the loudspeaker's voice at the microphones
MAX_PLAYED_S = 30.0  # voice kept for the microphones (s); older is forgotten


class RobotLoudspeaker:
    """Blocks of voice played back to back, heard ``latency_s`` after each starts.

    Thread-safe: ALAudioDevice's calls arrive on qi's threads, the microphones read on the
    node's.
    """

    def __init__(self, latency_s: float, clock: Callable[[], float]) -> None:
        self.latency_s = latency_s
        self.clock = clock
        self.rate_hz = 0
        self._end_s = -np.inf  # when what is queued has been played
        self._played: deque[tuple[float, np.ndarray]] = deque()  # (heard from (s), mono)
        self._lock = threading.Lock()
        self.frames_played = 0
        self.blocks = 0

    def play(self, mono: np.ndarray, rate_hz: int) -> None:
        """Queue a block: it starts when the previous one ends, or now."""
        with self._lock:
            start = max(self.clock(), self._end_s)
            self._end_s = start + len(mono) / rate_hz
            self.rate_hz = rate_hz
            self._played.append((start + self.latency_s, mono))
            self.frames_played += len(mono)
            self.blocks += 1
            while self._played and start - self._played[0][0] > MAX_PLAYED_S:
                self._played.popleft()

    def played_audio(self) -> np.ndarray:
        """Every sample kept (the last ``MAX_PLAYED_S``), in the order played (mono)."""
        with self._lock:
            blocks = [mono for _, mono in self._played]
        return np.concatenate(blocks) if blocks else np.zeros(0)

    def flush(self) -> None:
        """Drop what has not been heard yet (ALAudioDevice's flushAudioOutputs)."""
        with self._lock:
            now = self.clock()
            self._played = deque(
                (t, s[: int((now - t) * self.rate_hz)]) for t, s in self._played if t <= now
            )
            self._end_s = now

    def heard(self, start_s: float, end_s: float, rate_hz: int) -> np.ndarray:
        """The voice heard over ``[start_s, end_s)``, sampled at ``rate_hz`` (mono)."""
        times = start_s + np.arange(round((end_s - start_s) * rate_hz)) / rate_hz
        out = np.zeros(len(times))
        with self._lock:
            played, rate = list(self._played), self.rate_hz
        for heard_s, mono in played:
            stop_s = heard_s + len(mono) / rate
            if stop_s <= start_s or heard_s >= end_s:
                continue
            inside = (times >= heard_s) & (times < stop_s)
            source = np.arange(len(mono)) / rate + heard_s
            out[inside] += np.interp(times[inside], source, mono)
        return out


class RobotMicrophones:
    """Pepper's four microphones: the room's sound with the loudspeaker's voice mixed in.

    :meth:`due` gives every 8192-frame buffer complete by ``now_s``, each with the time of its
    last sample (naoqi_driver stamps a buffer when it has it).
    """

    def __init__(self, speaker: RobotLoudspeaker, start_s: float, seed: int = 0) -> None:
        self.speaker = speaker
        self.next_start_s = start_s
        self.rng = np.random.default_rng(seed)
        self.hum_phase = 0.0

    def due(self, now_s: float) -> list[tuple[float, np.ndarray]]:
        """``(stamp of the last sample (s), (8192, 4) int16)`` buffers complete by ``now_s``."""
        out = []
        duration = MIC_FRAMES / MIC_RATE_HZ
        while self.next_start_s + duration <= now_s:
            start = self.next_start_s
            self.next_start_s += duration
            voice = VOICE_GAIN * self.speaker.heard(start, start + duration, MIC_RATE_HZ)
            voice = voice[:MIC_FRAMES]
            t = np.arange(MIC_FRAMES) / MIC_RATE_HZ
            hum = 0.5 * ROOM_RMS * np.sin(2 * np.pi * 100.0 * t + self.hum_phase)
            self.hum_phase += 2 * np.pi * 100.0 * duration
            room = self.rng.normal(0.0, ROOM_RMS, (MIC_FRAMES, MIC_CHANNELS)) + hum[:, None]
            mixed = room + voice[:, None]
            pcm = np.clip(np.round(mixed * 32767.0), -32768, 32767).astype(np.int16)
            out.append((start + (MIC_FRAMES - 1) / MIC_RATE_HZ, pcm))
        return out


class FakeAudioDevice:
    """The methods of NAOqi's ALAudioDevice the voice uses, typed as NAOqi declares them."""

    def __init__(self, speaker: RobotLoudspeaker) -> None:
        self.speaker = speaker
        self.rate_hz = 0
        self.refused = 0  # calls refused (bad rate, size or buffer)
        self.calls = 0
        self.flushes = 0  # flushAudioOutputs calls

    def counts(self) -> dict[str, int]:
        """Calls taken and refused, the output rate and the frames played."""
        return {
            "audio_device_calls": self.calls,
            "audio_device_refused": self.refused,
            "audio_device_rate_hz": self.rate_hz,
            "voice_frames_played": self.speaker.frames_played,
        }

    @qi.bind(qi.Void, [qi.String, qi.Int32])  # type: ignore[untyped-decorator]
    def setParameter(self, name: str, value: int) -> None:  # noqa: N802 (NAOqi's name)
        """``outputSampleRate`` is one of 16000, 22050, 44100, 48000; other names are ignored."""
        if name == "outputSampleRate":
            if value not in OUTPUT_RATES_HZ:
                self.refused += 1
                raise ValueError(f"outputSampleRate {value}: not one of {OUTPUT_RATES_HZ}")
            self.rate_hz = value

    @qi.bind(qi.Bool, [qi.Int32, qi.Buffer])  # type: ignore[untyped-decorator]
    def sendRemoteBufferToOutput(self, nframes: int, buffer: Any) -> bool:  # noqa: N802
        """Play ``nframes`` frames of 16-bit interleaved stereo at the output rate."""
        data = bytes(buffer)
        if not self.rate_hz or not 0 < nframes <= MAX_FRAMES_PER_CALL:
            self.refused += 1
            return False
        if len(data) != nframes * BYTES_PER_FRAME:
            self.refused += 1
            return False
        self.calls += 1
        stereo = np.frombuffer(data, dtype="<i2").reshape(nframes, 2)
        self.speaker.play(stereo.mean(axis=1) / 32768.0, self.rate_hz)
        return True

    @qi.bind(qi.Void, [])  # type: ignore[untyped-decorator]
    def flushAudioOutputs(self) -> None:  # noqa: N802 (NAOqi's name)
        """Drop what is queued and not heard yet."""
        self.flushes += 1
        self.speaker.flush()


def serve_audio_device(url: str, device: FakeAudioDevice) -> tuple[Any, str]:
    """Serve ``device`` as ALAudioDevice from a standalone qi session listening at ``url``.

    Returns:
        The session (close it to stop) and the address it listens on (the port chosen when
        ``url`` says 0).
    """
    session = qi.Session()
    session.listenStandalone(url)
    session.registerService("ALAudioDevice", device)
    endpoints = [str(e) for e in session.endpoints()]
    host = url.partition("://")[2].rpartition(":")[0]
    listening = next((e for e in endpoints if host in e), endpoints[0] if endpoints else url)
    return session, listening


def run_robot_audio(url: str, loudspeaker_latency_s: float, conn: Connection) -> None:
    """The robot's audio as a process of its own: ALAudioDevice, loudspeaker, microphones.

    On a robot the audio device is a process of its own, woken at once by each buffer; in the
    simulated Pepper's process it would wait behind the physics for the interpreter, so the
    voice would be heard later than the device's latency says. Here it runs apart, and talks to
    the simulated Pepper over ``conn``:

    - first ``("url", address served)``;
    - then ``("mic", stamp of the last sample (s), (8192, 4) int16 bytes)`` for every
      microphone buffer, and ``("counts", {...})`` twice a second;
    - it stops when ``conn`` says ``"stop"`` or is closed (its parent is gone).
    """
    speaker = RobotLoudspeaker(loudspeaker_latency_s, time.time)
    device = FakeAudioDevice(speaker)
    session, listening = serve_audio_device(url, device)
    microphones = RobotMicrophones(speaker, time.time())
    conn.send(("url", listening))
    next_counts_s = 0.0
    try:
        while not conn.poll(0.01):
            for stamp_s, pcm in microphones.due(time.time()):
                conn.send(("mic", stamp_s, pcm.tobytes()))
            if time.monotonic() >= next_counts_s:
                next_counts_s = time.monotonic() + 0.5
                conn.send(("counts", device.counts()))
    except (EOFError, OSError):  # the parent is gone
        pass
    finally:
        session.close()
