"""The robot's camera stops and comes back: console_node says so on /diagnostics and to the pages.

console_node runs as a process of its own over DDS; the camera is another process publishing
sensor_msgs/Image on camera/front/image_raw, as naoqi_driver and the simulated Pepper do. It is
killed (a dead camera process): /diagnostics turns WARN naming the topic and the last picture's
age, and the status every page gets says the camera has stopped and since when; a new camera
process brings both back. Judged by the order of what is reported, never by time.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from background_node import BackgroundNode
from test_console_browser import _console_url

TOKEN = "camera-test-token-0123456789"
WAIT_S = 60.0  # only a hung graph takes this long
CAMERA = """
import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

rclpy.init()
node = Node("test_camera")
pub = node.create_publisher(Image, "camera/front/image_raw", qos_profile_sensor_data)
image = Image(height=24, width=32, encoding="rgb8", step=96, data=bytes(24 * 96))
node.create_timer(0.1, lambda: pub.publish(image))
rclpy.spin(node)
"""

pytestmark = [pytest.mark.ros, pytest.mark.slow]


class Diagnostics(BackgroundNode):
    """console_node's statuses on /diagnostics, as they arrive (level, message, values)."""

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        super().__init__("camera_test_diagnostics")
        self.seen: list[tuple[int, str, dict[str, str]]] = []
        self.lock = threading.Lock()
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 50)
        self.start()

    def _on(self, msg: Any) -> None:
        for status in msg.status:
            if status.name.endswith("/console_node"):
                level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
                values = {v.key: v.value for v in status.values}
                with self.lock:
                    self.seen.append((level, status.message, values))

    def wait_for(self, what: str, test: Callable[[int, str, dict[str, str]], bool]) -> str:
        """The message of the first status from now on that passes ``test``."""
        with self.lock:
            start = len(self.seen)
        found: list[str] = []

        def seen() -> bool:
            with self.lock:
                found[:] = [m for level, m, v in self.seen[start:] if test(level, m, v)]
            return bool(found)

        _wait(seen, what)
        return found[0]


def _wait(condition: Callable[[], bool], what: str) -> None:
    import time

    deadline = time.monotonic() + WAIT_S
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.1)


def page_camera(url: str, test: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
    """The ``camera`` of the first status message a page gets that passes ``test``."""

    async def read() -> dict[str, Any]:
        base = url.rstrip("/")
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base)
            await ws.send_str(json.dumps({"type": "hello", "token": TOKEN, "name": "watcher"}))
            while True:
                message = await ws.receive(timeout=WAIT_S)
                if message.type == aiohttp.WSMsgType.BINARY:
                    continue  # the room's pictures
                assert message.type == aiohttp.WSMsgType.TEXT, message
                data = json.loads(message.data)
                if data["type"] == "status" and test(data["camera"]):
                    await ws.close()
                    return dict(data["camera"])

    return asyncio.run(asyncio.wait_for(read(), WAIT_S))


@contextmanager
def process(command: list[str], log: Path) -> Iterator[subprocess.Popen[bytes]]:
    with log.open("wb") as out:
        child = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    try:
        yield child
    finally:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
            try:
                child.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                child.kill()
                child.wait()


def test_when_the_camera_process_dies_and_another_starts_expect_a_warning_then_ok(
    tmp_path: Path,
) -> None:
    from audio2pose_ros.ros.console_runner import console_command

    command = console_command(None, {"port": 0, "token": TOKEN}, tmp_path)
    diagnostics = Diagnostics()
    try:
        with process(command, tmp_path / "console_node.log"):
            url = _console_url(tmp_path / "console_node.log")
            with process([sys.executable, "-c", CAMERA], tmp_path / "camera1.log") as camera:
                diagnostics.wait_for(
                    "pictures counted, the console OK",
                    lambda level, _, values: level == 0 and values["camera_frames"] != "0",
                )
                running = page_camera(url, lambda c: c["frames"] > 0)
                os.kill(camera.pid, signal.SIGKILL)  # the camera's process dies
                camera.wait()
            warning = diagnostics.wait_for("a warning", lambda level, _, __: level == 1)
            stopped = page_camera(url, lambda c: c["stopped"])
            with process([sys.executable, "-c", CAMERA], tmp_path / "camera2.log"):
                back = diagnostics.wait_for(
                    "OK again",
                    lambda level, _, values: level == 0 and values["camera_stops"] == "1",
                )
                again = page_camera(url, lambda c: not c["stopped"])
    finally:
        diagnostics.close()

    assert running["topic"] == "/camera/front/image_raw"
    assert running["stopped"] is False
    assert "no picture on /camera/front/image_raw for " in warning
    assert stopped["age_s"] >= 3.0  # no picture for as long as the console waits
    assert stopped["last_s"] is not None
    assert stopped["frames"] >= running["frames"]
    assert "no picture" not in back
    assert again["frames"] > stopped["frames"]
    assert again["age_s"] < stopped["age_s"]
