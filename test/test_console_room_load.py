"""A room feed that takes the console's time must hold up neither its heartbeat nor a STOP.

console_node runs in the test's process on the project's own spin loop (its heartbeat paced
between callbacks); the robot's microphones (naoqi_bridge_msgs/AudioBuffer) and camera
(sensor_msgs/Image) are published by the test over DDS; a plain WebSocket client is the page,
identified, holding the floor and talking. The echo canceller is made to hold the first block of
the room until the test lets it go (``EchoCanceller.process`` waits on a gate): the slowest
canceller there is. While it holds, the console's heartbeat must keep coming, the page's status
must keep coming, a STOP the page sends must reach the ``stop`` topic, and the microphones'
buffers and pictures that come meanwhile must be dropped and counted on /diagnostics, not
queued. Judged by order and counts, never by time (the waits bound a hang only).
"""

from __future__ import annotations

import array
import asyncio
import json
import threading
import time
from typing import Any

import aiohttp
import numpy as np
import pytest
from background_node import BackgroundNode, spinning
from test_console_camera import WAIT_S, _wait

from audio2pose_ros.console.protocol import audio_frame
from audio2pose_ros.console.room_feed import EchoCanceller
from audio2pose_ros.console.room_worker import ROOM_BACKLOG

pytestmark = [pytest.mark.ros]

TOKEN = "room-load-token-0123456789"
MIC_FRAMES = 8192  # naoqi_driver's buffers: 8192 frames of 4 channels at 48 kHz (170 ms)
HEARTBEATS = 3  # heartbeats that must come while the canceller holds its block
BUFFERS_WHILE_HELD = 10  # microphone buffers published while it holds (ROOM_BACKLOG wait)
PICTURES_WHILE_HELD = 5


class Graph(BackgroundNode):
    """The robot's microphones and camera, and what console_node says on /diagnostics and stop.

    ``events`` holds, in order of arrival, ``("heartbeat", values)`` for each of console_node's
    statuses and ``("stop", on)`` for each stop message.
    """

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from naoqi_bridge_msgs.msg import AudioBuffer
        from sensor_msgs.msg import Image
        from std_msgs.msg import Bool

        from audio2pose_ros.ros.qos import LATCHED_QOS

        super().__init__("room_load_graph")
        self.lock = threading.Lock()
        self.events: list[tuple[str, Any]] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 50)
        self.node.create_subscription(Bool, "stop", self._on_stop, LATCHED_QOS)
        self.microphones = self.node.create_publisher(AudioBuffer, "audio", 50)
        self.camera = self.node.create_publisher(Image, "camera/front/image_raw", 10)
        noise = np.random.default_rng(0).normal(0.0, 2000.0, MIC_FRAMES * 4)
        self.buffer = AudioBuffer(frequency=48000, channel_map=[0, 1, 2, 3])
        self.buffer.data = array.array("h", noise.astype(np.int16).tobytes())
        self.image = Image(height=24, width=32, encoding="rgb8", step=96, data=bytes(24 * 96))
        self.start()

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            if status.name.endswith("/console_node"):
                with self.lock:
                    self.events.append(("heartbeat", {v.key: v.value for v in status.values}))

    def _on_stop(self, msg: Any) -> None:
        with self.lock:
            self.events.append(("stop", bool(msg.data)))

    def mark(self) -> int:
        with self.lock:
            return len(self.events)

    def since(self, start: int, kind: str) -> list[Any]:
        with self.lock:
            return [value for what, value in self.events[start:] if what == kind]


