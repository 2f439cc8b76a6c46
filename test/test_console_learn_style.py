"""The console's "learn my style" without a browser: tickets, uploads and learning runs, and the
real aiohttp server driven by a real WebSocket and HTTP client.

The learning child here is a short Python program that behaves as the real worker does at its
edge (progress lines, then the settings line, or a failure line and an exit status); the real
worker, with the importer and the style fit, runs in test_console_learn_style_browser.py. An
upload is checked before it is accepted: the uploads here are a real one-second recording.
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import json
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import AsyncIterator, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from audio2pose_ros.console import enrollment
from audio2pose_ros.console.access import resolve_access
from audio2pose_ros.console.enrollment import EnrollmentError, Enrollments
from audio2pose_ros.console.protocol import ProtocolError, parse_control
from audio2pose_ros.console.server import ConsoleServer
from audio2pose_ros.console.server_thread import ServerThread
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.data.importers.media import ffmpeg_executable
from audio2pose_ros.resources import share_path

TOKEN = "learn-style-token-0123456789"
SETTINGS = {"head_gain": 0.5, "arms_tempo": 0.6}  # the style alone, against the packaged model
MODEL_SETTINGS = {"head_gain": 0.5, "arms_tempo": 0.8}  # the style fitted to the personal model
VERDICTS = [
    {
        "part": "head",
        "learned": True,
        "gain": 0.061,
        "spread": 0.02,
        "reason": "",
        "line": "head: learned (style, 40% of the way from the default), expected to come "
        "0.061 ± 0.020 closer to the person",
    },
    {
        "part": "arms",
        "learned": False,
        "gain": 0.0,
        "spread": 0.0,
        "reason": "no learned fit came closer",
        "line": "arms: kept the default (no learned fit came closer)",
    },
]
MODEL_LINE = "PERSONAL_MODEL " + json.dumps({"settings": MODEL_SETTINGS, "verdicts": VERDICTS})


def child(body: str) -> list[str]:
    """A learning child: ``body`` runs with ``rec`` and ``folder`` (paths) defined."""
    prelude = "import json, pathlib, sys, time\nrec, folder = map(pathlib.Path, sys.argv[1:3])\n"
    return [sys.executable, "-c", prelude + textwrap.dedent(body)]


LEARNS = child(
    f"""
    assert rec.stat().st_size > 0
    folder.mkdir(parents=True)
    (folder / "style.yaml").write_text("parts: {{}}")
    print("tracking face and body", flush=True)
    print({MODEL_LINE!r}, flush=True)
    print("STYLE_SETTINGS " + json.dumps({SETTINGS!r}), flush=True)
    """
)


@functools.cache
def real_recording() -> bytes:
    """A real recording: one second of a small grey picture and a tone (Matroska, a few KB)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "recording.mkv"
        subprocess.run(
            [ffmpeg_executable(), "-v", "error", "-f", "lavfi", "-i",
             "color=c=gray:s=64x48:r=10:d=1", "-f", "lavfi", "-i", "sine=duration=1",
             "-c:v", "mjpeg", "-c:a", "flac", str(path)],
            check=True,
        )  # fmt: skip
        return path.read_bytes()


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


async def chunks(*parts: bytes) -> AsyncIterator[bytes]:
    for part in parts:
        yield part


def run(coroutine: Any) -> Any:
    return asyncio.run(asyncio.wait_for(coroutine, 60.0))


# --- tickets --------------------------------------------------------------------------------


def test_when_a_ticket_is_used_expect_it_gone_and_a_second_upload_refused(tmp_path):
    jobs = Enrollments(tmp_path, LEARNS)
    key = jobs.ticket(1, "Ann", keep=False)
    ticket, path = run(jobs.receive(key, "video/webm", chunks(real_recording())))
    assert (ticket.session, ticket.owner, path.read_bytes()) == (1, "Ann", real_recording())
    with pytest.raises(EnrollmentError, match="unknown, used or expired"):
        run(jobs.receive(key, "video/webm", chunks(b"y")))


def test_when_a_ticket_expires_expect_the_upload_refused_and_the_console_idle(tmp_path):
    clock = Clock()
    jobs = Enrollments(tmp_path, LEARNS, clock=clock)
    key = jobs.ticket(1, "Ann", keep=False)
    assert jobs.status()["state"] == "waiting"
    clock.now = enrollment.TICKET_TTL_S + 1.0
    assert not jobs.busy
    assert jobs.status()["state"] == "idle"
    with pytest.raises(EnrollmentError, match="expired"):
        run(jobs.receive(key, "video/webm", chunks(b"x")))


