"""The console's HTTP and WebSocket server (aiohttp), run by a ``ServerThread``.

It serves the page (the built front end, ``web/dist``), the robot's URDF and one WebSocket,
``/ws`` (:class:`~audio2pose_ros.console.server_thread.ServerThread` runs it), and talks to
the robot only through a :class:`GraphBridge` (``console_node`` is one; tests use their own).
The "learn my style" upload (``POST /enroll/{ticket}``) and the page's ``enroll`` and
``style`` messages are :mod:`~audio2pose_ros.console.learn_style`'s; what an identified
operator may do to the robot (the floor, the stop and its owners, the settings) is
:mod:`~audio2pose_ros.console.room`'s. What a connection goes through:

1. **The TCP connection**, counted by its client address from its acceptance, before any TLS
   handshake, by the console's front door (:mod:`~audio2pose_ros.console.door`): one address
   may hold a limited share, all addresses together enough for ``max_clients`` operators more.
   A newcomer beyond a limit takes the place of a connection that has made no request yet
   (the oldest of the address holding the most): connections that wait for
   nothing cannot keep new operators out, however fast they come back, and a connection that
   has made a request (a page, a WebSocket, an operator) is never closed for anyone. Only when
   no connection waits is the newcomer closed at once (answered 503 on plain HTTP; over TLS
   before its handshake). A connection must complete its TLS handshake within
   ``auth_timeout_s``, and a request within as long of its first byte; an idle keep-alive
   connection is closed after as long (aiohttp's own default is an hour: half-sent requests
   would hold sockets that long). A connection that has sent nothing yet (a browser opens one
   before it knows its request, and may send it seconds later on a loaded machine) is closed
   only to make room.
2. **Before the upgrade**: the Host and Origin checks of
   :func:`~audio2pose_ros.console.access.request_problem` (403), ``max_clients`` identified
   operators, and :data:`PENDING_PER_ADDRESS` WebSockets of one address still waiting for their
   token (503): connections without the token cannot take the operators' places.
3. **Token**: the first message must be a ``hello`` with the token, within ``auth_timeout_s``;
   otherwise the connection is closed (code 4401 for a wrong token, 4400 for anything else).
   Wrong tokens slow their address down
   (:class:`~audio2pose_ros.console.access.TokenThrottle`: the next one is checked only after
   a delay that doubles with each, one at a time; one that comes meanwhile is closed
   unchecked, code 4429). Refused connections and wrong tokens are logged in one summary line
   every :data:`SUMMARY_PERIOD_S` at most, not one line each.
4. **Bounded use**: a frame larger than the largest allowed chunk closes the connection (1009,
   before it is read in full); every other frame is checked by
   :mod:`~audio2pose_ros.console.protocol`; audio counts against
   ``max_browser_audio_s_per_s`` seconds and :data:`MAX_AUDIO_FRAMES_PER_S` frames, text
   against ``max_messages_per_s``. A refused frame is dropped, counted (``refused_frames``) and
   answered with an ``error`` message (at most :data:`ERRORS_PER_S` a second after a burst of
   :data:`ERRORS_BURST`); a connection that keeps sending refused frames
   (:data:`VIOLATION_BURST` more than :data:`VIOLATIONS_PER_S` allow) is closed. Audio beyond
   its rates or stamped off the console's clock is only dropped and counted
   (:class:`~audio2pose_ros.console.protocol.AudioDroppedError`): the page may be catching up
   after a stall or a clock step.
5. **The floor and the stop** (:mod:`~audio2pose_ros.console.room`): only the holder's audio
   is published; ``enable``, ``mute`` and the style only while the floor is free or one's own; a
   ``stop`` from anyone, released only by whoever pressed it or, once they have left, by
   another operator who names them.
6. **The end**: a closed or dropped connection (WebSocket pings every :data:`HEARTBEAT_S`)
   releases its floor: audio stops, and the filter's watchdog brings the robot to rest. Its
   presses of STOP stay, held by someone who has left. A page
   that leaves while it is being answered ends its session quietly; any other exception in a
   connection's handler is logged in one line and closes that connection (1011), never
   escaping to aiohttp.

**The room**: every identified page, and no other, is sent what the robot sees and hears
(:mod:`~audio2pose_ros.console.room_feed`: JPEG pictures of its camera, its microphones with the
operator's echo removed) through its own :class:`~audio2pose_ros.console.room_feed.RoomOutbox`,
one message at a time, each sent when the connection has taken the one before: a page on a slow
link gets fewer pictures and never holds up another page, the pose, the status or a stop.
The status tells every page how many pages watch the room.

Every page is sent the pose at ``pose_rate_hz`` and the status (stop, enable, the style
parameters in force, health, latency, floor, operators) every :data:`STATUS_PERIOD_S`; a page
that reads slower than that skips frames rather than making the server queue them. A value in
them that JSON cannot carry (a NaN statistic) is sent as ``null`` and logged once, the rest of
the message as usual.
"""

