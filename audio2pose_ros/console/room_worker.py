"""The room's work in a thread of its own, so that it never holds up the console's STOP path.

Decoding the robot's microphones, removing the operator's echo from them
(:class:`~audio2pose_ros.console.room_feed.EchoCanceller`: 45 ms median, up to 250 ms, for one
170 ms block while the operator talks, on a two-core machine) and encoding the camera's pictures
as JPEG take a lot of a slow machine's time. The console's executor (its heartbeat, the latched
stop and enable it shows) and the lock its snapshots for the pages share (the pose and status
every page gets, the voice the server publishes) must never wait on them: a STOP goes page ->
server -> ``stop`` topic through that loop. So :class:`RoomWorker` does that work in one thread
of its own, and the others only hand it what came:

- **Microphones** (:meth:`RoomWorker.microphones`, from the executor): each buffer as it came,
  at most :data:`ROOM_BACKLOG` waiting; when the worker is behind, the oldest waiting one is
  dropped (``sounds_dropped``), so the pages' sound stays recent and the work per second bounded.
- **The operator's voice** (:meth:`RoomWorker.voice`, from the server's thread): the chunks the
  console published, queued between the microphones' buffers in the order they came, so that the
  canceller sees the voice published before each block as it did in one thread; at most
  :data:`VOICE_BACKLOG` chunks wait (the oldest dropped, ``voice_dropped``: the canceller takes
  the gap for a skipped chunk).
- **Pictures** (:meth:`RoomWorker.picture`, from the executor): the newest one only; a newer one
  replaces the one not yet encoded (``pictures_dropped``). A waiting picture goes before the
  next block of sound (a JPEG takes milliseconds).

The canceller and the decoder belong to the worker's thread alone. What it makes for the pages
goes to ``send`` (called in the worker's thread); bad input and failures are kept for the owner
to report (:meth:`RoomWorker.take_problems`), never raised in the thread.
"""

from __future__ import annotations

import threading
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, encode_pcm
from audio2pose_ros.audio.source import AudioInput, AudioInputSettings
from audio2pose_ros.console.room_feed import EchoCanceller, RoomItem, jpeg_from_image, level_dbfs
from audio2pose_ros.errors import InputError

__all__ = [
    "ROOM_BACKLOG",
    "VOICE_BACKLOG",
    "MicrophoneBlock",
    "Picture",
    "RoomProblem",
    "RoomWorker",
]

ROOM_BACKLOG = 3  # microphone buffers waiting at most (about 0.5 s of naoqi_driver's 170 ms)
VOICE_BACKLOG = 400  # chunks of the operator's voice waiting at most (8 s of 20 ms chunks)
MAX_PROBLEMS = 16  # problems kept for the owner between two takes (the oldest dropped)


@dataclass(frozen=True)
class MicrophoneBlock:
    """One naoqi_bridge_msgs/AudioBuffer's fields, as it arrived.

    Attributes:
        frequency: its sample rate (Hz).
        channel_map: its channels.
        data: its interleaved int16 samples (a copy).
        taken_s: wall-clock time of its last sample (s).
        arrived_s: monotonic time it arrived (s).
    """

    frequency: int
    channel_map: tuple[int, ...]
    data: np.ndarray
    taken_s: float
    arrived_s: float


@dataclass(frozen=True)
class Picture:
    """One sensor_msgs/Image's fields and when it was taken (wall-clock s)."""

    width: int
    height: int
    encoding: str
    step: int
    data: bytes
    taken_s: float


@dataclass(frozen=True)
class RoomProblem:
    """Bad input (``refused``) or a failure in the worker, for its owner to report.

    Attributes:
        what: ``microphones`` or ``picture``.
        refused: bad input (an :class:`~audio2pose_ros.errors.InputError`), not a bug.
        message: what happened.
        trace: the traceback of a failure ("" for bad input).
    """

    what: str
    refused: bool
    message: str
    trace: str = ""


@dataclass(frozen=True)
class _Voice:
    samples: np.ndarray
    published_s: float


