"""The console's core without ROS: browser message checks, access rules, the floor, latency
pairing, and the real aiohttp server on a loopback port, driven by a real WebSocket client,
with a recording stand-in for the ROS side (console_node is tested in test_console_browser)."""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import math
import os
import re
import select
import shutil
import socket
import ssl
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from console_hogs import Hogs

from audio2pose_ros.console.access import (
    MIN_TOKEN_CHARS,
    TokenThrottle,
    client_key,
    is_loopback,
    request_problem,
    resolve_access,
)
from audio2pose_ros.console.floor import Floor
from audio2pose_ros.console.latency import VoiceLatency
from audio2pose_ros.console.protocol import (
    AUDIO_HEADER,
    MAX_STAMP_SKEW_S,
    MAX_TEXT_BYTES,
    AudioDroppedError,
    ProtocolError,
    audio_frame,
    encode,
    parse_audio_frame,
    parse_control,
)
from audio2pose_ros.console.server import (
    AUDIO_FRAMES_BURST,
    CONNECTIONS_PER_ADDRESS,
    MAX_AUDIO_FRAMES_PER_S,
    PENDING_PER_ADDRESS,
    SUMMARY_PERIOD_S,
    ConsoleServer,
)
from audio2pose_ros.console.server_thread import ServerThread
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.console.stop import MAX_PRESSES, OUTSIDE, StopHolders, unique_name
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.motion.style import MAX_TEMPO, MIN_TEMPO
from audio2pose_ros.resources import share_path

CHUNK = b"\x01\x00" * 320  # 20 ms of 16 kHz S16LE
TOKEN = "unit-test-token-0123456789"


def now_ms() -> float:
    """The console's clock (ms since the epoch): what the page stamps its chunks with."""
    return time.time() * 1e3


# --- protocol -----------------------------------------------------------------------------------


def test_when_an_audio_frame_is_well_formed_expect_its_fields():
    frame = parse_audio_frame(audio_frame(7, 1.7e12, CHUNK), max_pcm_bytes=3200, now_ms=1.7e12)
    assert (frame.seq, frame.stamp_ms, frame.pcm) == (7, 1.7e12, CHUNK)
    assert frame.duration_s == pytest.approx(0.02)


@pytest.mark.parametrize(
    ("data", "match"),
    [
        (b"A2PA", "shorter than header"),
        (audio_frame(0, 0.0, b""), "shorter than header"),
        (b"XXXX" + audio_frame(0, 0.0, CHUNK)[4:], "magic"),
        (audio_frame(0, float("nan"), CHUNK), "non-finite stamp"),
        (audio_frame(0, float("inf"), CHUNK), "non-finite stamp"),
        (audio_frame(0, 0.0, CHUNK + b"\x00"), "whole 16-bit samples"),
        (audio_frame(0, 0.0, CHUNK * 11), "over the limit"),
    ],
)
def test_when_an_audio_frame_is_malformed_expect_a_protocol_error(data, match):
    with pytest.raises(ProtocolError, match=match):
        parse_audio_frame(data, max_pcm_bytes=3200, now_ms=0.0)


@pytest.mark.parametrize(
    "stamp_ms",
    [-1e308, 1e308, -MAX_STAMP_SKEW_S * 1e3 - 1.0, MAX_STAMP_SKEW_S * 1e3 + 1.0],
)
def test_when_a_chunk_is_stamped_off_the_consoles_clock_expect_it_dropped(stamp_ms):
    """A finite stamp of -1e308 ms passed, and its latency (about 1e308 ms) made the latency
    medians infinite: the status JSON then failed on every tick, for every page."""
    with pytest.raises(AudioDroppedError, match="from the console's clock"):
        parse_audio_frame(audio_frame(0, stamp_ms, CHUNK), max_pcm_bytes=3200, now_ms=0.0)
    for edge_ms in (-MAX_STAMP_SKEW_S * 1e3, MAX_STAMP_SKEW_S * 1e3):
        parse_audio_frame(audio_frame(0, edge_ms, CHUNK), max_pcm_bytes=3200, now_ms=0.0)


def test_when_control_messages_are_valid_expect_their_fields():
    assert parse_control('{"type":"talk","on":true}').fields == {"on": True}
    assert parse_control('{"type":"style_set","arms_gain":0,"head_tempo":0.5}').fields == {
        "arms_gain": 0.0,
        "head_tempo": 0.5,
    }
    assert parse_control('{"type":"style","use":"calm_reader"}').fields == {"use": "calm_reader"}
    hello = parse_control(json.dumps({"type": "hello", "token": "t", "name": "Ann"}))
    assert hello.fields == {"token": "t", "name": "Ann"}
    assert parse_control('{"type":"ping","t":12}').fields == {"t": 12.0}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("not json", "not JSON"),
        ('{"type":"ping","t":NaN}', "not JSON"),
        ('{"type":"ping","t":Infinity}', "not JSON"),
        ("[1, 2]", "JSON object"),
        ("[" * 100000 + "]" * 100000, "over the limit"),
        ('{"type":"launch"}', "unknown message type"),
        ('{"type":1}', "unknown message type"),
        ('{"type":"talk"}', "needs the field 'on'"),
        ('{"type":"talk","on":1}', "must be bool"),
        ('{"type":"talk","on":true,"extra":1}', "unknown fields"),
        ('{"type":"style_set"}', "at least one"),
        ('{"type":"style_set","arms_gain":2.5}', r"arms_gain: value 2.5 is out of range"),
        ('{"type":"style_set","arms_gain":-0.1}', r"in \[0, 2\]"),
        ('{"type":"style_set","head_tempo":0.1}', rf"in \[{MIN_TEMPO:g}, {MAX_TEMPO:g}\]"),
        ('{"type":"style_set","arms_raise_limit_rad":9}', "out of range"),
        ('{"type":"style_set","arms":1}', "unknown fields"),
        ('{"type":"style_set","arms_gain":true}', "must be a number"),
        ('{"type":"style_set","arms_gain":"1"}', "must be a number"),
        ('{"type":"style_set","arms_gain":1e999}', "finite"),
        ('{"type":"style","use":"../../etc/passwd"}', "or a preset"),
        ('{"type":"style","use":""}', "or a preset"),
        ('{"type":"hello","token":5}', "must be str"),
        ('{"type":"hello","token":"t","name":"a\\u0000b"}', "printable"),
        ('{"type":"hello","token":"\\ud800"}', "hello.token must be valid UTF-8"),
        ('{"type":"hello","token":"t","name":"\\udfff"}', "hello.name must be valid UTF-8"),
        (json.dumps({"type": "hello", "token": "t" * 300}), "longer than 256"),
        (json.dumps({"type": "hello", "token": "t", "name": "n" * 41}), "longer than 40"),
        (json.dumps({"type": "ping", "t": 1, "pad": "x" * MAX_TEXT_BYTES}), "over the limit"),
    ],
)
def test_when_a_control_message_is_malformed_expect_a_protocol_error(text, match):
    with pytest.raises(ProtocolError, match=match):
        parse_control(text)


def test_when_a_control_number_is_a_huge_integer_expect_a_protocol_error():
    """float(10**400) raises OverflowError, which escaped parse_control (the server answered
    'could not act on that message' and logged it as a failed message)."""
    for text in (
        '{"type":"ping","t":1' + "0" * 400 + "}",
        '{"type":"style_set","arms_gain":-1' + "0" * 400 + "}",
        '{"type":"talk","on":true,"extra":1' + "0" * 400 + "}",  # in any field, known or not
    ):
        with pytest.raises(ProtocolError, match="out of range"):
            parse_control(text)
    assert parse_control('{"type":"ping","t":9007199254740992}').fields == {"t": 2.0**53}


# --- access -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("127.3.2.1", True),
        ("::1", True),
        ("[::1]", True),
        ("localhost", True),
        ("app.localhost", True),
        ("0.0.0.0", False),
        ("192.168.1.20", False),
        ("pepper.local", False),
        ("localhost.evil.com", False),
    ],
)
def test_when_a_host_is_given_expect_loopback_only_for_this_machine(host, loopback):
    assert is_loopback(host) is loopback


def test_when_bound_to_loopback_expect_no_token_needed_unless_set():
    access = resolve_access(ConsoleSettings())
    assert access.loopback
    assert access.token == ""
    assert access.token_matches("anything")
    assert access.url(8765) == "http://127.0.0.1:8765/"
    guarded = resolve_access(ConsoleSettings(token="abc"))
    assert guarded.token_matches("abc")
    assert not guarded.token_matches("abd")
    assert not guarded.token_matches("")