from __future__ import annotations

import asyncio
import itertools
import ssl
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from aiohttp import WSMsgType, web

from audio2pose_ros.audio.source import AudioBudget
from audio2pose_ros.console.access import Access, TokenThrottle, client_key, request_problem
from audio2pose_ros.console.door import (
    CONNECTIONS_PER_ADDRESS,
    CONNECTIONS_PER_CLIENT,
    Connections,
    Gate,
)
from audio2pose_ros.console.enrollment import Enrollments, default_work_dir
from audio2pose_ros.console.learn_style import LearnMyStyle
from audio2pose_ros.console.protocol import (
    AUDIO_HEADER,
    MAX_TEXT_BYTES,
    AudioDroppedError,
    AudioFrame,
    Control,
    ProtocolError,
    encode,
    json_ready,
    parse_audio_frame,
    parse_control,
)
from audio2pose_ros.console.room import Operator, Room
from audio2pose_ros.console.room_feed import RoomItem, RoomOutbox, encode_room_message
from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.console.stop import unique_name
from audio2pose_ros.errors import ConfigurationError

__all__ = ["ConsoleServer", "GraphBridge"]

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]  # what a middleware wraps

HEARTBEAT_S = 5.0  # WebSocket ping period; a peer that misses a pong is dropped
STATUS_PERIOD_S = 0.5
ERRORS_PER_S = 2.0  # error messages sent back to one connection at most ...
ERRORS_BURST = 10.0  # ... after a burst of this many
VIOLATIONS_PER_S = 5.0  # refused frames a connection may keep sending ...
VIOLATION_BURST = 50.0  # ... after a burst of this many; beyond it the connection is closed
# Audio frames (binary messages) a connection may send per second: twice the page's 50 (20 ms
# chunks) ...
MAX_AUDIO_FRAMES_PER_S = 100.0
# ... after a burst of this many: 2 s of the page's chunks, more than the 75 the seconds budget
# (max_browser_audio_s_per_s, 1.5 s) lets through at once. So the page, even catching up after a
# stall, meets the seconds budget first; only chunks shorter than 15 ms meet this one, which
# bounds the messages a talker causes downstream (one ROS message each), not only their seconds.
AUDIO_FRAMES_BURST = 100.0
LISTEN_BACKLOG = 128  # connections the kernel queues before the console accepts them
PENDING_PER_ADDRESS = 2  # WebSockets of one address waiting for their token, at most
SUMMARY_PERIOD_S = 10.0  # refused connections and wrong tokens are logged this often at most
MAX_TALLIED_ADDRESSES = 1024  # addresses named in one summary's counts, at most
CLOSE_BAD_TOKEN = 4401
CLOSE_NO_HELLO = 4400
CLOSE_TOKEN_WAIT = 4429  # another attempt of this address waits for its turn: not checked
CLOSE_FULL = 4503  # max_clients operators were identified meanwhile
CLOSE_POLICY = 1008  # RFC 6455: policy violation
CLOSE_INTERNAL = 1011  # RFC 6455: the server met an unexpected condition
MAX_CLOSE_REASON_BYTES = 120  # a close frame's reason is at most 123 bytes of UTF-8
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