def test_when_one_operator_is_recording_expect_another_refused_until_they_leave(tmp_path):
    jobs = Enrollments(tmp_path, LEARNS)
    jobs.ticket(1, "Ann", keep=False)
    with pytest.raises(EnrollmentError, match="Ann is already teaching a style"):
        jobs.ticket(2, "Bob", keep=False)
    jobs.forget_session(1)
    assert jobs.ticket(2, "Bob", keep=False)


@pytest.mark.parametrize(
    ("content_type", "parts", "match"),
    [
        ("text/html", [b"x"], "must be one of"),
        ("video/webm", [], "empty"),
        ("video/webm", [b"x" * 600, b"x" * 600], "over"),
    ],
)
def test_when_an_upload_is_refused_expect_nothing_of_it_kept(
    tmp_path, monkeypatch, content_type, parts, match
):
    monkeypatch.setattr(enrollment, "MAX_RECORDING_BYTES", 1000)
    jobs = Enrollments(tmp_path / "work", LEARNS)
    key = jobs.ticket(1, "Ann", keep=False)
    with pytest.raises(EnrollmentError, match=match):
        run(jobs.receive(key, content_type, chunks(*parts)))
    assert not [p for p in (tmp_path / "work").rglob("*") if p.is_file()]
    assert jobs.status()["state"] == "idle"


def test_when_an_upload_trickles_expect_it_dropped_and_the_slot_free(tmp_path, monkeypatch):
    monkeypatch.setattr(enrollment, "UPLOAD_TIMEOUT_S", 0.5)

    async def trickle() -> AsyncIterator[bytes]:
        while True:
            yield b"x"
            await asyncio.sleep(0.05)

    jobs = Enrollments(tmp_path / "work", LEARNS)
    key = jobs.ticket(1, "Ann", keep=False)
    with pytest.raises(EnrollmentError, match=r"did not arrive within 0\.5 s"):
        run(jobs.receive(key, "video/webm", trickle()))
    assert not [p for p in (tmp_path / "work").rglob("*") if p.is_file()]
    assert not jobs.busy
    assert jobs.ticket(2, "Bob", keep=False)


# --- learning -------------------------------------------------------------------------------


def _learn(jobs: Enrollments, keep: bool) -> tuple[Path, Any]:
    key = jobs.ticket(1, "Ann", keep=keep)
    ticket, path = run(jobs.receive(key, "video/webm", chunks(real_recording())))
    return path, run(jobs.run(ticket, path))


def test_when_learning_succeeds_expect_the_settings_and_the_recording_deleted(tmp_path):
    jobs = Enrollments(tmp_path, LEARNS)
    recording, result = _learn(jobs, keep=False)
    assert result.settings == SETTINGS
    assert (result.folder / "style.yaml").is_file()
    assert not recording.exists()
    assert result.kept_recording is None
    assert sorted(p.name for p in recording.parent.iterdir()) == ["style"]
    assert jobs.status() == {
        "state": "ready",
        "owner": "Ann",
        "message": "learned Ann's style",
        "personal": "style",
        "verdicts": VERDICTS,
    }


def test_when_enrolment_fits_the_arms_noise_expect_the_message_to_say_it_and_the_verdicts(
    tmp_path,
):
    """The personal model, its own checkpoint included, runs live: no restart to ask for."""
    writes_a_model = child(
        f"""
        folder.mkdir(parents=True)
        (folder / "style.yaml").write_text("parts: {{}}")
        (folder / "model.safetensors").write_bytes(b"model")
        print({MODEL_LINE!r}, flush=True)
        print("STYLE_SETTINGS " + json.dumps({SETTINGS!r}), flush=True)
        """
    )
    jobs = Enrollments(tmp_path, writes_a_model)
    _, result = _learn(jobs, keep=False)
    assert result.settings == SETTINGS
    assert result.model_settings == MODEL_SETTINGS
    assert result.verdicts == VERDICTS
    assert jobs.status()["verdicts"] == VERDICTS
    assert jobs.status()["message"] == (
        "learned Ann's style; with its arms' own noise (a model of its own)"
    )