def test_when_bound_to_a_network_without_certificate_expect_a_configuration_error():
    with pytest.raises(ConfigurationError, match=r"parameter host: .* needs HTTPS"):
        resolve_access(ConsoleSettings(host="0.0.0.0"))


def test_when_only_half_a_certificate_or_a_missing_file_is_given_expect_refused(tmp_path: Path):
    with pytest.raises(ConfigurationError, match="give both"):
        resolve_access(ConsoleSettings(certfile=str(tmp_path / "c.pem")))
    with pytest.raises(ConfigurationError, match="not a readable file"):
        resolve_access(
            ConsoleSettings(certfile=str(tmp_path / "c.pem"), keyfile=str(tmp_path / "k.pem"))
        )


@pytest.fixture(scope="module")
def certificate(tmp_path_factory) -> tuple[Path, Path]:
    """A self-signed certificate for localhost, made with openssl as doc/console.md shows."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    directory = tmp_path_factory.mktemp("tls")
    cert, key = directory / "console.crt", directory / "console.key"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-keyout", str(key), "-out", str(cert), "-subj", "/CN=localhost"),
            *("-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"),
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


def test_when_bound_to_a_network_expect_a_long_token_made_or_required(certificate):
    cert, key = (str(p) for p in certificate)
    made = resolve_access(ConsoleSettings(host="0.0.0.0", certfile=cert, keyfile=key))
    assert len(made.token) >= MIN_TOKEN_CHARS
    assert made.url(9).startswith("https://")
    assert made.url(9).endswith(f":9/#token={made.token}")
    assert not made.token_matches("")
    again = resolve_access(ConsoleSettings(host="0.0.0.0", certfile=cert, keyfile=key))
    assert again.token != made.token  # random, not a fixed default
    with pytest.raises(ConfigurationError, match="too short"):
        resolve_access(ConsoleSettings(host="10.0.0.2", certfile=cert, keyfile=key, token="1234"))


@pytest.mark.parametrize(
    ("host", "origin", "problem"),
    [
        ("127.0.0.1:8765", "http://127.0.0.1:8765", ""),
        ("localhost:8765", "http://localhost:8765", ""),
        (None, "http://127.0.0.1:8765", "no Host"),
        ("127.0.0.1:8765", None, "no Origin"),
        ("127.0.0.1:8765", "http://evil.example", "not this console"),
        ("127.0.0.1:8765", "https://127.0.0.1:8765", "not this console"),
        ("evil.example:8765", "http://evil.example:8765", "not a loopback name"),  # rebinding
    ],
)
def test_when_a_websocket_request_comes_expect_host_and_origin_checked(host, origin, problem):
    found = request_problem(resolve_access(ConsoleSettings()), host, origin)
    assert (problem in found) if problem else found == ""


# --- floor and latency --------------------------------------------------------------------------


def test_when_one_operator_holds_the_floor_expect_others_wait_until_released():
    floor = Floor()
    assert floor.take(1, "Ann")
    assert not floor.take(2, "Bob")
    assert floor.holder_name == "Ann"
    assert floor.free_for(1)
    assert not floor.free_for(2)
    assert not floor.release(2)
    assert floor.release(1)
    assert floor.free_for(2)
    assert floor.take(2, "Bob")


def test_when_chunks_poses_and_commands_arrive_expect_each_chunk_paired_with_its_command():
    latency = VoiceLatency()
    latency.chunk_published(stamp_s=9.990, received_s=9.995, published_s=10.000)  # no frame
    latency.chunk_published(stamp_s=10.010, received_s=10.015, published_s=10.020)
    latency.command_arrived(stamp_s=10.021, arrival_s=10.022)  # no raw pose yet: not paired
    latency.raw_arrived(10.023)  # answers the newest chunk published before it
    latency.command_arrived(stamp_s=10.015, arrival_s=10.024)  # ticked before the pose: not it
    assert latency.summary() == {"n": 0}
    latency.command_arrived(stamp_s=10.025, arrival_s=10.026)
    summary = latency.summary()
    assert summary["n"] == 1
    assert summary["p50"] == pytest.approx(16.0)  # 10.026 - 10.010
    assert summary["uplink_p50"] == pytest.approx(5.0)
    assert summary["graph_p50"] == pytest.approx(6.0)


def test_when_a_pose_is_never_commanded_expect_it_dropped_not_paired_late():
    latency = VoiceLatency()
    latency.chunk_published(1.0, 1.0, 1.0)
    latency.raw_arrived(1.01)
    latency.command_arrived(stamp_s=2.5, arrival_s=2.5)  # 1.5 s later (stopped): not a latency
    assert latency.summary() == {"n": 0}


def test_when_chunk_stamps_are_absurd_expect_no_latency_kept_and_the_summary_json():
    """Latencies of about 1e308 ms made np.median of two of them inf: encode('status') raised
    on every tick from then on (the window kept them, whatever the talker)."""
    latency = VoiceLatency()
    now = time.time()
    for stamp_s in (-1e305, -1e305, float("nan"), float("inf"), now - 7200.0, now):
        latency.chunk_published(stamp_s, now, now)
        latency.raw_arrived(now + 0.001)
        latency.command_arrived(now + 0.001, now + 0.002)
        now += 0.02
    summary = latency.summary()
    assert summary["n"] == 1  # only the chunk stamped on the console's clock
    assert all(math.isfinite(value) for value in summary.values())
    encode("status", latency=summary)


# --- the server ---------------------------------------------------------------------------------


class Bridge:
    """The ROS side, recorded."""

    def __init__(self) -> None:
        self.joint_names = ["HeadYaw"]
        self.neutral = {"HeadYaw": 0.0}
        self.calls: list[tuple[str, Any]] = []

    def publish_audio(self, frame, received_s) -> None:
        self.calls.append(("audio", len(frame.pcm)))

    def start_talk(self) -> None:
        self.calls.append(("start", None))

    def end_talk(self) -> None:
        self.calls.append(("end", None))

    def set_stop(self, on: bool) -> None:
        self.calls.append(("stop", on))

    def set_enable(self, on: bool) -> None:
        self.calls.append(("enable", on))

    def set_voice_muted(self, on: bool) -> None:
        self.calls.append(("mute", on))

    def set_style(self, settings) -> None:
        self.calls.append(("style", settings))

    def set_model(self, folder, fallback=None) -> None:
        self.calls.append(("model", folder))

    def pose(self) -> dict[str, Any]:
        return {"commanded": {"HeadYaw": 0.1}, "measured": None}

    def status(self) -> dict[str, Any]:
        return {"stop": False, "latency": {"n": 0}}

    def count(self, kind: str) -> int:
        return sum(1 for name, _ in self.calls if name == kind)


@contextmanager
def serving(
    tmp_path: Path,
    web: bool = True,
    bridge: Bridge | None = None,
    logged: list[tuple[str, str]] | None = None,
    servers: list[ConsoleServer] | None = None,
    tokens: TokenThrottle | None = None,
    summary_period_s: float = SUMMARY_PERIOD_S,
    **settings: Any,
) -> Iterator[tuple[str, Bridge]]:
    """The console on a free loopback port with ``bridge`` (a new one by default), its log
    lines appended to ``logged`` and the server to ``servers``; yields its address and the
    bridge. ``tokens`` and ``summary_period_s`` go to the server."""
    settings.setdefault("port", 0)
    config = ConsoleSettings(**settings)
    bridge = bridge or Bridge()
    lines: list[tuple[str, str]] = [] if logged is None else logged
    web_dir = tmp_path / "web"
    web_dir.mkdir(exist_ok=True)
    if web:
        (web_dir / "index.html").write_text("<html>console</html>")
        (web_dir / "console.js").write_text("1;")
    server = ConsoleServer(
        config,
        resolve_access(config),
        bridge,
        web_dir,
        share_path("urdf", "pepper.urdf"),
        lambda level, message: lines.append((level, message)),
        tokens=tokens,
        summary_period_s=summary_period_s,
    )
    if servers is not None:
        servers.append(server)
    thread = ServerThread(server)
    port = thread.start()
    scheme = "https" if config.certfile else "http"
    try:
        yield f"{scheme}://127.0.0.1:{port}", bridge
    finally:
        thread.stop()


def run(coroutine) -> Any:
    return asyncio.run(asyncio.wait_for(coroutine, 30.0))


async def connect(
    session: aiohttp.ClientSession, base: str, token: str = TOKEN, name: str = "", **kwargs: Any
) -> aiohttp.ClientWebSocketResponse:
    """A WebSocket as the page opens one, after its hello; the welcome is read."""
    ws = await session.ws_connect(f"{base.replace('http', 'ws', 1)}/ws", origin=base, **kwargs)
    await ws.send_str(json.dumps({"type": "hello", "token": token, "name": name}))
    return ws


async def until(ws: aiohttp.ClientWebSocketResponse, kind: str, **fields: Any) -> dict[str, Any]:
    """The next message of ``kind`` whose ``fields`` match (others are skipped)."""
    while True:
        message = await ws.receive(timeout=5.0)
        assert message.type == aiohttp.WSMsgType.TEXT, message
        data = json.loads(message.data)
        if data["type"] == kind and all(data.get(k) == v for k, v in fields.items()):
            return data


async def closed(ws: aiohttp.ClientWebSocketResponse) -> int | None:
    """Read until the connection closes; its close code."""
    while (await ws.receive(timeout=5.0)).type not in (
        aiohttp.WSMsgType.CLOSE,
        aiohttp.WSMsgType.CLOSED,
    ):
        pass
    return ws.close_code


@contextmanager
def escaped_exceptions() -> Iterator[list[logging.LogRecord]]:
    """What aiohttp and asyncio log as errors: an exception that escaped a handler or a task."""
    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append(record)

    handler = Keep(level=logging.ERROR)
    loggers = [logging.getLogger(name) for name in ("aiohttp.server", "asyncio")]
    for logger in loggers:
        logger.addHandler(handler)
    try:
        yield records
    finally:
        for logger in loggers:
            logger.removeHandler(handler)


def described(records: list[logging.LogRecord]) -> list[str]:
    return [f"{r.getMessage()} {r.exc_info and r.exc_info[1]!r}" for r in records]


def raw_websocket(port: int) -> socket.socket:
    """A WebSocket opened by hand, with the page's Host and Origin; the 101 is read."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nOrigin: http://127.0.0.1:{port}\r\n"
            f"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            "Sec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += sock.recv(4096)
    assert b" 101 " in answer.split(b"\r\n")[0], answer
    return sock