class _PeerLeftError(Exception):
    """A send to a page failed because its connection is closing: its session ends quietly."""


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

    def set_voice_muted(self, on: bool) -> None:
        """Mute (True) or play (False) the operator's voice out of the robot."""

    def set_style(self, settings: dict[str, float] | None) -> None:
        """Set any of the filter's live style parameters; None restores the graph's own style."""

    def set_model(self, folder: str | None, fallback: dict[str, float] | None = None) -> None:
        """Run a personal model folder on the inference node; None restores its own model.

        ``fallback``: the style applied instead when the node refuses the folder's model.
        """

    def pose(self) -> dict[str, Any]:
        """The latest commanded and measured pose: name -> angle (rad), or None each."""

    def status(self) -> dict[str, Any]:
        """Stop, enable, the style in force, health, latency and the voice, JSON-ready."""


@dataclass
class _Session:
    """One WebSocket connection."""

    id: int
    ws: web.WebSocketResponse
    peer: str
    audio: AudioBudget
    messages: AudioBudget
    frames: AudioBudget = field(
        default_factory=lambda: AudioBudget(MAX_AUDIO_FRAMES_PER_S, AUDIO_FRAMES_BURST)
    )
    violations: AudioBudget = field(
        default_factory=lambda: AudioBudget(VIOLATIONS_PER_S, VIOLATION_BURST)
    )
    errors: AudioBudget = field(default_factory=lambda: AudioBudget(ERRORS_PER_S, ERRORS_BURST))
    name: str = ""
    sending: bool = False
    refused: int = 0
    room: RoomOutbox = field(default_factory=RoomOutbox)
    room_waiting: asyncio.Event = field(default_factory=asyncio.Event)


