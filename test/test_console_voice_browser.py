"""The operator's voice out of the robot, muted from the page: real Chromium, the real graph.

Debian's Chromium, driven by Playwright, with a fake microphone playing bundled speech, against
the node graph, voice_out_node and console_node over DDS, and the simulated Pepper, whose fake
ALAudioDevice (audio2pose_ros/voice/robot_double.py) is reached through real libqi. The page
mutes the operator's voice: the frames the fake ALAudioDevice plays stop while the joint
commands go on and the console keeps publishing the voice into the graph; the mute is shown
again after the page reconnects, and the frames resume when it is lifted. The page shows the
voice node's three latencies and the offset (``window.a2p.voice``). Skipped where Chromium or
Playwright is missing (see test_console_browser.py).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from background_node import BackgroundNode
from sim_console import sim_console_page
from test_console_browser import _missing, _wait

TOKEN = "voice-browser-token-0123456789"
HUNG_S = 120.0  # waits for the graph's events: only a hung graph reaches this
MUTED_HEARTBEATS = 6  # the simulated Pepper's heartbeats (0.5 s apart) watched while muted
MIN_COMMANDS_MUTED = 50  # joint commands that must arrive meanwhile (100 a second)

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.alone]
if _missing():
    pytestmark.append(pytest.mark.skip(reason=_missing()))


class GraphWatch(BackgroundNode):
    """Counts /joint_angles and reads /diagnostics, in its own rclpy context and thread.

    ``frames``: the voice frames the fake ALAudioDevice had played, one entry per heartbeat of
    the simulated Pepper; ``published``: the console's ``chunks_published``; ``voice``: every
    set of values voice_out_node reported.
    """

    def __init__(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from naoqi_bridge_msgs.msg import JointAnglesWithSpeed

        super().__init__("voice_test_watch")
        self.commands = 0
        self.frames: list[int] = []
        self.published = 0
        self.voice: list[dict[str, str]] = []
        self.node.create_subscription(JointAnglesWithSpeed, "/joint_angles", self._command, 100)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diagnostics, 50)
        self.start()

    def _command(self, _msg) -> None:
        self.commands += 1

    def _diagnostics(self, msg) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if "voice_frames_played" in values:
                self.frames.append(int(values["voice_frames_played"]))
            elif status.name.endswith("/voice_out_node"):
                self.voice.append(values)
            elif status.name.endswith("/console_node"):
                self.published = int(values.get("chunks_published", self.published))

    def heartbeats_after(self, count: int) -> list[int]:
        """The frames played in the simulated Pepper's next ``count`` heartbeats."""
        start = len(self.frames)
        _wait(lambda: len(self.frames) >= start + count, HUNG_S, f"{count} heartbeats")
        return self.frames[start : start + count]


def _settled(watch: GraphWatch) -> int:
    """The frames played once two heartbeats in a row report the same (what was sent arrived)."""
    while True:
        first, second = watch.heartbeats_after(2)
        if first == second:
            return second


def test_when_the_operator_mutes_their_voice_expect_the_robot_silent_and_moving_until_unmuted(
    tmp_path: Path,
) -> None:
    with sim_console_page(tmp_path, TOKEN, 900) as page:
        watch = GraphWatch()
        try:
            page.wait_for_function(
                "window.a2p.connected && window.a2p.voice.available"
                " && window.a2p.voice.muted === false"
            )
            stop_note = page.locator("#stop-note").inner_text()
            page.click("#talk")
            page.wait_for_function("window.a2p.you === true")
            _wait(lambda: watch.frames and watch.frames[-1] > 0, HUNG_S, "the voice at the robot")
            playing = watch.frames[-1]

            page.click("#voice-mute")
            page.wait_for_function("window.a2p.voice.muted === true")
            shown_muted = page.locator("#voice-state").inner_text()
            pressed = page.locator("#voice-mute").get_attribute("aria-pressed")
            silent_from = _settled(watch)
            commands, published = watch.commands, watch.published
            while_muted = watch.heartbeats_after(MUTED_HEARTBEATS)
            commands_muted = watch.commands - commands
            published_muted = watch.published - published

            page.reload()  # a reconnect: the page is told what is in force
            page.wait_for_function("window.a2p.connected && window.a2p.voice.muted !== null")
            muted_after_reconnect = page.evaluate("window.a2p.voice.muted")
            page.click("#talk")
            page.wait_for_function("window.a2p.you === true")
            page.click("#voice-mute")
            page.wait_for_function("window.a2p.voice.muted === false")
            _wait(lambda: watch.frames[-1] > while_muted[-1], HUNG_S, "the voice again")

            page.wait_for_function("window.a2p.voice.offsetMs !== null")
            voice = page.evaluate("window.a2p.voice")
            lines = page.locator("#voice-latency li").all_inner_texts()
            if os.environ.get("AUDIO2POSE_CONSOLE_SHOTS"):  # the page, for the documentation
                shot = Path(os.environ["AUDIO2POSE_CONSOLE_SHOTS"]) / "console_voice.png"
                page.locator("#voice").screenshot(path=str(shot))
        finally:
            watch.close()

    print(f"muted: frames played {while_muted}, joint commands {commands_muted}")
    print(f"chunks published {published_muted}; offset {voice['offsetMs']} ms; {voice['parts']}")
    assert "STOP stops the motion, not your voice" in stop_note
    assert playing > 0
    assert pressed == "true"
    assert shown_muted.startswith("MUTED")
    # nothing more reached the robot's loudspeaker while muted ...
    assert while_muted == [silent_from] * MUTED_HEARTBEATS, while_muted
    # ... while the robot kept moving and the voice kept reaching the graph
    assert commands_muted >= MIN_COMMANDS_MUTED
    assert published_muted > 0
    assert any(values.get("muted") == "True" for values in watch.voice)
    assert muted_after_reconnect is True
    assert watch.frames[-1] > silent_from
    # the three parts, as voice_out_node reported them, with why a default is used
    reported = {key: {values.get(key) for values in watch.voice} for key in watch.voice[0]}
    for part in ("graph", "execution", "loudspeaker"):
        shown = voice["parts"][part]
        assert shown["text"] in reported[f"{part}_latency"]
        assert isinstance(shown["ms"], int | float)
        assert shown["measured"] or shown["why"]
    assert voice["offsetMs"] is not None
    assert f"{voice['offsetMs']:+.0f}" in reported["offset_ms"]
    assert len(lines) == 4
    assert lines[0].startswith("graph: ")
    assert "the motion reaches the joints" in lines[3]