def client_frame(text: bytes) -> bytes:
    """One masked, final text frame from a client (shorter than 126 bytes)."""
    mask = os.urandom(4)
    masked = bytes(b ^ mask[i % 4] for i, b in enumerate(text))
    return bytes([0x81, 0x80 | len(text)]) + mask + masked


def port_of(base: str) -> int:
    return int(base.rsplit(":", 1)[1])


def test_when_the_page_is_asked_for_expect_it_served_with_security_headers(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            async with session.get(f"{base}/") as response:
                assert response.status == 200
                assert "default-src 'self'" in response.headers["Content-Security-Policy"]
                assert response.headers["X-Frame-Options"] == "DENY"
            async with session.get(f"{base}/urdf/pepper.urdf") as response:
                assert "<robot" in await response.text()
            for missing in ("/../setup.py", "/nothing.js", "/%2e%2e%2fsetup.py"):
                async with session.get(base + missing) as response:
                    assert response.status == 404

    with serving(tmp_path) as (base, _):
        run(scenario(base))


def test_when_the_front_end_is_not_built_expect_a_page_that_says_how_to_build_it(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session, session.get(f"{base}/") as response:
            assert "npm ci" in await response.text()

    with serving(tmp_path, web=False) as (base, _):
        run(scenario(base))


def test_when_the_token_is_wrong_or_missing_expect_the_connection_closed(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base, token="wrong-token")
            message = await until(ws, "error")
            assert "wrong token" in message["message"]
            assert (await ws.receive(timeout=5.0)).type == aiohttp.WSMsgType.CLOSE
            assert ws.close_code == 4401
            silent = await session.ws_connect(f"{base.replace('http', 'ws')}/ws", origin=base)
            assert (await silent.receive(timeout=5.0)).type == aiohttp.WSMsgType.CLOSE
            assert silent.close_code == 4400  # no hello within auth_timeout_s
            ws = await connect(session, base)
            assert (await until(ws, "welcome"))["joints"] == ["HeadYaw"]

    with serving(tmp_path, token=TOKEN, auth_timeout_s=0.5) as (base, bridge):
        run(scenario(base))
        assert bridge.calls == []


def test_when_another_site_opens_the_websocket_expect_refused_before_the_upgrade(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            for headers in ({"Origin": "http://evil.example"}, {"Host": "evil.example"}):
                with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                    await session.ws_connect(f"{base.replace('http', 'ws')}/ws", headers=headers)
                assert refused.value.status == 403

    with serving(tmp_path) as (base, bridge):
        run(scenario(base))
        assert bridge.calls == []


def test_when_two_operators_talk_expect_one_floor_and_its_release_on_disconnect(tmp_path: Path):
    async def scenario(base: str, bridge: Bridge) -> None:
        async with aiohttp.ClientSession() as session:
            ann = await connect(session, base, name="Ann")
            bob = await connect(session, base, name="Bob")
            await until(bob, "welcome")
            await ann.send_str('{"type":"talk","on":true}')
            assert (await until(bob, "floor", holder="Ann"))["you"] is False
            await ann.send_bytes(audio_frame(0, now_ms(), CHUNK))
            await bob.send_bytes(audio_frame(0, now_ms(), CHUNK))  # without the floor: dropped
            assert "press Talk" in (await until(bob, "error"))["message"]
            await bob.send_str('{"type":"talk","on":true}')
            assert "Ann has the floor" in (await until(bob, "error"))["message"]
            await bob.send_str('{"type":"stop","on":true}')  # a stop from anyone
            holders = [{"name": "Bob", "present": True}]
            await until(ann, "stop_holders", holders=holders, you=False)
            await ann.send_str('{"type":"stop","on":false}')  # the talker cannot release it
            assert "held by Bob" in (await until(ann, "error"))["message"]
            await bob.send_str('{"type":"style_set","arms_gain":0.2}')
            assert "only a stop" in (await until(bob, "error"))["message"]
            await ann.close()  # the talker leaves: the floor is free
            await until(bob, "floor", holder=None)
            await bob.send_str('{"type":"talk","on":true}')
            await until(bob, "floor", holder="Bob", you=True)
            await bob.send_str('{"type":"style_set","arms_gain":0.2}')  # waits for the release
            assert "held by Bob" in (await until(bob, "error"))["message"]
            await bob.send_str('{"type":"enable","on":false}')
            await bob.send_str('{"type":"stop","on":false}')  # his own stop: his to release
            await until(bob, "stop_holders", holders=[], you=False)
            await bob.send_str('{"type":"style_set","arms_gain":0.2}')
            await bob.send_str('{"type":"ping","t":1}')
            await until(bob, "pong")  # the style was acted on before

    with serving(tmp_path) as (base, bridge):
        run(scenario(base, bridge))
    assert bridge.count("audio") == 1
    assert [call for call in bridge.calls if call[0] != "audio"] == [
        ("start", None),
        ("stop", True),
        ("end", None),
        ("start", None),
        ("enable", False),
        ("stop", False),
        ("style", {"arms_gain": 0.2}),
        ("end", None),
    ]


def test_when_operators_mute_the_voice_expect_the_talkers_choice_kept_and_stop_apart(
    tmp_path: Path,
):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            stranger = await session.ws_connect(f"{base.replace('http', 'ws')}/ws", origin=base)
            await stranger.send_str('{"type":"mute","on":true}')  # instead of the hello
            assert await closed(stranger) == 4400  # never identified: the bridge is not told
            ann = await connect(session, base, name="Ann")
            bob = await connect(session, base, name="Bob")
            await until(bob, "welcome")
            await ann.send_str('{"type":"talk","on":true}')
            await until(bob, "floor", holder="Ann")
            await bob.send_str('{"type":"mute","on":true}')  # a bystander mutes Ann's voice
            assert "only a stop" in (await until(bob, "error"))["message"]
            await ann.send_str('{"type":"mute","on":true}')
            await ann.send_str('{"type":"stop","on":true}')  # the stop does not touch the voice
            await ann.send_str('{"type":"stop","on":false}')
            await ann.send_str('{"type":"mute","on":false}')  # the mute not held by the stop
            await ann.send_str('{"type":"ping","t":1}')
            await until(ann, "pong")

    with serving(tmp_path, token=TOKEN) as (base, bridge):
        run(scenario(base))
    assert [call for call in bridge.calls if call[0] != "audio"] == [
        ("start", None),
        ("mute", True),
        ("stop", True),
        ("stop", False),
        ("mute", False),
        ("end", None),
    ]


def test_when_a_talker_floods_audio_expect_only_the_rate_bound_published(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base)
            await ws.send_str('{"type":"talk","on":true}')
            await until(ws, "floor", you=True)
            for seq in range(150):  # 3 s of audio at once
                await ws.send_bytes(audio_frame(seq, now_ms(), CHUNK))
            assert "s per second" in (await until(ws, "error"))["message"]
            await ws.send_str('{"type":"ping","t":1}')
            assert (await until(ws, "pong"))["t"] == 1

    with serving(tmp_path, max_browser_audio_s_per_s=1.0) as (base, bridge):
        run(scenario(base))
    # the bucket holds max(1.0 s/s, max_browser_chunk_s) = 1 s: about 50 chunks of 20 ms pass
    assert 45 <= bridge.count("audio") <= 60


def test_when_a_connection_sends_garbage_expect_it_closed_and_the_server_serving(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base)
            await until(ws, "welcome")
            for _ in range(200):
                await ws.send_str("{not json")
            while (await ws.receive(timeout=5.0)).type != aiohttp.WSMsgType.CLOSE:
                pass
            assert ws.close_code == 1008
            big = await connect(session, base)
            await until(big, "welcome")
            await big.send_bytes(struct.pack("<4sId", b"A2PA", 0, 0.0) + b"\0" * 100_000)
            while (await big.receive(timeout=5.0)).type != aiohttp.WSMsgType.CLOSE:
                pass
            assert big.close_code == 1009  # too big: refused before it is read in full
            after = await connect(session, base)
            await until(after, "welcome")

    with serving(tmp_path) as (base, bridge):
        run(scenario(base))
        assert bridge.count("audio") == 0


def test_when_more_operators_connect_than_allowed_expect_the_extra_refused(tmp_path: Path):
    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            first = await connect(session, base)
            await until(first, "welcome")
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await connect(session, base)
            assert refused.value.status == 503
            await first.close()
            await asyncio.sleep(0.2)  # the server's side of the closed connection ends
            url = f"{base.replace('http', 'ws')}/ws"
            silent = [
                await session.ws_connect(url, origin=base) for _ in range(PENDING_PER_ADDRESS)
            ]
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:  # one waiting more
                await session.ws_connect(url, origin=base)
            assert refused.value.status == 503
            # WebSockets without their token take no operator's place: they held all
            # max_clients places, and every page got 503, for as long as they kept reopening
            async with from_address("127.0.0.3") as other:
                operator = await connect(other, base)
                await until(operator, "welcome")
            for ws in silent:
                await ws.close()

    with serving(tmp_path, max_clients=1, auth_timeout_s=30.0) as (base, _):
        run(scenario(base))


def test_when_the_hello_token_holds_a_lone_surrogate_expect_a_refusal_not_an_escaped_exception(
    tmp_path: Path,
):
    """JSON's "\\ud800" is a str that UTF-8 cannot encode: the token comparison raised out of
    the handler (aiohttp logged a traceback, the page saw 1006, nothing was counted)."""

    async def scenario(base: str) -> int | None:
        async with aiohttp.ClientSession() as session:
            ws = await session.ws_connect(f"{base.replace('http', 'ws')}/ws", origin=base)
            await ws.send_str('{"type":"hello","token":"\\ud800"}')
            return await closed(ws)

    servers: list[ConsoleServer] = []
    with (
        escaped_exceptions() as escaped,
        serving(tmp_path, token=TOKEN, servers=servers) as (
            base,
            bridge,
        ),
    ):
        code = run(scenario(base))
    assert code == 4400  # a malformed hello
    assert not escaped, described(escaped)
    assert servers[0].refused_frames == 1
    assert bridge.calls == []


class BrokenModelBridge(Bridge):
    """A bridge whose robot model cannot be sent: the welcome fails."""

    def __init__(self) -> None:
        super().__init__()
        self.neutral = None  # type: ignore[assignment]


def test_when_a_connections_handler_fails_unexpectedly_expect_one_warning_and_close_1011(
    tmp_path: Path,
):
    """An exception outside the per-message boundary (here in the welcome) escaped to aiohttp,
    which logged a traceback and dropped the connection without a close code."""

    async def scenario(base: str) -> int | None:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base, name="Ann")
            return await closed(ws)

    logged: list[tuple[str, str]] = []
    bridge = BrokenModelBridge()
    with (
        escaped_exceptions() as escaped,
        serving(tmp_path, bridge=bridge, logged=logged) as (
            base,
            _,
        ),
    ):
        code = run(scenario(base))
    assert code == 1011
    assert not escaped, described(escaped)
    warnings = [message for level, message in logged if level == "warning"]
    assert len(warnings) == 1, warnings
    assert "'Ann'" in warnings[0]
    assert "TypeError" in warnings[0]


def test_when_a_page_drops_its_connection_mid_exchange_expect_no_escaped_exception(
    tmp_path: Path,
):
    """A hello and pings, then a TCP reset: the pong's send failed, the per-message boundary
    logged it as a failed message and answered with an error, whose send failed again, out of
    the handler (aiohttp: 'Error handling request ... ClientConnectionResetError')."""
    pages = 10
    logged: list[tuple[str, str]] = []
    with escaped_exceptions() as escaped, serving(tmp_path, logged=logged) as (base, _):
        for _ in range(pages):
            sock = raw_websocket(port_of(base))
            sock.sendall(
                client_frame(b'{"type":"hello","token":""}')
                + client_frame(b'{"type":"ping","t":1}') * 5
            )
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.close()  # a reset, no close frame: the page's tab is gone
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            if sum(" left" in message for _, message in logged) == pages:
                break
            time.sleep(0.05)
    assert sum(" left" in message for _, message in logged) == pages, logged
    assert not escaped, described(escaped[:3])
    assert not [message for level, message in logged if level == "warning"], logged[:3]


def test_when_a_page_stamps_its_chunks_off_the_consoles_clock_expect_them_dropped_not_fatal(
    tmp_path: Path,
):
    """Stamps of -1e308 ms were published and measured (then the status failed for every page);
    they are dropped and counted, and the connection stays: a page whose clock offset is
    catching up after a clock step sends such stamps for a moment."""

    async def scenario(base: str) -> list[str]:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base)
            await ws.send_str('{"type":"talk","on":true}')
            await until(ws, "floor", you=True)
            for seq in range(60):  # more than VIOLATION_BURST refused frames
                await ws.send_bytes(audio_frame(seq, -1e308 if seq % 2 else 1.0, CHUNK))
            await ws.send_bytes(audio_frame(60, now_ms(), CHUNK))
            await ws.send_str('{"type":"ping","t":1}')
            errors = []
            while (message := json.loads((await ws.receive(timeout=5.0)).data))["type"] != "pong":
                if message["type"] == "error":
                    errors.append(message["message"])
            return errors

    servers: list[ConsoleServer] = []
    with serving(tmp_path, servers=servers) as (base, bridge):
        errors = run(scenario(base))
    assert bridge.count("audio") == 1  # only the chunk stamped on the console's clock
    assert servers[0].refused_frames == 60
    assert errors
    assert all("from the console's clock" in error for error in errors), errors


class NonFiniteStatusBridge(Bridge):
    """A bridge whose statistics went wrong: an infinite latency, a NaN style value."""

    def status(self) -> dict[str, Any]:
        return {
            "stop": False,
            "latency": {"n": 2, "p50": math.inf},
            "style_values": {"head_gain": math.nan},
        }


def test_when_a_status_value_is_not_finite_expect_it_sent_as_null_and_the_rest_kept(
    tmp_path: Path,
):
    """One infinite statistic made encode('status') raise: no page got the stop, enable, style,
    health or floor again, and the failure was logged every 0.5 s."""

    async def scenario(base: str) -> dict[str, Any]:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base)
            first = await asyncio.wait_for(until(ws, "status"), 3.0)
            await asyncio.wait_for(until(ws, "status"), 3.0)  # a second tick, not logged again
            return first

    logged: list[tuple[str, str]] = []
    with serving(tmp_path, bridge=NonFiniteStatusBridge(), logged=logged) as (base, _):
        status = run(scenario(base))
    assert status["stop"] is False
    assert status["latency"] == {"n": 2, "p50": None}
    assert status["style_values"] == {"head_gain": None}
    assert status["operators"] == 1
    warnings = [message for level, message in logged if level == "warning"]
    assert len(warnings) == 1, warnings
    assert "status.latency.p50" in warnings[0]
    assert "status.style_values.head_gain" in warnings[0]