class ConsoleServer:
    """The page, the URDF and the WebSocket; run it in a ``ServerThread``.

    Args:
        settings: the console's settings.
        access: the resolved bind and token rules.
        bridge: the robot's side.
        web_dir: the built front end (``index.html`` and its files, flat).
        urdf_path: the robot model the page draws.
        log: ``log(level, message)`` with level ``info`` or ``warning``.
        tokens: the wrong-token throttle (a default one; tests pass their own delays).
        summary_period_s: the period of the log's summaries of refusals and wrong tokens.
    """

    def __init__(
        self,
        settings: ConsoleSettings,
        access: Access,
        bridge: GraphBridge,
        web_dir: Path,
        urdf_path: Path,
        log: Callable[[str, str], None],
        tokens: TokenThrottle | None = None,
        summary_period_s: float = SUMMARY_PERIOD_S,
        enrollments: Enrollments | None = None,
    ) -> None:
        self.settings = settings
        self.enrollments = enrollments or Enrollments(default_work_dir())
        self.access = access
        self.bridge = bridge
        self.web_dir = web_dir
        self.urdf = urdf_path.read_text(encoding="utf-8")
        self.log = log
        self.tokens = tokens if tokens is not None else TokenThrottle()
        self.summary_period_s = summary_period_s
        self.sessions: dict[int, _Session] = {}
        self.refused_connections = 0
        self.refused_frames = 0
        self.port = 0
        self._ids = itertools.count(1)
        self._runner: web.AppRunner | None = None
        self._listener: asyncio.Server | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._tcp = Connections(
            CONNECTIONS_PER_CLIENT * settings.max_clients + CONNECTIONS_PER_ADDRESS,
            CONNECTIONS_PER_ADDRESS,
            on_evict=lambda key: self._tally(
                self._refusals, f"{key} (waiting connections closed for newcomers)"
            ),
        )
        self.tls: ssl.SSLContext | None = None
        self.handshake_timeout_s = settings.auth_timeout_s
        self._pending: dict[str, int] = {}  # WebSockets waiting for their token, by address
        self._refusals: dict[str, int] = {}  # refused connections since the last summary
        self._unsent: set[str] = set()  # snapshot fields sent as null, logged once each
        self.files = {
            path.name: path.read_bytes()
            for path in sorted(web_dir.glob("*"))
            if path.is_file() and path.suffix in CONTENT_TYPES
        }
        self.built = "index.html" in self.files
        self.learn_style = LearnMyStyle(
            self.enrollments,
            access,
            bridge,
            log,
            refused=lambda why: self._tally(self._refusals, why),
            may_apply=lambda id_: (
                id_ in self.sessions
                and self.floor.free_for(id_)
                and self.room.style_may_change(id_)
            ),
        )
        self.room = Room(bridge, self.learn_style, self.sessions.values, self._send_to, log)
        self.floor, self.stops = self.room.floor, self.room.stops

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

        @web.middleware
        async def requested(request: web.Request, handler: Handler) -> web.StreamResponse:
            """The connection makes a request: it is no longer closed for a newcomer."""
            self._tcp.requested(request.transport)
            return await handler(request)

        app = web.Application(
            middlewares=[requested, _security_headers], client_max_size=MAX_TEXT_BYTES
        )
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/urdf/pepper.urdf", self._urdf)
        app.router.add_get("/favicon.ico", self._no_icon)
        app.router.add_get("/{name}", self._file)
        app.router.add_post("/enroll/{ticket}", self.learn_style.upload)
        # A request's clock starts at its first byte (the door hands a connection over then): a
        # request not complete by then, or an idle keep-alive connection, is closed (the page's
        # few files load within milliseconds).
        self._runner = web.AppRunner(
            app,
            access_log=None,
            handle_signals=False,
            keepalive_timeout=self.settings.auth_timeout_s,
        )
        await self._runner.setup()
        self.tls = self._ssl_context()
        try:  # every connection starts at its gate (the door), which hands it to aiohttp
            self._listener = await asyncio.get_running_loop().create_server(
                self._accept, self.access.host, self.access.port, backlog=LISTEN_BACKLOG
            )
        except OSError as exc:
            await self._runner.cleanup()
            raise ConfigurationError(
                f"parameters host and port: cannot listen on {self.access.host}:"
                f"{self.access.port}: {exc.strerror or exc}"
            ) from None
        sockets = self._listener.sockets  # the bound socket tells the port chosen for port 0
        self.port = int(sockets[0].getsockname()[1]) if sockets else self.access.port
        self._tasks = [
            asyncio.create_task(self._every(1.0 / self.settings.pose_rate_hz, self._send_pose)),
            asyncio.create_task(self._every(STATUS_PERIOD_S, self._send_status)),
            asyncio.create_task(self._every(self.summary_period_s, self._log_summary)),
        ]
        return self.port

    async def stop(self) -> None:
        """Release the floor, close every connection, stop serving."""
        for task in self._tasks:
            task.cancel()
        self.learn_style.stop()
        if self._listener is not None:
            self._listener.close()  # no new connections
        for session in list(self.sessions.values()):
            await session.ws.close(code=1001, message=b"console stopping")
        if self._runner is not None:
            await self._runner.cleanup()  # aiohttp closes the connections it was handed
        self._tcp.close_all()  # and the door those it still holds (a TLS handshake, say)

    async def _every(self, period_s: float, send: Callable[[], Awaitable[None]]) -> None:
        failed = ""  # the last failure, logged once until it changes or sending works again
        while True:
            await asyncio.sleep(period_s)
            try:
                await send()
            except Exception as exc:  # the boundary: a bad snapshot must not end the loop
                if repr(exc) != failed:
                    self.log("warning", f"console: sending to the pages failed: {exc!r}")
                failed = repr(exc)
            else:
                failed = ""

    def _accept(self) -> asyncio.BaseProtocol:
        """The protocol for a new TCP connection: its gate, which admits it or not."""
        return Gate(self)

    def admit(self, key: str, gate: Gate) -> bool:
        """Whether ``gate``, a connection of ``key``, may open (counted if so).

        A refusal is tallied for the next summary.
        """
        problem = self._tcp.admit(key, gate)
        if not problem:
            return True
        self.refused_connections += 1
        self._tally(self._refusals, f"{key} ({problem})")
        return False

    def lost(self, key: str, gate: Gate) -> None:
        """``gate``, an admitted connection of ``key``, has ended: it stops counting."""
        self._tcp.lost(key, gate)

    def http_protocol(self) -> asyncio.Protocol:
        """The protocol of aiohttp for an admitted connection."""
        assert self._runner is not None
        assert self._runner.server is not None
        return self._runner.server()

    @staticmethod
    def _tally(counts: dict[str, int], key: str) -> None:
        """Count ``key`` in ``counts``, which names at most :data:`MAX_TALLIED_ADDRESSES`."""
        if key not in counts and len(counts) >= MAX_TALLIED_ADDRESSES:
            key = "other addresses"
        counts[key] = counts.get(key, 0) + 1

    async def _log_summary(self) -> None:
        """One line for the connections refused and one for the wrong tokens of the last period."""
        refusals, self._refusals = self._refusals, {}
        if refusals:
            worst = sorted(refusals.items(), key=lambda item: -item[1])[:3]
            self.log(
                "warning",
                f"console: {sum(refusals.values())} connection(s) refused or closed in the last "
                f"{self.summary_period_s:g} s: "
                + ", ".join(f"{count} from {why}" for why, count in worst)
                + (" and more" if len(refusals) > len(worst) else ""),
            )
        tokens = self.tokens.summary()
        if tokens:
            self.log("warning", f"console: in the last {self.summary_period_s:g} s: {tokens}")

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
        """One WebSocket from upgrade to end: the boundary no exception crosses."""
        peer = request.remote or "?"
        problem = request_problem(
            self.access, request.headers.get("Host"), request.headers.get("Origin")
        )
        if problem:
            self.refused_connections += 1
            self.log("warning", f"console: WebSocket from {peer} refused: {problem}")
            raise web.HTTPForbidden(text=problem)
        key = client_key(peer)
        if len(self.sessions) >= self.settings.max_clients:
            self.refused_connections += 1
            raise web.HTTPServiceUnavailable(
                text=f"at most {self.settings.max_clients} operators at once"
            )
        if self._pending.get(key, 0) >= PENDING_PER_ADDRESS:
            self.refused_connections += 1
            self._tally(self._refusals, f"{key} (WebSockets waiting for their token)")
            raise web.HTTPServiceUnavailable(
                text=f"at most {PENDING_PER_ADDRESS} connections of one address wait for "
                "their token at once"
            )
        ws = web.WebSocketResponse(
            heartbeat=HEARTBEAT_S,
            max_msg_size=AUDIO_HEADER.size + self.settings.max_chunk_bytes,
        )
        try:
            await ws.prepare(request)
        except ConnectionError:  # the page left during the upgrade
            return ws
        self._pending[key] = self._pending.get(key, 0) + 1
        pending = True
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
            identified = await self._authenticate(session)
            pending = self._unpend(key)
            if identified and await self._room_for(session):
                self.sessions[session.id] = session
                self.log("info", f"console: operator {session.name!r} connected from {peer}")
                await self._welcome(session)
                sender = asyncio.get_running_loop().create_task(self._send_room(session))
                try:
                    await self._serve(session)
                finally:
                    sender.cancel()
        except (_PeerLeftError, ConnectionError):
            pass  # the page left while it was being answered: nothing failed here
        except Exception as exc:  # the boundary: one line, this connection closed, no traceback
            self._failed(session, "closing it after an error", exc)
            await ws.close(code=CLOSE_INTERNAL, message=b"console error")
        finally:
            if pending:
                self._unpend(key)
            self.sessions.pop(session.id, None)
            self.enrollments.forget_session(session.id)
            try:
                self.room.left(session)
            except Exception as exc:  # the boundary, for the end of the session too
                self._failed(session, "releasing its floor failed", exc)
            if session.name:
                self.log("info", f"console: operator {session.name!r} left")
        return ws

    def _unpend(self, key: str) -> bool:
        """A WebSocket of ``key`` no longer waits for its token; False (no longer pending)."""
        left = self._pending.get(key, 0) - 1
        if left > 0:
            self._pending[key] = left
        else:
            self._pending.pop(key, None)
        return False

    async def _room_for(self, session: _Session) -> bool:
        """Whether an identified operator finds a place; closed (4503) if not."""
        if len(self.sessions) < self.settings.max_clients:
            return True
        self.refused_connections += 1
        await self._send_now(
            session,
            encode("error", message=f"at most {self.settings.max_clients} operators at once"),
        )
        await session.ws.close(code=CLOSE_FULL, message=b"too many operators")
        return False

    def _failed(self, session: _Session, what: str, exc: Exception) -> None:
        """Log an unexpected exception of a connection's handler: one line, no traceback."""
        who = repr(session.name) if session.name else "a page not yet identified"
        self.log("warning", f"console: {who} ({session.peer}): {what}: {exc!r}")

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
            await ws.close(code=CLOSE_NO_HELLO, message=_close_reason(str(exc)))
            return False
        if not await self._token_accepted(session, control.fields["token"]):
            return False
        name = " ".join(control.fields.get("name", "").split()) or f"operator {session.id}"
        taken = {other.name for other in self.sessions.values()} | self.stops.names()
        session.name = unique_name(name, taken)
        return True

    async def _token_accepted(self, session: _Session, presented: str) -> bool:
        """Check the token after its address's wait; close the connection if it is refused.

        Raises:
            _PeerLeftError: the page left before it could be told.
        """
        if not self.access.token:
            return True
        key = client_key(session.peer)
        wait_s = self.tokens.wait_s(key)
        if wait_s is None:
            self.refused_connections += 1
            await self._send_now(
                session,
                encode(
                    "error",
                    message="too many wrong tokens from this address: another attempt is "
                    "waiting its turn, try again later",
                ),
            )
            await session.ws.close(code=CLOSE_TOKEN_WAIT, message=b"wait for your turn")
            return False
        matched: bool | None = None
        try:
            if wait_s > 0:
                await asyncio.sleep(wait_s)
            matched = self.access.token_matches(presented)
        finally:
            self.tokens.done(key, matched)
        if matched:
            return True
        self.refused_connections += 1
        await self._send_now(session, encode("error", message="wrong token: access refused"))
        await session.ws.close(code=CLOSE_BAD_TOKEN, message=b"wrong token")
        return False

    async def _welcome(self, session: _Session) -> None:
        await self._send_now(
            session,
            encode(
                "welcome",
                id=session.id,
                name=session.name,
                joints=list(self.bridge.joint_names),
                neutral=dict(self.bridge.neutral),
                urdf="urdf/pepper.urdf",
            ),
        )
        self.room.send_floor()
        self._send(session, self.room.stop_holders(session), droppable=False)

    async def _serve(self, session: _Session) -> None:
        """Act on each message until the connection ends.

        Raises:
            _PeerLeftError: the page left while it was being answered.
        """
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
            except AudioDroppedError as exc:  # a page catching up: not a fault
                await self._refuse(session, str(exc), violation=False)
            except ProtocolError as exc:
                if not await self._refuse(session, str(exc)):
                    break
            except _PeerLeftError:
                raise  # no answer can reach the page: not a failed message
            except Exception as exc:  # the boundary: a bug must not end the operator's session
                self.log("warning", f"console: {session.name!r}'s message failed: {exc!r}")
                if not await self._refuse(session, "the console could not act on that message"):
                    break

    async def _send_now(self, session: _Session, text: str) -> None:
        """Send one message to the page and wait until it is on its way.

        Every send on a connection's own path goes through here (broadcasts use :meth:`_send`).

        Raises:
            _PeerLeftError: the connection is closing or closed, or the page has not read for
                :data:`SEND_TIMEOUT_S`.
        """
        if session.ws.closed:
            raise _PeerLeftError("the connection is closed")
        try:
            await asyncio.wait_for(session.ws.send_str(text), SEND_TIMEOUT_S)
        except (ConnectionError, asyncio.TimeoutError, RuntimeError) as exc:
            raise _PeerLeftError(repr(exc)) from None

    async def _refuse(self, session: _Session, reason: str, violation: bool = True) -> bool:
        """Count a refused frame and tell the page; False when the connection is closed for it.

        Only a ``violation`` counts towards closing the connection.

        Raises:
            _PeerLeftError: the page left.
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
            await self._send_now(session, encode("error", message=reason))
        return True

    def _on_audio(self, session: _Session, data: bytes) -> None:
        received_s = time.time()
        if not session.frames.take(1.0):
            raise AudioDroppedError(
                f"more than {MAX_AUDIO_FRAMES_PER_S:g} audio frames per second: dropped"
            )
        frame = parse_audio_frame(data, self.settings.max_chunk_bytes, received_s * 1e3)
        if not self.floor.holds(session.id):
            raise ProtocolError("audio without the floor: press Talk first")
        if not session.audio.take(frame.duration_s):
            raise AudioDroppedError(
                f"audio beyond {self.settings.max_browser_audio_s_per_s:g} s per second: dropped"
            )
        self.bridge.publish_audio(frame, received_s)

    async def _on_control(self, session: _Session, control: Control) -> None:
        if control.type == "ping":
            await self._send_now(
                session, encode("pong", t=control.fields["t"], server=time.time() * 1e3)
            )
        elif control.type == "hello":
            raise ProtocolError("already identified")
        else:  # what operators may do to the robot
            self.room.on_control(session, control)

    def _send_to(self, operator: Operator, text: str) -> None:
        """Send the room's message to ``operator``'s page (not dropped), while it is connected."""
        session = self.sessions.get(operator.id)
        if session is not None:
            self._send(session, text, droppable=False)

    # --- broadcasts -----------------------------------------------------------------------------

    @property
    def watchers(self) -> int:
        """Pages sent the room's picture and sound (every identified page)."""
        return len(self.sessions)

    def offer_room(self, item: RoomItem) -> None:
        """Give every identified page ``item`` (run on the server's loop)."""
        for session in self.sessions.values():
            session.room.offer(item)
            session.room_waiting.set()

    async def _send_room(self, session: _Session) -> None:
        """Send the page its room outbox, one message at a time, until the session ends."""
        while not session.ws.closed:
            await session.room_waiting.wait()
            session.room_waiting.clear()
            while (item := session.room.take()) is not None:
                try:
                    await asyncio.wait_for(
                        session.ws.send_bytes(encode_room_message(item)), SEND_TIMEOUT_S
                    )
                except (ConnectionError, asyncio.TimeoutError, RuntimeError):
                    return  # a closing connection: its handler cleans up

    async def _send_pose(self) -> None:
        if self.sessions:
            text = self._snapshot("pose", self.bridge.pose())
            for session in list(self.sessions.values()):
                self._send(session, text)

    async def _send_status(self) -> None:
        if self.sessions:
            status = self.bridge.status()
            status["operators"] = len(self.sessions)
            status["room_watchers"] = self.watchers
            status["floor"] = self.floor.holder_name or None
            status.update(self.learn_style.status())
            text = self._snapshot("status", status)
            for session in list(self.sessions.values()):
                self._send(session, text)

    def _snapshot(self, kind: str, fields: dict[str, Any]) -> str:
        """``fields`` as a message to the pages, a value JSON cannot carry sent as null.

        Each such field is logged once (the first time), not on every tick.
        """
        ready, replaced = json_ready(fields)
        assert isinstance(ready, dict)
        new = [f"{kind}.{path}" for path in replaced if f"{kind}.{path}" not in self._unsent]
        if new:
            self._unsent.update(new)
            self.log("warning", f"console: sent as null (not a finite number or JSON): {new}")
        return encode(kind, **ready)

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


def _close_reason(text: str) -> bytes:
    """``text`` as a close frame's reason: UTF-8, cut to whole characters within the limit."""
    encoded = text.encode("utf-8", "replace")[:MAX_CLOSE_REASON_BYTES]
    return encoded.decode("utf-8", "ignore").encode("utf-8")


@web.middleware
async def _security_headers(request: web.Request, handler: Handler) -> web.StreamResponse:
    """Every answer carries the console's security headers (a WebSocket's upgrade excepted)."""
    response = await handler(request)
    if not isinstance(response, web.WebSocketResponse):
        response.headers.update(SECURITY_HEADERS)
    return response
