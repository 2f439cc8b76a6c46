"""What the console shows of the voice out of the robot, from the voice node's /diagnostics."""

from __future__ import annotations

import pytest
from background_node import ParameterReader

from audio2pose_ros.console.protocol import ProtocolError, encode, parse_control
from audio2pose_ros.console.voice_status import RobotSeen, part_view, voice_view
from audio2pose_ros.voice.sync import WINDOW_EARLY_S, WINDOW_LATE_S

SEEN_ALL = RobotSeen(joint_states=True, microphones=True, talked=True)
REPORTED = {
    "voice_out": "naoqi:tcp://127.0.0.1:9559",
    "muted": "True",
    "graph_latency": "85 ms (measured, 12)",
    "execution_latency": "100 ms (default: not measured)",
    "loudspeaker_latency": "100 ms (default: not measured)",
    "voice_delay_ms": "100",
    "offset_ms": "-15",
}


def test_when_the_voice_node_reports_expect_each_part_measured_or_default_with_why():
    view = voice_view(REPORTED, None, SEEN_ALL, "")
    parts = view["parts"]
    assert view["available"] is True
    assert view["muted"] is True  # from the status, while the parameter is not read yet
    assert parts["graph"] == {
        "ms": 85.0,
        "measured": True,
        "why": "",
        "text": "85 ms (measured, 12)",
    }
    assert parts["execution"]["ms"] == 100.0
    assert parts["execution"]["measured"] is False
    assert parts["execution"]["why"].startswith("not measured yet")
    assert parts["loudspeaker"]["why"].startswith("not measured yet")
    assert view["delay_ms"] == 100.0
    assert view["offset_ms"] == -15.0
    assert view["window_ms"] == [-WINDOW_EARLY_S * 1e3, WINDOW_LATE_S * 1e3]
    encode("status", voice=view)  # JSON, finite numbers


def test_when_the_robot_reports_no_joint_states_nor_microphones_expect_not_measurable():
    seen = RobotSeen(joint_states=False, microphones=False, talked=True)
    parts = voice_view(REPORTED, False, seen, "")["parts"]
    assert parts["execution"]["why"] == "not measurable: the robot reports no measured joint_states"
    assert parts["loudspeaker"]["why"] == "not measurable: no robot microphones on audio"


def test_when_the_node_gives_a_note_for_a_default_part_expect_its_note():
    values = {
        **REPORTED,
        "graph_latency": "80 ms (default: not measured)",
        "graph_latency_note": "needs raw_trajectory and commanded_joint_states",
    }
    part = part_view("graph", values, SEEN_ALL)
    assert part["measured"] is False
    assert part["why"] == "not measured: needs raw_trajectory and commanded_joint_states"


def test_when_the_operator_has_not_talked_expect_the_parts_waiting_for_speech():
    seen = RobotSeen(joint_states=True, microphones=True, talked=False)
    parts = voice_view(REPORTED, False, seen, "")["parts"]
    assert parts["execution"]["why"] == "not measured yet: talk for a few seconds"


@pytest.mark.parametrize("text", ["", "soon", "NaN ms (measured, 1)", "12 s (measured, 1)"])
def test_when_a_part_is_unreadable_expect_no_number_and_the_reason(text):
    part = part_view("graph", {"graph_latency": text}, SEEN_ALL)
    assert part["ms"] is None
    assert part["measured"] is False
    assert part["why"].startswith("not reported by the voice node")


def test_when_no_voice_node_reports_expect_unavailable_and_no_parts():
    view = voice_view(None, None, SEEN_ALL, "voice_out_node's parameter service is not available")
    assert view["available"] is False
    assert view["muted"] is None
    assert view["parts"] == {}
    assert view["offset_ms"] is None
    assert view["problem"].startswith("voice_out_node")


def test_when_the_parameter_is_read_back_expect_it_over_the_status():
    assert voice_view(REPORTED, False, SEEN_ALL, "")["muted"] is False


def test_when_a_mute_message_comes_expect_it_checked():
    assert parse_control('{"type": "mute", "on": true}').fields == {"on": True}
    with pytest.raises(ProtocolError, match=r"mute\.on must be bool"):
        parse_control('{"type": "mute", "on": 1}')
    with pytest.raises(ProtocolError, match="mute needs the field 'on'"):
        parse_control('{"type": "mute"}')


@pytest.mark.ros
@pytest.mark.slow
def test_when_the_voice_node_restarts_after_a_mute_expect_the_console_to_mute_it_again(tmp_path):
    import asyncio
    import json
    import os
    import signal

    import aiohttp
    from test_console_browser import _console_url, _wait

    from audio2pose_ros.ros.console_runner import CONSOLE_NODE, console_command
    from audio2pose_ros.ros.supervisor import executable_command, node_graph
    from audio2pose_ros.ros.voice_graph import VOICE_NODE, voice_out_processes

    token = "voice-restart-token-0123456789"
    command = console_command(None, {"port": 0, "token": token}, tmp_path)
    voice_nodes, _ = voice_out_processes("topic", False, executable_command)
    logs = tmp_path / "logs"
    with node_graph(
        log_dir=logs, more_nodes={CONSOLE_NODE: command, **voice_nodes}, no_robot=True
    ) as graph:
        reader = ParameterReader(VOICE_NODE)
        try:
            base = _console_url(logs / f"{CONSOLE_NODE}.log").rstrip("/")

            async def mute() -> None:
                async with aiohttp.ClientSession() as http:
                    ws = await http.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base)
                    await ws.send_str(json.dumps({"type": "hello", "token": token}))
                    await ws.send_str('{"type": "mute", "on": true}')
                    await ws.close()

            _wait(lambda: reader.read("muted") is False, 120.0, "the voice node")
            asyncio.run(mute())
            _wait(lambda: reader.read("muted") is True, 120.0, "the mute in force")
            victim = graph.processes[VOICE_NODE]
            os.kill(victim.pid, signal.SIGKILL)
            _wait(lambda: graph.processes[VOICE_NODE] is not victim, 120.0, "the restart")
            _wait(lambda: reader.read("muted") is not None, 120.0, "the restarted node")
            _wait(lambda: reader.read("muted") is True, 120.0, "the mute set again")
        finally:
            reader.close()
    console_log = (logs / f"{CONSOLE_NODE}.log").read_text(encoding="utf-8")
    voice_log = (logs / f"{VOICE_NODE}.log").read_text(encoding="utf-8")
    assert "the operator chose True: set again" in console_log
    assert voice_log.count("parameters changed: muted=True") >= 2  # each process was muted