def test_when_a_talker_sends_one_sample_chunks_expect_the_message_rate_bounded(tmp_path: Path):
    """The budget counted seconds of audio, not messages: 1-sample chunks (2 bytes) passed at up
    to 24,000 a second, each one ROS message to audio_features_node. The page sends 50 a
    second; frames beyond MAX_AUDIO_FRAMES_PER_S are dropped and counted, the talker stays."""

    async def scenario(base: str) -> tuple[float, list[str]]:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base)
            await ws.send_str('{"type":"talk","on":true}')
            await until(ws, "floor", you=True)
            start = time.monotonic()
            stamp = now_ms()
            for seq in range(3000):  # 0.19 s of audio in 3000 messages
                await ws.send_bytes(audio_frame(seq, stamp, b"\x10\x00"))
            await ws.send_str('{"type":"ping","t":1}')
            errors = []
            while (message := json.loads((await ws.receive(timeout=5.0)).data))["type"] != "pong":
                if message["type"] == "error":
                    errors.append(message["message"])
            return time.monotonic() - start, errors

    servers: list[ConsoleServer] = []
    with serving(tmp_path, servers=servers) as (base, bridge):
        elapsed, errors = run(scenario(base))
    published = bridge.count("audio")
    assert published <= AUDIO_FRAMES_BURST + MAX_AUDIO_FRAMES_PER_S * elapsed + 1, (
        published,
        elapsed,
    )
    assert servers[0].refused_frames == 3000 - published
    assert errors
    assert all("audio frames per second" in error for error in errors), errors