def test_when_the_operator_keeps_the_recording_expect_it_beside_the_style(tmp_path):
    jobs = Enrollments(tmp_path, LEARNS)
    recording, result = _learn(jobs, keep=True)
    assert not recording.exists()
    assert result.kept_recording == result.folder / "recording.webm"
    assert result.kept_recording.read_bytes() == real_recording()


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (
            'print("ENROLL_FAILED the video has no audio track", flush=True); sys.exit(1)',
            "^the video has no audio track$",
        ),
        (  # a progress line is not a reason
            'print("tracking face and body", flush=True); sys.exit(1)',
            r"^the learning process ended \(exit code 1\) without a result$",
        ),
        (
            'import os, signal; print("tracking face and body", flush=True); '
            "os.kill(os.getpid(), signal.SIGKILL)",
            r"stopped by signal 9 \(a crash, or its memory bound of 1\.5 GiB reached\)",
        ),
        ('print("STYLE_SETTINGS " + json.dumps({"head_gain": float("nan")}))', "not finite"),
        ('print("STYLE_SETTINGS [1, 2]")', "not finite"),
        ('print("STYLE_SETTINGS {")', "unreadable"),
        ('print("done, but no settings")', "without a result"),
        (  # the personal model is part of the result
            'print("STYLE_SETTINGS " + json.dumps({"head_gain": 1.0}))',
            "without a result",
        ),
        ('print("PERSONAL_MODEL {")', "unreadable personal model"),
        ('print("PERSONAL_MODEL " + json.dumps({"settings": {}}))', "without verdicts"),
        (
            'print("PERSONAL_MODEL " + json.dumps({"settings": {}, "verdicts": [3]}))',
            "verdict that cannot be read",
        ),
    ],
)
def test_when_learning_fails_expect_the_reason_and_nothing_left(tmp_path, body, match):
    jobs = Enrollments(tmp_path, child(body))
    key = jobs.ticket(1, "Ann", keep=True)
    ticket, recording = run(jobs.receive(key, "video/webm", chunks(real_recording())))
    with pytest.raises(EnrollmentError, match=match):
        run(jobs.run(ticket, recording))
    assert not recording.parent.exists()  # the recording too, although it was to be kept
    assert jobs.status()["state"] == "failed"
    assert jobs.result is None
    assert jobs.failed == 1


def test_when_learning_hangs_expect_the_child_killed_after_the_timeout(tmp_path, monkeypatch):
    monkeypatch.setattr(enrollment, "ENROLL_TIMEOUT_S", 1.0)
    jobs = Enrollments(tmp_path, child('print("started", flush=True); time.sleep(600)'))
    key = jobs.ticket(1, "Ann", keep=False)
    ticket, recording = run(jobs.receive(key, "video/webm", chunks(real_recording())))
    with pytest.raises(EnrollmentError, match="took over 1 s"):
        run(jobs.run(ticket, recording))
    assert not recording.parent.exists()


# --- protocol -------------------------------------------------------------------------------


def test_when_style_messages_are_sent_expect_them_checked():
    assert parse_control('{"type":"enroll","keep":false}').fields == {"keep": False}
    assert parse_control('{"type":"style","use":"default"}').fields == {"use": "default"}
    for text in ('{"type":"style","use":"/etc/passwd"}', '{"type":"enroll","keep":"yes"}'):
        with pytest.raises(ProtocolError):
            parse_control(text)


# --- the server -----------------------------------------------------------------------------


class Bridge:
    """The ROS side, recorded."""

    def __init__(self) -> None:
        self.joint_names = ["HeadYaw"]
        self.neutral = {"HeadYaw": 0.0}
        self.styles: list[dict[str, float] | None] = []
        self.models: list[str | None] = []
        self.fallbacks: list[dict[str, float] | None] = []
        self.stopped = False

    def publish_audio(self, frame: Any, received_s: float) -> None:
        pass

    def start_talk(self) -> None:
        pass

    def end_talk(self) -> None:
        pass

    def set_stop(self, on: bool) -> None:
        pass

    def set_enable(self, on: bool) -> None:
        pass

    def set_style(self, settings: dict[str, float] | None) -> None:
        self.styles.append(settings)

    def set_model(self, folder: str | None, fallback: Any = None) -> None:
        self.models.append(folder)
        self.fallbacks.append(fallback)

    def pose(self) -> dict[str, Any]:
        return {"commanded": None, "measured": None}

    def status(self) -> dict[str, Any]:
        return {"stop": self.stopped}


@contextmanager
def serving(tmp_path: Path, command: list[str]) -> Iterator[tuple[str, Bridge]]:
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
        enrollments=Enrollments(tmp_path / "styles", command),
    )
    thread = ServerThread(server)
    port = thread.start()
    try:
        yield f"http://127.0.0.1:{port}", bridge
    finally:
        thread.stop()


async def connect(session: aiohttp.ClientSession, base: str, name: str) -> Any:
    ws = await session.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base)
    await ws.send_str(json.dumps({"type": "hello", "token": TOKEN, "name": name}))
    return ws