def test_when_the_echo_canceller_holds_a_block_expect_heartbeats_the_stop_and_drops_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from audio2pose_ros.ros.executor import create_executor
    from audio2pose_ros.ros.nodes.console_node import ConsoleNode
    from audio2pose_ros.ros.player import rclpy_session

    held: list[int] = []  # blocks the canceller was given
    release = threading.Event()
    process = EchoCanceller.process

    def gated(self: EchoCanceller, room: np.ndarray, arrived_s: float) -> np.ndarray:
        held.append(room.size)
        release.wait(WAIT_S)  # the slowest canceller: until the test lets it go
        return process(self, room, arrived_s)

    monkeypatch.setattr(EchoCanceller, "process", gated)
    with rclpy_session(["--ros-args", "-p", "port:=0", "-p", f"token:={TOKEN}"]):
        console = ConsoleNode()
        with spinning(console, create_executor()):
            graph = Graph()
            base = console.access.url(console.server.port).split("#")[0].rstrip("/")
            try:
                statuses, stops_seen = asyncio.run(
                    asyncio.wait_for(_scenario(base, graph, held, release), 4 * WAIT_S)
                )
            finally:
                release.set()
                graph.close()
    assert stops_seen == 1
    assert statuses >= 2  # the page's status kept coming while the canceller held its block


async def _scenario(
    base: str, graph: Graph, held: list[int], release: threading.Event
) -> tuple[int, int]:
    """What the page does and sees; returns the statuses it got while the block was held."""
    async with aiohttp.ClientSession() as http:
        ws = await http.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base)
        await ws.send_str(json.dumps({"type": "hello", "token": TOKEN, "name": "operator"}))
        kinds: list[str] = []
        reading = asyncio.create_task(_read(ws, kinds))
        await ws.send_str('{"type":"talk","on":true}')
        voice = (np.sin(np.arange(320) * 0.3) * 8000).astype("<i2").tobytes()
        for k in range(10):  # the operator's voice: the canceller's reference
            await ws.send_bytes(audio_frame(k, time.time() * 1e3, voice))

        def taken() -> bool:  # published until the console hears it (discovery takes a while)
            if not held:
                graph.microphones.publish(graph.buffer)
            return bool(held)

        await asyncio.to_thread(_wait, taken, "the canceller to take a block")

        start = graph.mark()  # from here on the canceller holds its block
        statuses_before = kinds.count("status")
        for k in range(BUFFERS_WHILE_HELD):
            graph.microphones.publish(graph.buffer)
            if k < PICTURES_WHILE_HELD:
                graph.camera.publish(graph.image)
            await ws.send_bytes(audio_frame(10 + k, time.time() * 1e3, voice))
            await asyncio.sleep(0.1)  # pictures further apart than the console's 15 a second

        def beats() -> list[dict[str, str]]:
            return list(graph.since(start, "heartbeat"))

        await asyncio.to_thread(
            _wait, lambda: len(beats()) >= HEARTBEATS, "heartbeats while the block is held"
        )
        await ws.send_str('{"type":"stop","on":true}')
        await asyncio.to_thread(
            _wait, lambda: True in graph.since(start, "stop"), "the stop published"
        )
        await asyncio.to_thread(
            _wait,
            lambda: any(
                int(v["room_sounds_dropped_behind"]) >= 1
                and int(v["room_pictures_dropped_behind"]) >= 1
                for v in beats()
            ),
            "the buffers and pictures that came meanwhile counted as dropped",
        )
        # the page's status keeps coming: two more before the block is let go (a loaded
        # machine may take longer than the drops above to send them, never forever)
        await asyncio.to_thread(
            _wait,
            lambda: kinds.count("status") - statuses_before >= 2,
            "the page's status while the block is held",
        )
        assert len(held) == 1  # all of it while the canceller held its first block
        statuses = kinds.count("status") - statuses_before
        stops_seen = graph.since(start, "stop").count(True)

        release.set()
        await asyncio.to_thread(
            _wait,
            lambda: any(int(v["room_sound_blocks"]) >= 2 for v in graph.since(start, "heartbeat")),
            "the room's sound processed again",
        )
        # what came while the block was held was dropped down to the backlog, not queued
        assert len(held) <= 1 + ROOM_BACKLOG
        reading.cancel()
        await ws.close()
        return statuses, stops_seen


async def _read(ws: aiohttp.ClientWebSocketResponse, kinds: list[str]) -> None:
    """Keep the kinds of the text messages the page gets (the room's binary ones skipped)."""
    async for message in ws:
        if message.type == aiohttp.WSMsgType.TEXT:
            kinds.append(json.loads(message.data)["type"])
