"""The console's front door: TCP connections counted by client address before aiohttp sees them.

:class:`Gate` is the protocol of every accepted connection. It is counted towards its client
address (:func:`~audio2pose_ros.console.access.client_key`) at once, before any TLS handshake
(:class:`Connections`): one address may hold at most :data:`CONNECTIONS_PER_ADDRESS`, all of
them together :data:`CONNECTIONS_PER_CLIENT` times ``max_clients`` more than that. Beyond a
limit a connection that has made no request yet is closed to make room (a hog's, reopened or
not, never a page's request, WebSocket or operator); only when none waits is the newcomer
closed at once: answered 503 on plain HTTP, and over TLS before its handshake, so a refused
client costs the console no handshake. An admitted connection is
handed to aiohttp (after its TLS handshake, within ``auth_timeout_s``): to the protocol that
aiohttp's public low-level server (``web.AppRunner.server``, a ``web.Server``) makes for it.
The listening socket is asyncio's own (``loop.create_server`` with the gate as protocol). The
server that owns the door (:class:`~audio2pose_ros.console.server.ConsoleServer`) is seen
through :class:`Door`.
"""

from __future__ import annotations

import asyncio
import ssl
from collections.abc import Callable
from typing import Protocol

from audio2pose_ros.console.access import client_key

__all__ = [
    "BUSY_RESPONSE",
    "CONNECTIONS_PER_ADDRESS",
    "CONNECTIONS_PER_CLIENT",
    "Connections",
    "Door",
    "Gate",
]

# Open TCP connections at most, per max_clients: a browser loads the page over up to 6, and
# keeps its WebSocket beside them. Beyond it a waiting connection is closed for a newcomer.
CONNECTIONS_PER_CLIENT = 8
# Open TCP connections of one client address at most: two browsers' worth (two operators behind
# one address). The total limit is this more than CONNECTIONS_PER_CLIENT * max_clients.
CONNECTIONS_PER_ADDRESS = 2 * CONNECTIONS_PER_CLIENT
BUSY_RESPONSE = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
)


class Door(Protocol):
    """What a :class:`Gate` needs from the server that owns it (called in its asyncio loop)."""

    tls: ssl.SSLContext | None  # None: plain HTTP
    handshake_timeout_s: float

    def admit(self, key: str, gate: Gate) -> bool:
        """Whether ``gate``, a new connection of client address ``key``, may open (counted)."""

    def lost(self, key: str, gate: Gate) -> None:
        """``gate``, an admitted connection of ``key``, has ended: it stops counting."""

    def http_protocol(self) -> asyncio.Protocol:
        """Aiohttp's protocol for an admitted connection."""


class Connections:
    """The TCP connections open at once, by client address, from acceptance until they end.

    A connection is *waiting* until aiohttp starts to handle a request on it (:meth:`requested`):
    it has sent nothing (a browser's speculative preconnect, or a hog), or only part of a
    request. Only a waiting connection is ever closed for a newcomer, and only when the newcomer
    finds no place: its address holding ``per_address`` (then one of that address's waiting
    connections goes) or all ``limit`` open (then one of any address). The one that goes is the
    oldest waiting connection of the address holding the most waiting ones (the newcomer, the
    newest, is about to send its request). A newcomer is refused only when every connection
    that could make room serves a request, a WebSocket or an operator. So connections that wait
    for nothing, even reopened the moment they are closed, cannot keep a way in shut; a page
    that makes its requests is never closed for anyone, nor an operator's WebSocket; and no
    connection is closed while there is room.

    Args:
        limit: connections open at once, at most.
        per_address: connections of one client address open at once, at most.
        on_evict: told the address of each connection closed for a newcomer.
    """

    def __init__(
        self, limit: int, per_address: int, on_evict: Callable[[str], None] = lambda _: None
    ) -> None:
        self.limit = limit
        self.per_address = per_address
        self.on_evict = on_evict
        self.total = 0
        self.by_address: dict[str, list[Gate]] = {}  # in order of acceptance; only open ones
        self.evicted = 0

    def admit(self, key: str, gate: Gate) -> str:
        """Count ``gate``, a new connection of ``key``, and return '', or return why not.

        A waiting connection may be closed to make room for it (counted in ``evicted``, and
        its address passed to ``on_evict``).
        """
        mine = self.by_address.get(key, [])
        if len(mine) >= self.per_address:
            if not self._make_room({key: mine}):
                return f"{len(mine)} connections open, the most one address may, all in use"
        elif self.total >= self.limit and not self._make_room(self.by_address):
            return f"{self.total} connections open, the most allowed, all in use"
        self.by_address.setdefault(key, []).append(gate)
        self.total += 1
        return ""

    def _make_room(self, among: dict[str, list[Gate]]) -> bool:
        """Close the waiting connection that goes first ``among`` these addresses' connections.

        Returns:
            False if none of them waits (nothing closed).
        """
        victims = []
        for key, gates in among.items():
            waiting = [gate for gate in gates if gate.waiting]  # in order of acceptance
            victims += [(-len(waiting), age, key, g) for age, g in enumerate(waiting)]
        if not victims:
            return False
        *_, key, victim = min(victims, key=lambda v: v[:2])
        self.evicted += 1
        self.on_evict(key)
        victim.evict()
        return True

    def requested(self, transport: object) -> None:
        """A request on ``transport`` is being handled: its connection no longer waits."""
        for gates in self.by_address.values():
            for gate in gates:
                if gate.handed is transport:
                    gate.waiting = False
                    return

    def close_all(self) -> None:
        """Close every connection still counted (the console stops)."""
        for gates in list(self.by_address.values()):
            for gate in list(gates):
                gate.evict()

    def lost(self, key: str, gate: Gate) -> None:
        """``gate``, a connection of ``key``, has ended (or been closed for a newcomer)."""
        gates = self.by_address.get(key, [])
        if gate in gates:
            gates.remove(gate)
            self.total -= 1
        if not gates:
            self.by_address.pop(key, None)