async def until(ws: Any, kind: str, check: Any = None) -> dict[str, Any]:
    while True:
        message = await ws.receive(timeout=20.0)
        assert message.type == aiohttp.WSMsgType.TEXT, message
        data = json.loads(message.data)
        if data["type"] == kind and (check is None or check(data)):
            return data


def test_when_an_operator_uploads_a_recording_expect_the_style_applied_then_undone(tmp_path):
    async def scenario(base: str, bridge: Bridge) -> None:
        async with aiohttp.ClientSession() as http:
            ws = await connect(http, base, "Ann")
            await ws.send_str('{"type":"enroll","keep":false}')
            ticket = (await until(ws, "enroll_ticket"))["ticket"]
            headers = {"Content-Type": "video/webm", "Origin": base}
            upload = real_recording()
            async with http.post(f"{base}/enroll/{ticket}", data=upload, headers=headers) as r:
                assert r.status == 202
            status = await until(ws, "status", lambda s: s["enrollment"]["state"] == "ready")
            assert status["style"] == "personal"
            assert status["enrollment"]["verdicts"] == VERDICTS  # every page is told
            # the personal model: its folder on the inference node, the style fitted to it
            (folder,) = bridge.models
            assert (Path(folder) / "style.yaml").is_file()
            assert bridge.styles == [MODEL_SETTINGS]
            async with http.post(f"{base}/enroll/{ticket}", data=b"webm", headers=headers) as r:
                assert r.status == 400  # single use
            await ws.send_str('{"type":"style","use":"default"}')
            await until(ws, "status", lambda s: s["style"] == "default")
            await ws.send_str('{"type":"style","use":"personal"}')
            await until(ws, "status", lambda s: s["style"] == "personal")
            assert bridge.styles == [MODEL_SETTINGS, None, MODEL_SETTINGS]
            assert bridge.models == [folder, None, folder]  # back to the default model too
            # should the node refuse the personal model: the style alone, for the packaged one
            assert bridge.fallbacks == [SETTINGS, None, SETTINGS]
            bridge.stopped = True  # STOP latched (set outside the console): no change
            await ws.send_str('{"type":"style","use":"default"}')
            assert "the robot is stopped" in (await until(ws, "error"))["message"]
            assert bridge.models == [folder, None, folder]

    with serving(tmp_path, LEARNS) as (base, bridge):
        run(scenario(base, bridge))


def test_when_an_operator_picks_a_preset_or_moves_a_slider_expect_the_filter_style_set(tmp_path):
    """A preset sets every style parameter (those it leaves out back to the identity) from the
    settings its file keeps for the packaged model; a slider sets its parameter alone; going
    back restores the graph's own style."""
    from audio2pose_ros.motion.style import STYLE_FIELDS
    from audio2pose_ros.style.figures import load_style

    calm = dataclasses.asdict(load_style("calm_reader").fitted[1])

    async def scenario(base: str, bridge: Bridge) -> None:
        async with aiohttp.ClientSession() as http:
            ws = await connect(http, base, "Ann")
            status = await until(ws, "status")
            assert {"calm_reader", "addressing_camera", "lecturer"} <= set(status["presets"])
            assert set(status["style_ranges"]) == set(STYLE_FIELDS)
            assert status["style_ranges"]["arms_gain"] == [0.0, 2.0]
            await ws.send_str('{"type":"style","use":"calm_reader"}')
            await until(ws, "status", lambda s: s["style"] == "calm_reader")
            await ws.send_str('{"type":"style_set","arms_tempo":0.5}')
            await until(ws, "status", lambda s: s["style"] == "adjusted")
            await ws.send_str('{"type":"style","use":"nobody"}')
            assert "no preset named 'nobody'" in (await until(ws, "error"))["message"]
            await ws.send_str('{"type":"style","use":"default"}')
            await until(ws, "status", lambda s: s["style"] == "default")
            assert bridge.styles == [calm, {"arms_tempo": 0.5}, None]
            assert bridge.models == [None, None]  # a preset is for the packaged model

    assert set(calm) == set(STYLE_FIELDS)
    assert calm["head_gain"] < 0.5
    assert calm["arms_gain"] == 1.0  # the head only: the arms as generated
    with serving(tmp_path, LEARNS) as (base, bridge):
        run(scenario(base, bridge))