def closed_by_the_server(sock: socket.socket, within_s: float) -> bool:
    """Whether the server closes ``sock`` (an end of stream or a reset) within ``within_s``."""
    sock.settimeout(within_s)
    try:
        return sock.recv(1024) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def test_when_a_client_never_finishes_its_request_expect_the_connection_closed(tmp_path: Path):
    """Before the upgrade only aiohttp's keep-alive timeout (3630 s by default) bounded a
    connection: a half-sent request, or one trickled a byte at a time (slowloris), held its
    socket for an hour, without a token. Now auth_timeout_s bounds the whole request."""
    request = b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n" + b"X-Slow: 1\r\n" * 100
    with serving(tmp_path, auth_timeout_s=0.5) as (base, _):
        port = port_of(base)
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as half:
            start = time.monotonic()
            half.sendall(b"GET /ws HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            half_closed = closed_by_the_server(half, 5.0)
            half_s = time.monotonic() - start
        with socket.create_connection(("127.0.0.1", port), timeout=5.0) as trickle:
            start = time.monotonic()
            trickle_closed = False
            for byte in request:  # a byte every 50 ms: 60 s of request
                try:
                    trickle.sendall(bytes([byte]))
                except OSError:  # a reset or a broken pipe: the server closed it
                    trickle_closed = True
                    break
                if select.select([trickle], [], [], 0.05)[0]:
                    trickle_closed = closed_by_the_server(trickle, 1.0)
                    break
                if time.monotonic() - start > 5.0:
                    break
            trickle_s = time.monotonic() - start
    assert half_closed, "a half-sent request was held open"
    assert half_s < 3.0, half_s
    assert trickle_closed, "a request sent a byte at a time was held open"
    assert trickle_s < 3.0, trickle_s


def test_when_a_client_never_finishes_its_tls_handshake_expect_the_connection_closed(
    tmp_path: Path, certificate
):
    """asyncio waits 60 s for a TLS handshake by default, and aiohttp's clock starts after it:
    a connection that never says hello held its socket that long."""
    cert, key = (str(p) for p in certificate)
    settings = {"certfile": cert, "keyfile": key, "token": TOKEN, "auth_timeout_s": 0.5}
    with serving(tmp_path, **settings) as (base, _):
        sock = socket.create_connection(("127.0.0.1", port_of(base)), timeout=5.0)
        start = time.monotonic()
        try:
            closed = closed_by_the_server(sock, 5.0)
        finally:
            sock.close()
        elapsed = time.monotonic() - start
    assert closed, "a connection without a TLS handshake was held open"
    assert elapsed < 3.0, elapsed


def from_address(source: str) -> aiohttp.ClientSession:
    """A client whose connections come from ``source`` (every 127.x.y.z is this machine)."""
    return aiohttp.ClientSession(connector=aiohttp.TCPConnector(local_addr=(source, 0)))


def idle_socket(port: int, source: str) -> socket.socket:
    """A TCP connection from ``source`` that sends nothing."""
    sock = socket.socket()
    sock.settimeout(5.0)
    sock.bind((source, 0))
    sock.connect(("127.0.0.1", port))
    return sock


def answer(sock: socket.socket, within_s: float = 3.0) -> bytes:
    """What the server says on ``sock`` until it closes it (or what became of it)."""
    sock.settimeout(within_s)
    said = b""
    try:
        while chunk := sock.recv(1024):
            said += chunk
    except ConnectionResetError:  # closed with our request unread: refused all the same
        return said or b"(reset)"
    except TimeoutError:
        return said + b"(open after %.0f s)" % within_s
    return said or b"(closed)"


def answers(socks: list[socket.socket], within_s: float = 5.0) -> list[bytes]:
    """What the server says on each of ``socks``, those it has not closed within ``within_s``
    (all together) marked as still open."""
    deadline = time.monotonic() + within_s
    waiting = list(socks)
    while waiting and time.monotonic() < deadline:
        ready = select.select(waiting, [], [], max(0.0, deadline - time.monotonic()))[0]
        waiting = [sock for sock in waiting if sock not in ready]
    return [answer(sock, 0.5) if sock not in waiting else b"(open)" for sock in socks]


REFUSED = (b"HTTP/1.1 503", b"(reset)", b"(closed)")


async def operator_stops(base: str, source: str, **kwargs: Any) -> None:
    """A page from ``source``: its file, its WebSocket, its hello and a STOP."""
    async with from_address(source) as session:
        async with session.get(f"{base}/", **kwargs) as response:
            assert response.status == 200
        ws = await connect(session, base, name="Observer", **kwargs)
        await until(ws, "welcome")
        await ws.send_str('{"type":"stop","on":true}')
        await until(ws, "stop_holders", you=True)


def test_when_one_address_holds_idle_connections_expect_another_operator_connects_and_stops(
    tmp_path: Path,
):
    """Idle TCP connections (no request, no TLS handshake, no token) from one client held all
    64 connection slots: every new page, with its STOP button, was answered 503 (0 of 10
    connects). One address holds at most CONNECTIONS_PER_ADDRESS: each connection beyond
    closes its address's oldest idle one, and another address's operator gets in."""
    with serving(tmp_path, token=TOKEN, auth_timeout_s=30.0) as (base, bridge):
        port = port_of(base)
        held = [idle_socket(port, "127.0.0.2") for _ in range(100)]
        try:
            oldest = answers(held[:-CONNECTIONS_PER_ADDRESS])
            run(operator_stops(base, "127.0.0.3"))
            answered = select.select(held[-CONNECTIONS_PER_ADDRESS:], [], [], 0.1)[0]
        finally:
            for sock in held:
                sock.close()
    assert all(a.startswith(REFUSED) for a in oldest), oldest
    assert answered == [], "one of the newest connections of the address was closed"
    assert bridge.calls == [("stop", True)]


def test_when_one_address_holds_tls_connections_expect_the_oldest_closed_before_its_handshake(
    tmp_path: Path, certificate
):
    """Over TLS a connection was counted but not attributed before its handshake: idle ones
    held every slot. One beyond the address's share closes the oldest, which never had a
    handshake, and gets in."""
    cert, key = (str(p) for p in certificate)
    trust = ssl.create_default_context(cafile=cert)
    settings = {"certfile": cert, "keyfile": key, "token": TOKEN, "auth_timeout_s": 30.0}
    with serving(tmp_path, **settings) as (base, bridge):
        port = port_of(base)
        held = [idle_socket(port, "127.0.0.2") for _ in range(CONNECTIONS_PER_ADDRESS)]
        extra = idle_socket(port, "127.0.0.2")
        try:
            with trust.wrap_socket(extra, server_hostname="localhost") as secure:
                secure.sendall(b"GET / HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
                page = answer(secure)  # type: ignore[arg-type]
            ends = [answer(held[0], 5.0), *answers(held[1:], 0.1)]
            with pytest.raises((ssl.SSLError, ConnectionError)):  # closed before its handshake
                trust.wrap_socket(held[0], server_hostname="localhost")
            run(operator_stops(base, "127.0.0.3", ssl=trust))
        finally:
            for sock in held:
                sock.close()
    assert page.startswith(b"HTTP/1.1 200"), page
    assert ends[0].startswith(REFUSED), ends
    assert set(ends[1:]) == {b"(open)"}, ends
    assert bridge.calls == [("stop", True)]


async def newcomer(base: str, source: str) -> bool:
    """Whether a new page from ``source`` loads and its operator is welcomed."""
    try:
        async with from_address(source) as session:
            async with session.get(f"{base}/") as response:
                if response.status != 200:
                    return False
            ws = await connect(session, base, name="Newcomer")
            await until(ws, "welcome")
            await ws.close()
            return True
    except (aiohttp.ClientError, ConnectionError, asyncio.TimeoutError, AssertionError):
        return False


@pytest.mark.parametrize(
    "hog_sources",
    [[f"127.0.2.{i}" for i in range(1, 129)], ["127.0.0.3"]],
    ids=["one each from other addresses", "the newcomers' address"],
)
def test_when_idle_connections_reconnect_at_once_expect_every_newcomer_in_and_the_stop_pressed(
    tmp_path: Path, hog_sources: list[str]
):
    """64 idle TCP connections, each reopened the moment the console closed it, locked every
    new operator out (0 of 10 connected, 503). A connection that has not made a request yet
    is closed for a newcomer when the door is full (the oldest first, of the address holding
    the most), so 10 of 10 operators get in, and one connected before the flood still stops
    the robot."""
    servers: list[ConsoleServer] = []

    async def scenario() -> tuple[list[bool], int]:
        async with from_address("127.0.0.4") as session:
            ann = await connect(session, base, name="Ann")
            await until(ann, "welcome")
            tcp = servers[0]._tcp
            full = tcp.limit if len(hog_sources) > 1 else tcp.per_address
            hogs = Hogs(port, hog_sources, full)
            try:
                while tcp.total < full:  # every slot taken before the newcomers come
                    await asyncio.sleep(0.01)
                entered = [await newcomer(base, "127.0.0.3") for _ in range(10)]
                await ann.send_str('{"type":"stop","on":true}')
                await until(ann, "stop_holders", you=True)
            finally:
                hogs.stop()
            return entered, hogs.reopened

    with serving(tmp_path, servers=servers, token=TOKEN, auth_timeout_s=30.0) as (base, bridge):
        port = port_of(base)
        entered, reopened = run(scenario())
    print(f"newcomers in: {sum(entered)} of {len(entered)}; hogs reopened {reopened} times")
    assert entered == [True] * 10
    assert reopened >= 10  # the hogs came back each time one was closed for a newcomer
    assert bridge.calls == [("stop", True)]


def test_when_many_addresses_fill_every_slot_expect_a_newcomer_in_and_operators_kept(
    tmp_path: Path,
):
    """Several addresses, each within its share, filled every connection slot together: new
    pages got 503. A newcomer takes the place of the oldest connection of the address that
    holds the most, never an identified operator's WebSocket."""
    servers: list[ConsoleServer] = []

    async def scenario() -> None:
        async with from_address("127.0.0.4") as session:
            operator = await connect(session, base, name="Ann")
            await until(operator, "welcome")
            flood = [
                idle_socket(port, f"127.0.2.{i % 4 + 1}") for i in range(servers[0]._tcp.limit + 8)
            ]
            try:
                await operator_stops(base, "127.0.0.3")
                await operator.send_str('{"type":"ping","t":1}')
                await until(operator, "pong")  # Ann's WebSocket was kept
            finally:
                for sock in flood:
                    sock.close()

    with serving(tmp_path, servers=servers, max_clients=2, auth_timeout_s=30.0) as (base, bridge):
        port = port_of(base)
        run(scenario())
    assert servers[0]._tcp.evicted >= 1  # the newcomer took a flood connection's place
    assert bridge.calls == [("stop", True)]


def test_when_tls_connections_fail_in_every_way_expect_each_counted_until_it_ends(
    tmp_path: Path, certificate
):
    """A connection counts from its acceptance; one that sends garbage instead of a TLS hello,
    resets mid-handshake, closes before a byte or never starts its handshake must stop
    counting, or its address would lose its share for good."""
    cert, key = (str(p) for p in certificate)
    trust = ssl.create_default_context(cafile=cert)
    settings = {"certfile": cert, "keyfile": key, "token": TOKEN, "auth_timeout_s": 1.0}
    servers: list[ConsoleServer] = []
    with serving(tmp_path, servers=servers, **settings) as (base, bridge):
        port = port_of(base)
        silent = [idle_socket(port, "127.0.0.2") for _ in range(4)]  # timed out by the server
        for i in range(3 * CONNECTIONS_PER_ADDRESS):
            sock = idle_socket(port, "127.0.0.2")
            if i % 3 == 0:
                sock.sendall(b"GET / HTTP/1.1\r\n\r\n")  # plain HTTP on a TLS port
                answer(sock, 5.0)
            elif i % 3 == 1:
                sock.sendall(b"\x16\x03\x01\x00")  # the start of a hello, then a reset
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.close()
        tcp = servers[0]._tcp
        deadline = time.monotonic() + 10.0
        while tcp.total and time.monotonic() < deadline:
            time.sleep(0.05)
        counted = dict(tcp.by_address)
        for sock in silent:
            sock.close()
        run(operator_stops(base, "127.0.0.2", ssl=trust))
    assert counted == {}
    assert bridge.calls == [("stop", True)]


def test_when_one_address_opens_more_connections_than_its_share_expect_its_oldest_closed(
    tmp_path: Path,
):
    """max_clients counted WebSockets only, then every TCP connection together (8 per
    max_clients): one address could take them all. It may hold CONNECTIONS_PER_ADDRESS: each
    half-sent request beyond closes its oldest one, its slots come back as its connections end,
    and the closings are logged in summaries."""
    logged: list[tuple[str, str]] = []
    servers: list[ConsoleServer] = []

    with serving(tmp_path, logged=logged, servers=servers, summary_period_s=0.2) as (base, _):
        port = port_of(base)
        sockets = []
        try:
            for _ in range(CONNECTIONS_PER_ADDRESS + 4):
                sock = idle_socket(port, "127.0.0.1")
                sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
                sockets.append(sock)
            oldest = answers(sockets[:4])
            held = select.select(sockets[4:], [], [], 0.1)[0]
        finally:
            for sock in sockets:
                sock.close()
        assert all(a.startswith(REFUSED) for a in oldest), oldest
        assert held == [], "one of the newest connections was answered or closed"
        deadline = time.monotonic() + 5.0
        while True:  # the slots come back as the connections end
            with socket.create_connection(("127.0.0.1", port), timeout=3.0) as sock:
                sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
                if answer(sock).startswith(b"HTTP/1.1 200") or time.monotonic() > deadline:
                    break
            time.sleep(0.05)
        assert time.monotonic() <= deadline
        summaries = [m for _, m in logged if "connection(s) refused" in m]
        deadline = time.monotonic() + 5.0
        while not summaries and time.monotonic() < deadline:
            time.sleep(0.1)
            summaries = [m for _, m in logged if "connection(s) refused" in m]
    assert servers[0]._tcp.evicted == 4
    assert summaries
    assert "4 from 127.0.0.1 (waiting connections closed for newcomers)" in summaries[0]
    assert servers[0]._tcp.by_address == {}  # nothing kept for addresses without connections


def test_when_connections_stay_half_sent_expect_them_closed_in_seconds(tmp_path: Path):
    """A connection that has begun its request must end it within auth_timeout_s, or it is
    closed, and its address gets its share back."""
    with serving(tmp_path, auth_timeout_s=0.5) as (base, bridge):
        port = port_of(base)
        half = [idle_socket(port, "127.0.0.2") for _ in range(CONNECTIONS_PER_ADDRESS)]
        try:
            for sock in half:
                sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            start = time.monotonic()
            ends = answers(half, within_s=10.0)
            elapsed = time.monotonic() - start
        finally:
            for sock in half:
                sock.close()
        run(operator_stops(base, "127.0.0.2"))
    assert ends == [b"(closed)"] * CONNECTIONS_PER_ADDRESS, ends
    assert elapsed < 10.0  # a generous bound on 0.5 s: minutes (aiohttp's default) fail it
    assert bridge.calls == [("stop", True)]


@pytest.mark.parametrize("tls", [False, True], ids=["http", "https"])
def test_when_a_browser_opens_a_connection_before_its_request_expect_it_served_later(
    tmp_path: Path, certificate, tls: bool
):
    """A browser opens connections before it knows their requests (Chromium's speculative
    connection at a navigation's start) and sends a request on one seconds later on a loaded
    machine. The console closed every connection silent for auth_timeout_s: a request sent as
    it closed met a reset, and the browser test's first page failed with
    ERR_SOCKET_NOT_CONNECTED. A silent connection is closed only to make room for a newcomer;
    the request's own clock starts at its first byte."""
    cert, key = (str(p) for p in certificate)
    trust = ssl.create_default_context(cafile=cert)
    settings = {"certfile": cert, "keyfile": key} if tls else {}
    with serving(tmp_path, auth_timeout_s=0.5, **settings) as (base, _):
        port = port_of(base)
        sock: socket.socket = idle_socket(port, "127.0.0.1")
        if tls:
            sock = trust.wrap_socket(sock, server_hostname="localhost")
        with sock:
            time.sleep(4 * 0.5)  # silent for longer than auth_timeout_s
            sock.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
            page = answer(sock)
    assert page.startswith(b"HTTP/1.1 200"), page


def test_when_served_over_https_expect_the_page_and_websocket_to_work(tmp_path: Path, certificate):
    cert, key = certificate
    trust = ssl.create_default_context(cafile=str(cert))

    async def scenario(base: str) -> None:
        async with aiohttp.ClientSession() as session:
            async with session.get(f"{base}/", ssl=trust) as response:
                assert response.status == 200
            ws = await connect(session, base, ssl=trust)
            await until(ws, "welcome")

    with serving(tmp_path, certfile=str(cert), keyfile=str(key), token=TOKEN) as (base, _):
        run(scenario(base))


def test_when_the_port_is_taken_expect_a_configuration_error(tmp_path: Path):
    with serving(tmp_path) as (base, _):
        port = int(base.rsplit(":", 1)[1])
        refused = pytest.raises(ConfigurationError, match=r"cannot listen on 127\.0\.0\.1")
        with refused, serving(tmp_path, port=port):
            pass


def test_audio_header_is_16_bytes():
    assert AUDIO_HEADER.size == 16  # the page writes it by hand (web/src/main.js)


@pytest.mark.parametrize(
    ("heard", "raw", "pairs", "ambiguous"),
    [
        ([0, 20, 40], [5, 25, 45], [(0, 0), (1, 1), (2, 2)], 0),
        ([0, 20, 40, 60], [5, 45, 65], [(0, 0), (2, 1), (3, 2)], 1),  # chunk 1 dropped
        ([0, 20, 40], [25, 45], [(1, 0), (2, 1)], 1),  # the first chunk completes no frame
        ([10, 30], [5, 15, 16, 35], [(0, 1), (1, 3)], 0),  # answers to nothing measured
    ],
)
def test_when_the_bench_pairs_chunks_and_raw_poses_expect_the_newest_unanswered_chunk(
    heard, raw, pairs, ambiguous
):
    from audio2pose_ros.ros.tools.console_bench import pair_chunks

    assert pair_chunks(heard, raw) == (pairs, ambiguous)


@pytest.mark.parametrize(
    ("sent", "heard", "which"),
    [
        (b"abcd", b"abcd", [0, 1, 2, 3]),
        (b"abcd", b"acd", [0, 2, 3]),  # b lost: the rest still belongs to its own chunk
        (b"a00b00", b"a0b0", [0, 1, 3, 4]),  # equal chunks (silence) match in order
        (b"abc", b"axc", [0, None, 2]),  # something else on the topic matches nothing
    ],
)
def test_when_chunks_are_lost_on_the_way_expect_each_heard_one_matched_to_its_own(
    sent, heard, which
):
    """Audio is best effort: the bench reported a lost chunk as an error, not as a loss."""
    from audio2pose_ros.ros.tools.console_bench import match_heard

    assert match_heard([bytes([c]) for c in sent], [bytes([c]) for c in heard]) == which


def test_when_the_console_command_is_given_a_network_bind_without_certificate_expect_refused(
    capsys,
):
    from audio2pose_ros.cli.main import main

    assert main(["console", "--host", "0.0.0.0"]) == 1  # before any process starts
    assert "needs HTTPS" in capsys.readouterr().err


DROPPING_CLIENT = """
import asyncio, json, sys, time, aiohttp
from audio2pose_ros.console.protocol import audio_frame
async def main(base):
    async with aiohttp.ClientSession() as session:
        ws = await session.ws_connect(base.replace("http", "ws") + "/ws", origin=base)
        await ws.send_str(json.dumps({"type": "hello", "token": "", "name": "Dee"}))
        await ws.send_str(json.dumps({"type": "talk", "on": True}))
        await ws.send_bytes(audio_frame(0, time.time() * 1e3, bytes(640)))
        print("talking", flush=True)
        await asyncio.sleep(60)
asyncio.run(main(sys.argv[1]))
"""


def test_when_the_talkers_process_dies_expect_the_floor_released(tmp_path: Path):
    with serving(tmp_path) as (base, bridge):
        client = subprocess.Popen(
            [sys.executable, "-c", DROPPING_CLIENT, base], stdout=subprocess.PIPE, text=True
        )
        try:
            assert client.stdout is not None
            assert client.stdout.readline().strip() == "talking"
            deadline = time.monotonic() + 10.0
            while bridge.count("audio") == 0 and time.monotonic() < deadline:
                time.sleep(0.05)
            client.kill()  # no close frame: the browser crashed or the laptop vanished
        finally:
            client.wait()
        deadline = time.monotonic() + 10.0
        while bridge.count("end") == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [name for name, _ in bridge.calls] == ["start", "audio", "end"]

        async def successor() -> None:
            async with aiohttp.ClientSession() as session:
                ws = await connect(session, base)
                await ws.send_str('{"type":"talk","on":true}')
                await until(ws, "floor", you=True)

        run(successor())


@pytest.mark.ros
@pytest.mark.parametrize(
    ("ros_args", "expected"),
    [
        (("-p", "host:=0.0.0.0"), "parameter host: value '0.0.0.0' is reachable"),
        (("-p", "port:=70000"), "parameter port: value 70000 is out of range"),
        (("-p", "max_browser_audio_s_per_s:=9.0"), "max_browser_audio_s_per_s: value 9.0"),
    ],
)
def test_when_console_node_is_misconfigured_expect_one_line_and_status_78(ros_args, expected):
    from node_processes import configuration_error_line

    assert expected in configuration_error_line("console_node", *ros_args)


# --- wrong tokens and who holds the stop --------------------------------------------------------


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_when_an_address_keeps_sending_wrong_tokens_expect_its_wait_to_double_up_to_a_bound():
    clock = FakeClock()
    throttle = TokenThrottle(base_delay_s=0.5, max_delay_s=30.0, clock=clock)
    waits = []
    for _ in range(9):  # each attempt comes as soon as it may: its wait is the whole delay
        wait = throttle.wait_s("10.0.0.9")
        assert wait is not None
        waits.append(wait)
        clock.now += wait
        throttle.done("10.0.0.9", matched=False)
    assert waits == [0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 30.0]
    assert throttle.wait_s("10.0.0.7") == 0.0  # another address is not slowed
    throttle.done("10.0.0.7", matched=True)
    assert len(throttle) == 1  # an address without wrong tokens is not remembered


def test_when_an_address_tries_tokens_in_parallel_expect_one_checked_at_a_time():
    clock = FakeClock()
    throttle = TokenThrottle(base_delay_s=0.5, clock=clock)
    assert throttle.wait_s("10.0.0.9") == 0.0
    throttle.done("10.0.0.9", matched=False)
    assert throttle.wait_s("10.0.0.9") == 0.5  # this one waits its turn ...
    assert throttle.wait_s("10.0.0.9") is None  # ... and one meanwhile is refused unchecked
    assert throttle.refused_unchecked == 1
    throttle.done("10.0.0.9", matched=None)  # the waiting one left before its check
    clock.now += 0.5
    assert throttle.wait_s("10.0.0.9") == 0.0


def test_when_wrong_tokens_come_from_many_addresses_expect_bounded_memory_and_the_worst_kept():
    clock = FakeClock()
    throttle = TokenThrottle(base_delay_s=0.5, max_addresses=64, forget_s=600.0, clock=clock)
    for _ in range(10):  # one address guesses ten times ...
        clock.now += throttle.wait_s("10.9.9.9") or 0.0
        throttle.done("10.9.9.9", matched=False)
    for i in range(10_000):  # ... then 10,000 others once each, to wash it out
        clock.now += 0.001
        key = f"10.{i // 65536}.{i // 256 % 256}.{i % 256}"
        assert throttle.wait_s(key) == 0.0
        throttle.done(key, matched=False)
        assert len(throttle) <= 64
    assert throttle.wait_s("10.9.9.9") == pytest.approx(30.0 - 10.0, abs=0.01)
    throttle.done("10.9.9.9", matched=None)
    clock.now += 600.0  # forgotten once quiet for forget_s
    assert throttle.wait_s("10.9.9.9") == 0.0
    assert len(throttle) <= 64


def test_when_wrong_tokens_are_summarized_expect_one_line_with_the_counts():
    throttle = TokenThrottle(clock=FakeClock())
    for key in ("10.0.0.1", "10.0.0.1", "10.0.0.2"):
        throttle.wait_s(key)
        throttle.done(key, matched=False)
    summary = throttle.summary()
    assert summary.startswith("3 wrong token(s) from 2 address(es) (most: 10.0.0.1 2, 10.0.0.2 1)")
    assert throttle.summary() == ""  # a new window
    assert throttle.wrong_tokens == 3


@pytest.mark.parametrize(
    ("address", "key"),
    [
        ("192.0.2.7", "192.0.2.7"),
        ("::ffff:192.0.2.7", "192.0.2.7"),
        ("2001:db8:1:2:aaaa::1", "2001:db8:1:2::/64"),
        ("2001:db8:1:2:bbbb::9", "2001:db8:1:2::/64"),  # the same host's /64
        ("fe80::1%eth0", "fe80::/64"),
        ("?", "?"),
    ],
)
def test_when_a_client_connects_expect_it_counted_by_its_address_or_ipv6_network(address, key):
    assert client_key(address) == key


def test_when_one_address_guesses_tokens_expect_a_growing_wait_and_summarized_log_lines(
    tmp_path: Path,
):
    """Wrong tokens were never slowed (122 to 216 guesses a second from one client) and each
    was logged in its own line."""
    throttle = TokenThrottle(base_delay_s=0.2, max_delay_s=0.8)
    logged: list[tuple[str, str]] = []

    async def guess(source: str, token: str = "wrong-token") -> int | None:
        async with from_address(source) as session:
            return await closed(await connect(session, base, token=token))

    async def one_address() -> tuple[float, list[int | None]]:
        start = time.monotonic()
        codes = [await guess("127.0.0.2") for _ in range(4)]
        elapsed = time.monotonic() - start
        async with from_address("127.0.0.2") as session:  # two at once: one waits its turn
            first = await connect(session, base, token="wrong-token")
            second = await connect(session, base, token="wrong-token")
            codes += sorted([await closed(first), await closed(second)])
            operator = await connect(session, base)  # the token still opens, after the wait
            await until(operator, "welcome")
        return elapsed, codes

    async def many_addresses(n: int) -> None:
        for i in range(n):  # each address's first wrong token: checked at once
            assert await guess(f"127.0.1.{i + 1}") == 4401

    with serving(tmp_path, token=TOKEN, logged=logged, tokens=throttle, summary_period_s=0.5) as (
        base,
        _,
    ):
        elapsed, codes = run(one_address())
        start, before = time.monotonic(), len(logged)
        run(many_addresses(100))
        deadline = time.monotonic() + 10.0

        def counted() -> int:
            found = [re.search(r"(\d+) wrong token", m) for _, m in logged]
            return sum(int(f.group(1)) for f in found if f)

        while counted() < 105 and time.monotonic() < deadline:
            time.sleep(0.1)
        periods = (time.monotonic() - start) / 0.5
    assert codes == [4401] * 5 + [4429]
    # the 2nd, 3rd and 4th guesses waited 0.2, 0.4 and 0.8 s after the one before
    assert elapsed >= 0.2 + 0.4 + 0.8
    assert throttle.failures("127.0.0.2") == 5
    assert counted() == 105
    lines = [m for _, m in logged[before:] if "token" in m]
    assert len(lines) <= periods + 2, lines  # one summary a period, not one line a token
    assert len(lines) < 100 / 4


def test_when_an_observer_stops_the_robot_expect_only_they_release_it_or_a_confirmation(
    tmp_path: Path,
):
    """A STOP pressed by one operator was released by the talking operator with one message."""
    ann_here = [{"name": "Ann", "present": True}]
    ann_left = [{"name": "Ann", "present": False}]

    async def error(ws: aiohttp.ClientWebSocketResponse) -> str:
        return str((await until(ws, "error"))["message"])

    async def scenario() -> None:
        async with aiohttp.ClientSession() as session:
            ann = await connect(session, base, name="Ann")
            bob = await connect(session, base, name="Bob")
            await until(bob, "welcome")
            await bob.send_str('{"type":"talk","on":true}')
            await until(bob, "floor", you=True)
            await ann.send_str('{"type":"stop","on":true}')
            await until(ann, "stop_holders", holders=ann_here, you=True)
            await until(bob, "stop_holders", holders=ann_here, you=False)
            await bob.send_str('{"type":"stop","on":false}')  # the talker: not his stop
            assert "held by Ann: only they can release it" in await error(bob)
            await bob.send_str('{"type":"stop","on":false,"confirm":"Ann"}')
            assert "Ann is still connected" in await error(bob)
            await ann.send_str('{"type":"stop","on":false}')  # hers to release
            await until(bob, "stop_holders", holders=[])

            await ann.send_str('{"type":"stop","on":true}')
            await bob.send_str('{"type":"stop","on":true}')  # two holders: both must release
            await until(bob, "stop_holders", you=True)
            await bob.send_str('{"type":"stop","on":false}')
            await until(bob, "stop_holders", holders=ann_here, you=False)
            await ann.close()  # she leaves: her stop stays
            await until(bob, "stop_holders", holders=ann_left)
            impostor = await connect(session, base, name="Ann")  # her name is not hers to take
            assert (await until(impostor, "welcome"))["name"] == "Ann (2)"
            await impostor.send_str('{"type":"stop","on":false}')
            assert "held by Ann, who left" in await error(impostor)
            await bob.send_str('{"type":"stop","on":false,"confirm":"Zed"}')
            assert "no stop of 'Zed'" in await error(bob)
            await bob.send_str('{"type":"stop","on":false,"confirm":"Ann"}')
            await until(bob, "stop_holders", holders=[])

    logged: list[tuple[str, str]] = []
    with serving(tmp_path, logged=logged) as (base, bridge):
        run(scenario())
    assert [on for kind, on in bridge.calls if kind == "stop"] == [True, False, True, True, False]
    assert any("released the stop of 'Ann', who has left" in m for _, m in logged), logged


class StoppedOutsideBridge(Bridge):
    """A robot stopped by another tool on the stop topic (or before the console started)."""

    def status(self) -> dict[str, Any]:
        return {"stop": True, "latency": {"n": 0}}


def test_when_the_stop_was_set_outside_the_console_expect_its_release_confirmed(tmp_path: Path):
    async def scenario() -> str:
        async with aiohttp.ClientSession() as session:
            ws = await connect(session, base, name="Bob")
            await until(ws, "stop_holders", holders=[])
            await ws.send_str('{"type":"stop","on":false}')
            refused = str((await until(ws, "error"))["message"])
            await ws.send_str(json.dumps({"type": "stop", "on": False, "confirm": OUTSIDE}))
            await ws.send_str('{"type":"ping","t":1}')
            await until(ws, "pong")
            return refused

    with serving(tmp_path, bridge=StoppedOutsideBridge()) as (base, bridge):
        refused = run(scenario())
    assert f"set {OUTSIDE}" in refused
    assert bridge.calls == [("stop", False)]


def test_when_names_are_taken_expect_a_unique_one_and_never_the_outside_holder():
    assert unique_name("Ann", {"Bob"}) == "Ann"
    assert unique_name("Ann", {"Ann", "Ann (2)"}) == "Ann (3)"
    assert unique_name(OUTSIDE, set()) == f"{OUTSIDE} (2)"
    assert len(unique_name("x" * 40, {"x" * 40})) == 40
    holders = StopHolders()
    assert holders.press(1, "Ann")
    assert not holders.press(1, "Ann")
    assert holders.left(1)
    assert not holders.release(2)  # a new connection is not her
    assert not holders.release_absent("Bob")
    assert holders.release_absent("Ann")
    assert not holders.held
    for session in range(10 * MAX_PRESSES):  # press and leave, over and over
        holders.press(session, f"op {session}")
        holders.left(session)
    assert len(holders.presses) == MAX_PRESSES
    assert holders.held