class Gate(asyncio.Protocol):
    """One TCP connection from its acceptance: admitted by its address, then given to aiohttp.

    The connection counts towards its address's limit (:class:`Connections`) as soon as it is
    accepted; when it finds no place and none can be made, it is closed at once: answered 503
    on plain HTTP, and over TLS before its handshake, so a refused client costs the console no
    handshake. An admitted connection is handed to aiohttp at its first byte (a TLS one at its
    first byte after its handshake, which takes ``auth_timeout_s`` at most): aiohttp's clock
    for the request starts there, and a connection that has sent nothing stays at the door,
    however long (a browser's speculative connection). Until aiohttp handles a request on it,
    it *waits* and may be closed for a newcomer (:meth:`evict`).

    Args:
        server: the console.
    """

    def __init__(self, server: Door) -> None:
        self._door = server
        self._inner: asyncio.Protocol | None = None
        self._key: str | None = None  # counted under this address until it ends
        self._transport: asyncio.BaseTransport | None = None
        self._ready: asyncio.BaseTransport | None = None  # for aiohttp, at the first byte
        self.handed: asyncio.BaseTransport | None = None  # the transport aiohttp has
        self.waiting = True  # no request handled on it yet: it may be closed for a newcomer
        self._early: list[bytes] = []  # application data before aiohttp has the connection
        self._eof = False
        self._handshake: asyncio.Task[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Admit or refuse; start TLS or hand it over."""
        peer = transport.get_extra_info("peername")
        key = client_key(str(peer[0]) if isinstance(peer, tuple) and peer else "?")
        tls = self._door.tls
        self._transport = transport
        if not self._door.admit(key, self):
            if tls is None and isinstance(transport, asyncio.WriteTransport):
                transport.write(BUSY_RESPONSE)
            transport.close()
            return
        self._key = key
        if tls is None:
            self._ready = transport  # handed over at its first byte
            return
        assert isinstance(transport, asyncio.Transport)
        transport.pause_reading()  # its first bytes are the handshake's, not ours to read
        self._handshake = asyncio.get_running_loop().create_task(self._start_tls(transport, tls))

    async def _start_tls(self, transport: asyncio.Transport, context: ssl.SSLContext) -> None:
        """The TLS handshake, then aiohttp.

        asyncio tells the protocol nothing of a connection lost, failed or timed out during
        its handshake (``start_tls`` raises or returns None): it stops counting here.
        """
        secure: asyncio.BaseTransport | None = None
        try:
            secure = await asyncio.get_running_loop().start_tls(
                transport,
                self,
                context,
                server_side=True,
                ssl_handshake_timeout=self._door.handshake_timeout_s,
            )
        except (OSError, ssl.SSLError, asyncio.TimeoutError, ConnectionError, RuntimeError):
            transport.close()  # a failed or late handshake ends this connection only
        finally:
            if secure is None or secure.is_closing():
                self._forget()
        if secure is not None and not secure.is_closing():
            self._ready = secure  # handed over at its first byte (now if it has come)
            if self._early or self._eof:
                self._hand_over(secure)

    def _forget(self) -> None:
        """Stop counting this connection (once)."""
        if self._key is not None:
            self._door.lost(self._key, self)
            self._key = None

    def evict(self) -> None:
        """Close this connection for a newcomer (it stops counting at once)."""
        self._forget()
        if isinstance(self._transport, asyncio.WriteTransport):
            self._transport.abort()

    def _hand_over(self, transport: asyncio.BaseTransport) -> None:
        self.handed = transport
        inner = self._inner = self._door.http_protocol()
        inner.connection_made(transport)
        for data in self._early:
            inner.data_received(data)
        self._early.clear()
        if self._eof and not inner.eof_received():
            transport.close()

    def connection_lost(self, exc: Exception | None) -> None:
        """Stop counting it, then tell aiohttp."""
        self._forget()
        if self._handshake is not None and not self._handshake.done():
            self._handshake.cancel()
        if self._inner is not None:
            self._inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        """To aiohttp: the first byte hands the connection over (kept until then)."""
        if self._inner is not None:
            self._inner.data_received(data)
            return
        self._early.append(data)
        if self._ready is not None:
            self._hand_over(self._ready)

    def eof_received(self) -> bool | None:
        """To aiohttp; a connection that ends without a byte is closed here."""
        if self._inner is not None:
            return self._inner.eof_received()
        if self._ready is not None:
            return False  # it said nothing: nothing to hand over
        self._eof = True
        return True  # its handshake's end is still being read: kept until it is handed over

    def pause_writing(self) -> None:
        """To aiohttp."""
        if self._inner is not None:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        """To aiohttp."""
        if self._inner is not None:
            self._inner.resume_writing()
