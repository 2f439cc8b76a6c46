"""The room to the pages: only identified pages get it, a slow page gets fewer pictures.

The console's server with a recording bridge on a loopback port; pictures and sound are offered
on its loop as console_node offers them. Judged by counts and order, never by time.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import aiohttp

from audio2pose_ros.console.access import resolve_access
from audio2pose_ros.console.room_feed import ROOM_HEADER, SOUND_DEPTH, RoomItem
from audio2pose_ros.console.server import ConsoleServer
from audio2pose_ros.console.server_thread import ServerThread
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.resources import share_path

TOKEN = "room-test-token-0123456789"
PICTURE_BYTES = 200_000  # a large picture, so that a page that never reads backs up quickly


class Bridge:
    """The ROS side: records the stops."""

    def __init__(self) -> None:
        self.joint_names = ["HeadYaw"]
        self.neutral = {"HeadYaw": 0.0}
        self.stops: list[bool] = []

    def publish_audio(self, frame: Any, received_s: float) -> None:
        pass

    def start_talk(self) -> None:
        pass

    def end_talk(self) -> None:
        pass

    def set_stop(self, on: bool) -> None:
        self.stops.append(on)

    def set_enable(self, on: bool) -> None:
        pass

    def set_style(self, settings: Any) -> None:
        pass

    def set_model(self, folder: str | None, fallback: Any = None) -> None:
        pass

    def pose(self) -> dict[str, Any]:
        return {"commanded": None, "measured": None}

    def status(self) -> dict[str, Any]:
        return {"stop": False}


@contextmanager
def serving(tmp_path: Path) -> Iterator[tuple[str, ConsoleServer, ServerThread, Bridge]]:
    config = ConsoleSettings(port=0, token=TOKEN)
    bridge = Bridge()
    web_dir = tmp_path / "web"
    web_dir.mkdir()
    (web_dir / "index.html").write_text("<html>console</html>")
    server = ConsoleServer(
        config,
        resolve_access(config),
        bridge,
        web_dir,
        share_path("urdf", "pepper.urdf"),
        lambda level, message: None,
    )
    thread = ServerThread(server)
    port = thread.start()
    try:
        yield f"http://127.0.0.1:{port}", server, thread, bridge
    finally:
        thread.stop()


async def page(
    session: aiohttp.ClientSession, base: str, token: str = TOKEN
) -> aiohttp.ClientWebSocketResponse:
    ws = await session.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base)
    await ws.send_str(json.dumps({"type": "hello", "token": token, "name": ""}))
    return ws


async def text(ws: aiohttp.ClientWebSocketResponse, kind: str) -> dict[str, Any]:
    """The next text message of ``kind`` (binary room messages in between are skipped)."""
    while True:
        message = await ws.receive(timeout=10.0)
        if message.type == aiohttp.WSMsgType.TEXT and json.loads(message.data)["type"] == kind:
            return json.loads(message.data)  # type: ignore[no-any-return]
        assert message.type in (aiohttp.WSMsgType.TEXT, aiohttp.WSMsgType.BINARY), message


def offer(thread: ServerThread, server: ConsoleServer, item: RoomItem) -> None:
    asyncio.run_coroutine_threadsafe(_offer(server, item), thread.loop).result(10.0)


async def _offer(server: ConsoleServer, item: RoomItem) -> None:
    server.offer_room(item)
    await asyncio.sleep(0)  # the senders run


def picture(sequence: int) -> RoomItem:
    return RoomItem(False, sequence, 0.0, 0.0, 0.0, bytes(PICTURE_BYTES))


def test_when_one_page_never_reads_expect_the_other_served_and_its_stop_taken(
    tmp_path: Path,
) -> None:
    with serving(tmp_path) as (base, server, thread, bridge):

        async def scenario() -> list[int]:
            async with aiohttp.ClientSession() as session:
                slow = await page(session, base)
                await text(slow, "welcome")
                fast = await page(session, base)
                await text(fast, "welcome")
                received: list[int] = []
                for k in range(1, 121):  # 24 MB for the page that never reads
                    await asyncio.to_thread(offer, thread, server, picture(k))
                    await asyncio.to_thread(
                        offer, thread, server, RoomItem(True, k, 0.0, -40.0, -30.0, b"\0\0" * 2720)
                    )
                    message = await fast.receive(timeout=10.0)
                    while message.type != aiohttp.WSMsgType.BINARY or message.data[:4] != b"A2PV":
                        message = await fast.receive(timeout=10.0)
                    received.append(ROOM_HEADER.unpack(message.data[: ROOM_HEADER.size])[1])
                await fast.send_str('{"type":"stop","on":true}')  # while the slow page is stuck
                await text(fast, "stop_holders")
                await slow.close()
                await fast.close()
                return received

        received = asyncio.run(asyncio.wait_for(scenario(), 120.0))
        assert bridge.stops == [True]
    assert received == sorted(received)
    assert received[-1] == 120
    assert len(received) == 120  # the page that reads gets every picture


def test_when_a_page_never_reads_expect_its_outbox_bounded_and_pictures_dropped(
    tmp_path: Path,
) -> None:
    with serving(tmp_path) as (base, server, thread, _bridge):

        async def scenario() -> tuple[int, int, int, int]:
            async with aiohttp.ClientSession() as session:
                slow = await page(session, base)
                await text(slow, "welcome")
                for k in range(1, 121):
                    await asyncio.to_thread(offer, thread, server, picture(k))
                    await asyncio.to_thread(
                        offer, thread, server, RoomItem(True, k, 0.0, -40.0, -30.0, b"\0\0" * 2720)
                    )
                (outbox,) = [s.room for s in server.sessions.values()]
                counts = (
                    outbox.sent["picture"],
                    outbox.dropped["picture"],
                    len(outbox.sound),
                    int(outbox.picture is not None),
                )
                await slow.close()
                return counts

        sent, dropped, sounds_waiting, pictures_waiting = asyncio.run(
            asyncio.wait_for(scenario(), 120.0)
        )
    assert sent + dropped + pictures_waiting == 120
    assert dropped > 0
    assert sent < 120
    assert sounds_waiting <= SOUND_DEPTH
    assert pictures_waiting <= 1


def test_when_a_page_has_no_token_expect_no_picture_nor_sound(tmp_path: Path) -> None:
    with serving(tmp_path) as (base, server, thread, _bridge):

        async def scenario() -> list[aiohttp.WSMsgType]:
            async with aiohttp.ClientSession() as session:
                stranger = await page(session, base, token="wrong-token-0123456789abc")
                offer(thread, server, picture(1))
                kinds = []
                while (message := await stranger.receive(timeout=10.0)).type not in (
                    aiohttp.WSMsgType.CLOSE,
                    aiohttp.WSMsgType.CLOSED,
                ):
                    kinds.append(message.type)
                return kinds

        kinds = asyncio.run(asyncio.wait_for(scenario(), 60.0))
        assert server.watchers == 0
    assert aiohttp.WSMsgType.BINARY not in kinds