def test_when_uploads_come_from_elsewhere_or_without_a_ticket_expect_them_refused(tmp_path):
    async def scenario(base: str, bridge: Bridge) -> None:
        async with aiohttp.ClientSession() as http:
            ws = await connect(http, base, "Ann")
            await ws.send_str('{"type":"enroll","keep":false}')
            ticket = (await until(ws, "enroll_ticket"))["ticket"]
            evil = {"Content-Type": "video/webm", "Origin": "http://evil.example"}
            async with http.post(f"{base}/enroll/{ticket}", data=b"webm", headers=evil) as r:
                assert r.status == 403
            plain = {"Content-Type": "video/webm", "Origin": base}
            async with http.post(f"{base}/enroll/guess", data=b"webm", headers=plain) as r:
                assert r.status == 400
            await ws.send_str('{"type":"style","use":"personal"}')
            error = await until(ws, "error")
            assert "no style has been learned" in error["message"]
            assert bridge.styles == []

    with serving(tmp_path, LEARNS) as (base, bridge):
        run(scenario(base, bridge))


def test_when_another_operator_has_the_floor_expect_no_style_change_from_a_bystander(tmp_path):
    async def scenario(base: str, bridge: Bridge) -> None:
        async with aiohttp.ClientSession() as http:
            talker = await connect(http, base, "Ann")
            await until(talker, "welcome")
            await talker.send_str('{"type":"talk","on":true}')
            await until(talker, "floor", lambda f: f["you"])
            bystander = await connect(http, base, "Bob")
            await bystander.send_str('{"type":"enroll","keep":false}')
            error = await until(bystander, "error")
            assert "Ann has the floor" in error["message"]
            await bystander.send_str('{"type":"style","use":"default"}')
            await until(bystander, "error")
            assert bridge.styles == []

    with serving(tmp_path, LEARNS) as (base, bridge):
        run(scenario(base, bridge))


def test_when_the_stop_is_latched_expect_every_style_change_refused_until_its_release(tmp_path):
    """While Bob's STOP held the robot, Ann's style changes were taken (16 of 16, up to head and
    arms size 2 and arms tempo 3, and "Use my style"): at the release the robot moved in a
    style Bob never saw. Every change waits for the release: refused with the reason naming
    Bob, a style learned meanwhile is not applied (Ann is told), and after the release Ann's
    changes are taken again."""
    changes = [
        '{"type":"style_set","head_gain":2.0,"arms_gain":2.0,"arms_tempo":3.0}',
        '{"type":"style","use":"calm_reader"}',
        '{"type":"style","use":"personal"}',
        '{"type":"style","use":"default"}',
    ]

    async def learn(http: aiohttp.ClientSession, ws: Any, base: str) -> None:
        await ws.send_str('{"type":"enroll","keep":false}')
        ticket = (await until(ws, "enroll_ticket"))["ticket"]
        headers = {"Content-Type": "video/webm", "Origin": base}
        data = real_recording()
        async with http.post(f"{base}/enroll/{ticket}", data=data, headers=headers) as r:
            assert r.status == 202

    async def scenario(base: str, bridge: Bridge) -> list[str]:
        async with aiohttp.ClientSession() as http:
            ann = await connect(http, base, "Ann")
            await learn(http, ann, base)
            await until(ann, "status", lambda s: s["enrollment"]["state"] == "ready")
            bob = await connect(http, base, "Bob")
            await until(bob, "welcome")
            await bob.send_str('{"type":"stop","on":true}')
            await until(ann, "stop_holders", lambda m: m["holders"])
            refusals = []
            for change in changes:
                await ann.send_str(change)
                refusals.append((await until(ann, "error"))["message"])
            await learn(http, ann, base)  # learned again while stopped: not applied
            refusals.append((await until(ann, "error"))["message"])
            held = list(bridge.styles)
            models = list(bridge.models)
            await bob.send_str('{"type":"stop","on":false}')
            await until(ann, "stop_holders", lambda m: not m["holders"])
            await ann.send_str(changes[0])
            await until(ann, "status", lambda s: s["style"] == "adjusted")
            assert held == [MODEL_SETTINGS]  # only the style learned before the stop
            assert len(models) == 1  # and its model: no model changed while stopped
            return refusals

    with serving(tmp_path, LEARNS) as (base, bridge):
        refusals = run(scenario(base, bridge))
    assert len(refusals) == 5
    assert all("the robot is stopped (STOP held by Bob)" in r for r in refusals), refusals
    assert refusals[-1].startswith("your style is learned but not applied")
    assert bridge.styles == [
        MODEL_SETTINGS,
        {"head_gain": 2.0, "arms_gain": 2.0, "arms_tempo": 3.0},
    ]
