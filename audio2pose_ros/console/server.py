"""The console's HTTP and WebSocket server (aiohttp), in its own thread and asyncio loop.

It serves the page (the built front end, ``web/dist``), the robot's URDF and one WebSocket,
``/ws``, and talks to the robot only through a :class:`GraphBridge` (``console_node`` is one;
tests use their own). What a connection goes through:

1. **Before the upgrade**: the Host and Origin checks of
   :func:`~audio2pose_ros.console.access.request_problem` (403) and ``max_clients`` open
   connections, identified or still waiting for their token (503).
2. **Token**: the first message must be a ``hello`` with the token, within ``auth_timeout_s``;
   otherwise the connection is closed (code 4401 for a wrong token, 4400 for anything else).
3. **Bounded use**: a frame larger than the largest allowed chunk closes the connection (1009,
   before it is read in full); every other frame is checked by
   :mod:`~audio2pose_ros.console.protocol`; audio counts against
   ``max_browser_audio_s_per_s`` and text against ``max_messages_per_s``. A refused frame is
   dropped, counted and answered with an ``error`` message (at most :data:`ERRORS_PER_S` a
   second after a burst of :data:`ERRORS_BURST`); a connection that keeps sending refused
   frames (:data:`VIOLATION_BURST` more than :data:`VIOLATIONS_PER_S` allow) is closed. Audio
   beyond its rate is only dropped and counted: the page may be catching up after a stall.
4. **The floor**: only the holder's audio is published; a ``stop`` is accepted from anyone, a
   release of the stop, ``enable`` and ``gains`` only while the floor is free or one's own.
5. **The end**: a closed or dropped connection (WebSocket pings every :data:`HEARTBEAT_S`)
   releases its floor: audio stops, and the filter's watchdog brings the robot to rest.

Every page is sent the pose at ``pose_rate_hz`` and the status (stop, enable, gains, health,
latency, floor, operators) every :data:`STATUS_PERIOD_S`; a page that reads slower than that
skips frames rather than making the server queue them.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import ssl
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from aiohttp import WSMsgType, web

from audio2pose_ros.audio.source import AudioBudget
from audio2pose_ros.console.access import Access, request_problem
from audio2pose_ros.console.floor import Floor
from audio2pose_ros.console.protocol import (
    AUDIO_HEADER,
    MAX_TEXT_BYTES,
    AudioFrame,
    Control,
    ProtocolError,
    encode,
    parse_audio_frame,
    parse_control,
)
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.errors import ConfigurationError

__all__ = ["ConsoleServer", "GraphBridge", "ServerThread"]

HEARTBEAT_S = 5.0  # WebSocket ping period; a peer that misses a pong is dropped
STATUS_PERIOD_S = 0.5
ERRORS_PER_S = 2.0  # error messages sent back to one connection at most ...
ERRORS_BURST = 10.0  # ... after a burst of this many
VIOLATIONS_PER_S = 5.0  # refused frames a connection may keep sending ...
VIOLATION_BURST = 50.0  # ... after a burst of this many; beyond it the connection is closed
CLOSE_BAD_TOKEN = 4401
CLOSE_NO_HELLO = 4400
CLOSE_POLICY = 1008  # RFC 6455: policy violation
SEND_TIMEOUT_S = 2.0
CONTENT_TYPES = {
    ".html": "text/html",
    ".js": "text/javascript",
    ".css": "text/css",
    ".map": "application/json",
    ".svg": "image/svg+xml",
    ".png": "image/png",
}
SECURITY_HEADERS = {
    # Everything the page needs comes from the console itself.
    "Content-Security-Policy": (
        "default-src 'self'; connect-src 'self'; img-src 'self' data: blob:; "
        "style-src 'self'; script-src 'self'; worker-src 'self' blob:; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
    "Cache-Control": "no-store",
}
NOT_BUILT_PAGE = """<!doctype html><html><head><meta charset="utf-8">
<title>audio2pose console</title></head><body><h1>The console's front end is not built</h1>
<p>The node runs, but the page's scripts are missing: install Node.js and npm, then run
<code>make setup</code> (or <code>cd web &amp;&amp; npm ci &amp;&amp; npm run build</code>) and
restart the console.</p></body></html>
"""


class AudioOverRateError(ProtocolError):
    """Audio beyond ``max_browser_audio_s_per_s``: dropped and counted, the connection stays."""


class GraphBridge(Protocol):
    """What the server needs from the robot's side; called from the server's thread."""

    joint_names: list[str]
    neutral: dict[str, float]  # the robot's neutral pose (rad), drawn before any command

    def publish_audio(self, frame: AudioFrame, received_s: float) -> None:
        """Publish one chunk of the floor holder's voice."""

    def start_talk(self) -> None:
        """A talker got the floor."""

    def end_talk(self) -> None:
        """The talker released the floor (or left): no more audio follows."""

    def set_stop(self, on: bool) -> None:
        """Publish the emergency stop (True) or its release (False)."""

    def set_enable(self, on: bool) -> None:
        """Publish enable."""

    def set_gains(self, gains: dict[str, float]) -> None:
        """Set the filter's gains (``head``, ``arms``, ``hip``: the ``*_gain`` parameters)."""

    def pose(self) -> dict[str, Any]:
        """The latest commanded and measured pose: name -> angle (rad), or None each."""

    def status(self) -> dict[str, Any]:
        """Stop, enable, gains, health and latency, JSON-ready."""


