"""The room's thread: what waits while the canceller works is dropped oldest first, in order.

ROS-free: :class:`RoomWorker` with a canceller that records what it is given and holds its
first block until the test lets it go. Judged by order and counts, never by time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from audio2pose_ros.console.room_feed import EchoCanceller, RoomItem
from audio2pose_ros.console.room_worker import ROOM_BACKLOG, MicrophoneBlock, Picture, RoomWorker

WAIT_S = 30.0  # a hang only


class Recording(EchoCanceller):
    """Records the voice and the blocks in the order given; holds the first block."""

    def __init__(self) -> None:
        super().__init__()
        self.given: list[tuple[str, float]] = []
        self.release = threading.Event()

    def reference(self, samples: np.ndarray, published_s: float) -> None:
        self.given.append(("voice", published_s))
        super().reference(samples, published_s)

    def process(self, room: np.ndarray, arrived_s: float) -> np.ndarray:
        self.given.append(("block", arrived_s))
        self.release.wait(WAIT_S)
        return super().process(room, arrived_s)


def block(arrived_s: float, channels: tuple[int, ...] = (0, 1, 2, 3)) -> MicrophoneBlock:
    return MicrophoneBlock(48000, channels, np.zeros(8192 * 4, np.int16), 0.0, arrived_s)


def wait(condition: Callable[[], bool]) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_when_the_canceller_holds_a_block_expect_the_oldest_waiting_dropped_and_the_voice_kept():
    canceller = Recording()
    sent: list[RoomItem] = []
    worker = RoomWorker(sent.append, lambda: True, canceller)
    worker.start()
    try:
        worker.voice(np.ones(320), 0.5)
        worker.microphones(block(1.0))
        wait(lambda: ("block", 1.0) in canceller.given)  # held from now on
        for k in range(2, 8):  # six more blocks, the voice between them
            worker.voice(np.ones(320), k + 0.5)
            worker.microphones(block(float(k)))
        worker.picture(Picture(32, 24, "rgb8", 96, bytes(24 * 96), 0.0))
        worker.picture(Picture(32, 24, "rgb8", 96, bytes(24 * 96), 1.0))
        assert worker.sounds_dropped == 6 - ROOM_BACKLOG
        assert worker.pictures_dropped == 1
        canceller.release.set()
        wait(lambda: worker.blocks == 1 + ROOM_BACKLOG and worker.pictures == 1)
    finally:
        canceller.release.set()
        worker.stop()
    kept = [float(k) for k in range(8 - ROOM_BACKLOG, 8)]
    assert [t for what, t in canceller.given if what == "block"] == [1.0, *kept]
    voice = [t for what, t in canceller.given if what == "voice"]
    assert voice == [0.5, *(k + 0.5 for k in range(2, 8))]  # every chunk, in order
    # each block after the voice published before it
    assert canceller.given.index(("block", kept[0])) > canceller.given.index(("voice", 4.5))
    assert [item.sequence for item in sent] == list(range(1, len(sent) + 1))
    assert [item.sound for item in sent].count(False) == 1  # the newest picture only
    assert [item.taken_s for item in sent if not item.sound] == [1.0]


def test_when_a_block_is_malformed_expect_a_problem_kept_and_the_next_block_processed():
    sent: list[RoomItem] = []
    worker = RoomWorker(sent.append, lambda: True)
    worker.start()
    try:
        worker.microphones(block(1.0, channels=()))
        worker.picture(Picture(32, 24, "yuv422", 64, bytes(64 * 24), 0.0))
        worker.microphones(block(2.0))
        wait(lambda: worker.blocks == 1)
        problems = worker.take_problems()
    finally:
        worker.stop()
    assert [(p.what, p.refused) for p in problems] == [("picture", True), ("microphones", True)]
    assert "channel_map" in problems[1].message
    assert [item.sound for item in sent] == [True]
    assert worker.take_problems() == []
