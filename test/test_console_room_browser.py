"""The room in a real browser: the simulated Pepper's camera and microphones in the console.

Debian's Chromium, driven by Playwright, with a fake microphone playing bundled speech, against
the node graph, the simulated Pepper (its camera, its fake ALAudioDevice, loudspeaker and
microphones), voice_out_node and console_node over DDS. The page shows the camera's picture,
which changes when the head turns (``head_target``, a look-at, to the motion filter while the
operator talks); it plays the room and
shows its level; and while the operator talks, their voice, played by the robot's loudspeaker
into its microphones, comes back at least 20 dB lower. Skipped where Chromium or Playwright is
missing (see test_console_browser.py).
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np
import pytest
from background_node import BackgroundNode
from sim_console import sim_console_page
from test_console_browser import _missing

TOKEN = "room-browser-token-0123456789"
MIN_SUPPRESSION_DB = 20.0

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.alone]
if _missing():
    pytestmark.append(pytest.mark.skip(reason=_missing()))


class HeadTurner(BackgroundNode):
    """Publishes a head_target (HeadYaw, a look-at) to the motion filter at 10 Hz."""

    def __init__(self) -> None:
        from sensor_msgs.msg import JointState

        super().__init__("room_test_head")
        self.pub = self.node.create_publisher(JointState, "/head_target", 10)
        self.message = JointState(name=["HeadYaw"], position=[0.0])
        self.yaw = 0.0
        self.node.create_timer(0.1, self._publish)
        self.head_yaw: list[float] = []  # the simulated robot's measured HeadYaw
        self.node.create_subscription(JointState, "/joint_states", self._measured, 10)
        self.start()

    def _publish(self) -> None:
        if self.yaw:
            self.message.position = [self.yaw]
            self.message.header.stamp = self.node.get_clock().now().to_msg()
            self.pub.publish(self.message)

    def _measured(self, msg) -> None:
        if "HeadYaw" in msg.name:
            self.head_yaw.append(msg.position[list(msg.name).index("HeadYaw")])


def _picture(page) -> np.ndarray:
    from PIL import Image

    shot = page.locator("#room-picture").screenshot()
    return np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"), dtype=np.int16)


def _levels(page, blocks: int) -> np.ndarray:
    """(sent, heard) dBFS of the next ``blocks`` blocks of the room's sound the page receives."""
    rows = []
    for _ in range(blocks):
        seen = page.evaluate("window.a2p.room.soundBlocks")
        page.wait_for_function(f"window.a2p.room.soundBlocks > {seen}")
        room = page.evaluate("window.a2p.room")
        rows.append((room["levelDb"], room["heardDb"]))
    return np.array(rows, dtype=np.float64)


def _power(dbfs: np.ndarray) -> float:
    return float(np.mean(10.0 ** (dbfs / 10.0)))


def test_when_the_operator_talks_to_the_simulated_room_expect_its_picture_sound_and_no_echo(
    tmp_path: Path,
) -> None:
    autoplay = ["--autoplay-policy=no-user-gesture-required"]
    with sim_console_page(tmp_path, TOKEN, 760, autoplay) as page:
        turner = HeadTurner()
        try:
            page.wait_for_function(
                "window.a2p.connected && window.a2p.room.framesDrawn > 2"
                " && window.a2p.room.soundBlocks > 3 && window.a2p.room.watchers >= 1"
            )
            assert page.evaluate("window.a2p.room.playing") is True
            # the console counts this page; the badge is for the others, and there are none
            assert page.evaluate("window.a2p.room.othersWatching") == 0
            assert not page.locator("#room-watched").is_visible()
            assert page.evaluate("window.a2p.room.cameraStopped") is False  # pictures come
            ahead = _picture(page)
            silent = _levels(page, 8)

            page.click("#talk")
            page.wait_for_function("window.a2p.you === true")
            _levels(page, 12)  # the voice reaches the loudspeaker after the motion's delay
            talking = _levels(page, 30)
            # a look-at to the left while the robot moves with the voice: the red box in view
            turner.yaw = 1.0
            drawn = page.evaluate("window.a2p.room.framesDrawn")
            page.wait_for_function(f"window.a2p.room.framesDrawn > {drawn + 15}")
            turned = _picture(page)
            head_yaw = list(turner.head_yaw)
            changed = float((np.abs(turned - ahead).max(axis=2) > 40).mean())
            red = (turned[..., 0] > 150) & (turned[..., 1] < 80) & (turned[..., 2] < 80)
            age_ms = page.evaluate("window.a2p.room.frameAgeMs")

            if os.environ.get("AUDIO2POSE_CONSOLE_SHOTS"):  # the page, for the documentation
                shot = Path(os.environ["AUDIO2POSE_CONSOLE_SHOTS"]) / "console_room.png"
                page.screenshot(path=str(shot))
        finally:
            turner.close()

    assert max(head_yaw) > 0.5, f"the head did not turn: HeadYaw up to {max(head_yaw):.2f} rad"
    assert changed > 0.05, f"the picture did not follow the head ({changed:.3f} changed)"
    assert red.mean() > 0.02, "the red box to Pepper's left is not in the turned picture"
    assert age_ms is not None
    assert age_ms >= 0.0
    floor = _power(silent[:, 0])  # the room's own sound, as sent
    # blocks where the microphones heard the voice well above the room (not its pauses), so
    # that what is left of it can be told from the room's own sound
    loud = talking[talking[:, 1] >= 10.0 * math.log10(floor) + 15.0]
    assert len(loud) >= 5, "the operator's voice did not reach the robot's microphones"
    heard = _power(loud[:, 1]) - floor  # the voice as the microphones heard it
    left = max(_power(loud[:, 0]) - floor, 1e-12)  # what is left of it in what is sent
    suppression_db = 10.0 * math.log10(heard / left)
    print(f"room {10 * math.log10(floor):.1f} dBFS; voice heard {10 * math.log10(heard):.1f} "
          f"dBFS; sent {suppression_db:.1f} dB lower")  # fmt: skip
    assert suppression_db >= MIN_SUPPRESSION_DB