@dataclass
class _Session:
    """One WebSocket connection."""

    id: int
    ws: web.WebSocketResponse
    peer: str
    audio: AudioBudget
    messages: AudioBudget
    violations: AudioBudget = field(
        default_factory=lambda: AudioBudget(VIOLATIONS_PER_S, VIOLATION_BURST)
    )
    errors: AudioBudget = field(default_factory=lambda: AudioBudget(ERRORS_PER_S, ERRORS_BURST))
    name: str = ""
    sending: bool = False
    refused: int = 0


class ConsoleServer:
    """The page, the URDF and the WebSocket; run it in a :class:`ServerThread`.

    Args:
        settings: the console's settings.
        access: the resolved bind and token rules.
        bridge: the robot's side.
        web_dir: the built front end (``index.html`` and its files, flat).
        urdf_path: the robot model the page draws.
        log: ``log(level, message)`` with level ``info`` or ``warning``.
    """

    def __init__(
        self,
        settings: ConsoleSettings,
        access: Access,
        bridge: GraphBridge,
        web_dir: Path,
        urdf_path: Path,
        log: Callable[[str, str], None],
    ) -> None:
        self.settings = settings
        self.access = access
        self.bridge = bridge
        self.web_dir = web_dir
        self.urdf = urdf_path.read_text(encoding="utf-8")
        self.log = log
        self.floor = Floor()
        self.sessions: dict[int, _Session] = {}
        self.refused_connections = 0
        self.refused_frames = 0
        self.connections = 0  # open WebSockets, with or without their token yet
        self.port = 0
        self._ids = itertools.count(1)
        self._runner: web.AppRunner | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self.files = {
            path.name: path.read_bytes()
            for path in sorted(web_dir.glob("*"))
            if path.is_file() and path.suffix in CONTENT_TYPES
        }
        self.built = "index.html" in self.files

    # --- lifecycle ------------------------------------------------------------------------------

    def _ssl_context(self) -> ssl.SSLContext | None:
        if not self.access.certfile:
            return None
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        try:
            context.load_cert_chain(self.access.certfile, self.access.keyfile)
        except (OSError, ssl.SSLError) as exc:
            raise ConfigurationError(
                f"parameters certfile and keyfile: cannot load {self.access.certfile} with "
                f"{self.access.keyfile}: {exc}"
            ) from None
        return context

    async def start(self) -> int:
        """Bind and serve; return the port.

        Raises:
            ConfigurationError: the certificate does not load, or the address cannot be bound.
        """
        app = web.Application(middlewares=[_security_headers], client_max_size=MAX_TEXT_BYTES)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/urdf/pepper.urdf", self._urdf)
        app.router.add_get("/favicon.ico", self._no_icon)
        app.router.add_get("/{name}", self._file)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(
            self._runner, self.access.host, self.access.port, ssl_context=self._ssl_context()
        )
        try:
            await site.start()
        except OSError as exc:
            await self._runner.cleanup()
            raise ConfigurationError(
                f"parameters host and port: cannot listen on {self.access.host}:"
                f"{self.access.port}: {exc.strerror or exc}"
            ) from None
        server = site._server  # the bound socket tells the port chosen for port 0
        sockets = getattr(server, "sockets", None) or []
        self.port = int(sockets[0].getsockname()[1]) if sockets else self.access.port
        self._tasks = [
            asyncio.create_task(self._every(1.0 / self.settings.pose_rate_hz, self._send_pose)),
            asyncio.create_task(self._every(STATUS_PERIOD_S, self._send_status)),
        ]
        return self.port

    async def stop(self) -> None:
        """Release the floor, close every connection, stop serving."""
        for task in self._tasks:
            task.cancel()
        for session in list(self.sessions.values()):
            await session.ws.close(code=1001, message=b"console stopping")
        if self._runner is not None:
            await self._runner.cleanup()

    async def _every(self, period_s: float, send: Callable[[], Awaitable[None]]) -> None:
        while True:
            await asyncio.sleep(period_s)
            try:
                await send()
            except Exception as exc:  # the boundary: a bad snapshot must not end the loop
                self.log("warning", f"console: sending to the pages failed: {exc!r}")

    # --- HTTP -----------------------------------------------------------------------------------

    async def _index(self, _request: web.Request) -> web.Response:
        if not self.built:
            return web.Response(text=NOT_BUILT_PAGE, content_type="text/html")
        return web.Response(body=self.files["index.html"], content_type="text/html")

    async def _file(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        body = self.files.get(name)
        if body is None:
            raise web.HTTPNotFound()
        return web.Response(body=body, content_type=CONTENT_TYPES[Path(name).suffix])

    async def _no_icon(self, _request: web.Request) -> web.Response:
        return web.Response(status=204)

    async def _urdf(self, _request: web.Request) -> web.Response:
        return web.Response(text=self.urdf, content_type="application/xml")

    # --- WebSocket ------------------------------------------------------------------------------

    async def _websocket(self, request: web.Request) -> web.StreamResponse:
        peer = request.remote or "?"
        problem = request_problem(
            self.access, request.headers.get("Host"), request.headers.get("Origin")
        )
        if problem:
            self.refused_connections += 1
            self.log("warning", f"console: WebSocket from {peer} refused: {problem}")
            raise web.HTTPForbidden(text=problem)
        if self.connections >= self.settings.max_clients:  # identified or not yet
            self.refused_connections += 1
            raise web.HTTPServiceUnavailable(
                text=f"at most {self.settings.max_clients} operators at once"
            )
        ws = web.WebSocketResponse(
            heartbeat=HEARTBEAT_S,
            max_msg_size=AUDIO_HEADER.size + self.settings.max_chunk_bytes,
        )
        await ws.prepare(request)
        self.connections += 1
        session = _Session(
            id=next(self._ids),
            ws=ws,
            peer=peer,
            audio=AudioBudget(
                self.settings.max_browser_audio_s_per_s,
                max(self.settings.max_browser_audio_s_per_s, self.settings.max_browser_chunk_s),
            ),
            messages=AudioBudget(
                self.settings.max_messages_per_s, self.settings.max_messages_per_s
            ),
        )
        try:
            if await self._authenticate(session):
                self.sessions[session.id] = session
                self.log("info", f"console: operator {session.name!r} connected from {peer}")
                await self._welcome(session)
                await self._serve(session)
        finally:
            self.connections -= 1
            self.sessions.pop(session.id, None)
            if self.floor.release(session.id):
                self.bridge.end_talk()
                await self._send_floor()
            if session.name:
                self.log("info", f"console: operator {session.name!r} left")
        return ws

    async def _authenticate(self, session: _Session) -> bool:
        """Wait for the hello with the token; close the connection if it does not come."""
        ws = session.ws
        try:
            message = await ws.receive(timeout=self.settings.auth_timeout_s)
        except asyncio.TimeoutError:
            await ws.close(code=CLOSE_NO_HELLO, message=b"no hello with the token in time")
            return False
        try:
            if message.type != WSMsgType.TEXT:
                raise ProtocolError("the first message must be a hello with the token")
            control = parse_control(message.data)
            if control.type != "hello":
                raise ProtocolError("the first message must be a hello with the token")
        except ProtocolError as exc:
            self.refused_frames += 1
            await ws.close(code=CLOSE_NO_HELLO, message=str(exc)[:120].encode())
            return False
        if not self.access.token_matches(control.fields["token"]):
            self.refused_connections += 1
            self.log("warning", f"console: wrong token from {session.peer}: connection closed")
            await ws.send_str(encode("error", message="wrong token: access refused"))
            await ws.close(code=CLOSE_BAD_TOKEN, message=b"wrong token")
            return False
        name = " ".join(control.fields.get("name", "").split()) or f"operator {session.id}"
        session.name = name
        return True

    async def _welcome(self, session: _Session) -> None:
        await session.ws.send_str(
            encode(
                "welcome",
                id=session.id,
                name=session.name,
                joints=list(self.bridge.joint_names),
                neutral=dict(self.bridge.neutral),
                urdf="urdf/pepper.urdf",
            )
        )
        await self._send_floor()

    async def _serve(self, session: _Session) -> None:
        async for message in session.ws:
            try:
                if message.type == WSMsgType.BINARY:
                    self._on_audio(session, message.data)
                elif message.type == WSMsgType.TEXT:
                    if not session.messages.take(1.0):
                        raise ProtocolError(
                            f"more than {self.settings.max_messages_per_s:g} messages per "
                            "second: dropped"
                        )
                    await self._on_control(session, parse_control(message.data))
                else:  # an oversized frame or a broken connection: aiohttp closes it
                    break
            except AudioOverRateError as exc:  # a page catching up after a stall: not a fault
                await self._refuse(session, str(exc), violation=False)
            except ProtocolError as exc:
                if not await self._refuse(session, str(exc)):
                    break
            except Exception as exc:  # the boundary: a bug must not end the operator's session
                self.log("warning", f"console: {session.name!r}'s message failed: {exc!r}")
                if not await self._refuse(session, "the console could not act on that message"):
                    break

    async def _refuse(self, session: _Session, reason: str, violation: bool = True) -> bool:
        """Count a refused frame and tell the page; False when the connection is closed for it.

        Only a ``violation`` counts towards closing the connection.
        """
        session.refused += 1
        self.refused_frames += 1
        if violation and not session.violations.take(1.0):
            self.log(
                "warning",
                f"console: closing {session.name!r} ({session.peer}): {session.refused} "
                f"refused frames, last: {reason}",
            )
            await session.ws.close(code=CLOSE_POLICY, message=b"too many refused frames")
            return False
        if session.errors.take(1.0):
            await session.ws.send_str(encode("error", message=reason))
        return True

    def _on_audio(self, session: _Session, data: bytes) -> None:
        received_s = time.time()
        frame = parse_audio_frame(data, self.settings.max_chunk_bytes)
        if not self.floor.holds(session.id):
            raise ProtocolError("audio without the floor: press Talk first")
        if not session.audio.take(frame.duration_s):
            raise AudioOverRateError(
                f"audio beyond {self.settings.max_browser_audio_s_per_s:g} s per second: dropped"
            )
        self.bridge.publish_audio(frame, received_s)

    async def _on_control(self, session: _Session, control: Control) -> None:
        on = control.fields.get("on")
        if control.type == "ping":
            await session.ws.send_str(
                encode("pong", t=control.fields["t"], server=time.time() * 1e3)
            )
        elif control.type == "hello":
            raise ProtocolError("already identified")
        elif control.type == "talk":
            await self._talk(session, bool(on))
        elif control.type == "stop" and on:
            self.log("warning", f"console: STOP pressed by {session.name!r}")
            self.bridge.set_stop(True)
        else:
            if not self.floor.free_for(session.id):
                raise ProtocolError(
                    f"{self.floor.holder_name} has the floor: only a stop is accepted meanwhile"
                )
            if control.type == "stop":
                self.log("info", f"console: stop released by {session.name!r}")
                self.bridge.set_stop(False)
            elif control.type == "enable":
                self.bridge.set_enable(bool(on))
            else:
                self.bridge.set_gains({k: float(v) for k, v in control.fields.items()})

    async def _talk(self, session: _Session, on: bool) -> None:
        if on:
            if self.floor.holds(session.id):
                return
            if not self.floor.take(session.id, session.name):
                raise ProtocolError(f"{self.floor.holder_name} has the floor: wait for them")
            self.bridge.start_talk()
        elif self.floor.release(session.id):
            self.bridge.end_talk()
        else:
            return
        await self._send_floor()

    # --- broadcasts -----------------------------------------------------------------------------

    async def _send_floor(self) -> None:
        for session in list(self.sessions.values()):
            text = encode(
                "floor",
                holder=self.floor.holder_name or None,
                you=self.floor.holds(session.id),
            )
            self._send(session, text, droppable=False)

    async def _send_pose(self) -> None:
        if self.sessions:
            text = encode("pose", **self.bridge.pose())
            for session in list(self.sessions.values()):
                self._send(session, text)

    async def _send_status(self) -> None:
        if self.sessions:
            status = self.bridge.status()
            status["operators"] = len(self.sessions)
            status["floor"] = self.floor.holder_name or None
            text = encode("status", **status)
            for session in list(self.sessions.values()):
                self._send(session, text)

    def _send(self, session: _Session, text: str, droppable: bool = True) -> None:
        """Send without waiting.

        A ``droppable`` message (pose, status) skips a page whose previous one is still on its
        way, so a slow page gets fewer updates, not late ones.
        """
        if session.ws.closed or (droppable and session.sending):
            return
        if droppable:
            session.sending = True

        async def send() -> None:
            try:
                await asyncio.wait_for(session.ws.send_str(text), SEND_TIMEOUT_S)
            except (ConnectionError, asyncio.TimeoutError, RuntimeError):
                pass  # a closing connection: its handler cleans up
            finally:
                if droppable:
                    session.sending = False

        asyncio.get_running_loop().create_task(send())


@web.middleware
async def _security_headers(
    request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
) -> web.StreamResponse:
    """Every answer carries the console's security headers (a WebSocket's upgrade excepted)."""
    response = await handler(request)
    if not isinstance(response, web.WebSocketResponse):
        response.headers.update(SECURITY_HEADERS)
    return response


class ServerThread:
    """Runs a :class:`ConsoleServer` in its own thread and asyncio loop, next to rclpy's executor.

    Args:
        server: the server to run.
    """

    def __init__(self, server: ConsoleServer) -> None:
        self.server = server
        self.loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="console-server", daemon=True)

    def start(self, timeout_s: float = 10.0) -> int:
        """Start serving; return the bound port.

        Raises:
            ConfigurationError: the server cannot start (certificate, address in use).
        """
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise ConfigurationError(f"the console server did not start within {timeout_s:g} s")
        if self._error is not None:
            if isinstance(self._error, ConfigurationError):
                raise self._error
            raise ConfigurationError(f"the console server cannot start: {self._error!r}")
        return self.server.port

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.loop.run_until_complete(self.server.start())
        except BaseException as exc:  # reported to start() in the node's thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()
        self.loop.run_until_complete(self.server.stop())
        self.loop.close()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close the connections and stop serving."""
        if self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout_s)