class RoomWorker:
    """Decode, cancel the echo and encode the room's pictures in one thread of its own.

    Args:
        send: gets every picture and block of sound for the pages (in the worker's thread).
        watched: whether any page watches now (nothing is encoded for nobody; the microphones
            are still decoded and cancelled, so that the canceller keeps up with the room).
        canceller: the echo canceller (its state belongs to the worker's thread from now on).
        backlog: microphone buffers waiting at most.

    Attributes:
        sounds_dropped, pictures_dropped, voice_dropped: what waited too long, dropped.
        blocks, pictures: microphone buffers processed and pictures encoded.
        level_dbfs: the level of the last block of sound sent (``nan`` before one).
        echo_delay_s: the echo's delay found last (``nan`` before one).
    """

    def __init__(
        self,
        send: Callable[[RoomItem], None],
        watched: Callable[[], bool],
        canceller: EchoCanceller | None = None,
        backlog: int = ROOM_BACKLOG,
    ) -> None:
        self._send = send
        self._watched = watched
        self._canceller = EchoCanceller() if canceller is None else canceller
        self._decoder = AudioInput(AudioInputSettings(input_type="naoqi"))
        self._backlog = backlog
        self._changed = threading.Condition()
        self._sound: deque[MicrophoneBlock | _Voice] = deque()  # in the order they came
        self._waiting_blocks = 0
        self._waiting_voice = 0
        self._picture: Picture | None = None
        self._problems: deque[RoomProblem] = deque(maxlen=MAX_PROBLEMS)
        self._stopping = False
        self._sequence = 0
        self.sounds_dropped = 0
        self.pictures_dropped = 0
        self.voice_dropped = 0
        self.blocks = 0
        self.pictures = 0
        self.level_dbfs = float("nan")
        self.echo_delay_s = float("nan")
        self._thread = threading.Thread(target=self._run, name="console-room", daemon=True)

    def start(self) -> None:
        """Start the worker's thread."""
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop after the item in hand (what waits is dropped)."""
        with self._changed:
            self._stopping = True
            self._changed.notify()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    # --- handing over (any thread) ------------------------------------------------------------

    def voice(self, samples: np.ndarray, published_s: float) -> None:
        """The operator's voice as the console published it at ``published_s`` (monotonic)."""
        with self._changed:
            if self._waiting_voice >= VOICE_BACKLOG:
                self._drop_oldest(_Voice)
                self.voice_dropped += 1
            self._sound.append(_Voice(np.asarray(samples), published_s))
            self._waiting_voice += 1
            self._changed.notify()

    def microphones(self, block: MicrophoneBlock) -> None:
        """A buffer of the robot's microphones; the oldest waiting one dropped when behind."""
        with self._changed:
            if self._waiting_blocks >= self._backlog:
                self._drop_oldest(MicrophoneBlock)
                self.sounds_dropped += 1
            self._sound.append(block)
            self._waiting_blocks += 1
            self._changed.notify()

    def picture(self, picture: Picture) -> None:
        """A picture of the camera; it replaces the one not yet encoded."""
        with self._changed:
            if self._picture is not None:
                self.pictures_dropped += 1
            self._picture = picture
            self._changed.notify()

    def take_problems(self) -> list[RoomProblem]:
        """The problems met since the last call (at most :data:`MAX_PROBLEMS`, the newest)."""
        with self._changed:
            problems = list(self._problems)
            self._problems.clear()
        return problems

    def _drop_oldest(self, kind: type) -> None:
        for k, item in enumerate(self._sound):
            if isinstance(item, kind):
                del self._sound[k]
                if kind is MicrophoneBlock:
                    self._waiting_blocks -= 1
                else:
                    self._waiting_voice -= 1
                return

    # --- the worker's thread ------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._changed:
                while not self._stopping and not self._sound and self._picture is None:
                    self._changed.wait()
                if self._stopping:
                    return
                item: Picture | MicrophoneBlock | _Voice
                if self._picture is not None:
                    item, self._picture = self._picture, None
                else:
                    item = self._sound.popleft()
                    if isinstance(item, MicrophoneBlock):
                        self._waiting_blocks -= 1
                    else:
                        self._waiting_voice -= 1
            if isinstance(item, _Voice):
                self._canceller.reference(item.samples, item.published_s)
            else:
                self._guarded(item)

    def _guarded(self, item: Picture | MicrophoneBlock) -> None:
        what = "picture" if isinstance(item, Picture) else "microphones"
        try:
            if isinstance(item, Picture):
                self._encode(item)
            else:
                self._hear(item)
        except InputError as exc:
            self._keep(RoomProblem(what, True, str(exc)))
        except Exception as exc:  # the thread's boundary: a bug must not end the room's feed
            self._keep(
                RoomProblem(what, False, f"{type(exc).__name__}: {exc}", traceback.format_exc())
            )

    def _keep(self, problem: RoomProblem) -> None:
        with self._changed:
            self._problems.append(problem)

    def _encode(self, picture: Picture) -> None:
        jpeg = jpeg_from_image(
            picture.width, picture.height, picture.encoding, picture.step, picture.data
        )
        self.pictures += 1
        self._offer(False, picture.taken_s, jpeg, (0.0, 0.0))

    def _hear(self, block: MicrophoneBlock) -> None:
        samples, _ = self._decoder.decode_audio_buffer(
            block.frequency, block.channel_map, block.data
        )
        room = self._canceller.process(samples, block.arrived_s)
        self.blocks += 1
        self.echo_delay_s = self._canceller.delay_s
        level, heard = level_dbfs(room), level_dbfs(samples)
        self.level_dbfs = level
        if room.size and self._watched():
            self._offer(True, block.taken_s, encode_pcm(room, S16LE_MONO_16K), (level, heard))

    def _offer(
        self, sound: bool, taken_s: float, payload: bytes, levels: tuple[float, float]
    ) -> None:
        self._sequence += 1
        self._send(RoomItem(sound, self._sequence, taken_s, *levels, payload))
