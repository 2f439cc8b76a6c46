"""The console's front door: TCP connections counted by client address before aiohttp sees them.

:class:`Gate` is the protocol of every accepted connection. It is counted towards its client
address (:func:`~audio2pose_ros.console.access.client_key`) at once, before any TLS handshake
(:class:`Connections`): one address may hold at most :data:`CONNECTIONS_PER_ADDRESS`, all of
them together :data:`CONNECTIONS_PER_CLIENT` times ``max_clients`` more than that. Beyond a
limit the connection is closed at once: answered 503 on plain HTTP, and over TLS before its
handshake, so a refused client costs the console no handshake. An admitted connection is
handed to aiohttp (after its TLS handshake, within ``auth_timeout_s``): to the protocol that
aiohttp's public low-level server (``web.AppRunner.server``, a ``web.Server``) makes for it.
The listening socket is asyncio's own (``loop.create_server`` with the gate as protocol). The
server that owns the door (:class:`~audio2pose_ros.console.server.ConsoleServer`) is seen
through :class:`Door`.
"""

from __future__ import annotations

import asyncio
import ssl
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
# keeps its WebSocket beside them. Beyond it a connection is answered 503 and closed.
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

    When all ``limit`` are open, a new connection still gets in if some address holds more
    connections than the newcomer's: the oldest of that address's connections that is not an
    identified operator's WebSocket is closed for it. So many addresses together cannot hold
    the door shut either, and an operator's WebSocket is never closed for anyone.

    Args:
        limit: connections open at once, at most.
        per_address: connections of one client address open at once, at most.
    """

    def __init__(self, limit: int, per_address: int) -> None:
        self.limit = limit
        self.per_address = per_address
        self.total = 0
        self.by_address: dict[str, list[Gate]] = {}  # in order of acceptance; only open ones
        self.evicted = 0

    def admit(self, key: str, gate: Gate) -> str:
        """Count ``gate``, a new connection of ``key``, and return '', or return why not."""
        mine = self.by_address.get(key, [])
        if len(mine) >= self.per_address:
            return f"{len(mine)} connections open, the most one address may"
        if self.total >= self.limit:
            victim = self._victim(len(mine))
            if victim is None:
                return f"{self.total} connections open, the most allowed"
            self.evicted += 1
            victim.evict()
        self.by_address.setdefault(key, []).append(gate)
        self.total += 1
        return ""

    def _victim(self, newcomer_has: int) -> Gate | None:
        """The connection to close for a newcomer whose address holds ``newcomer_has``.

        It is the oldest connection that is not an operator's, of the address that holds the
        most, if that is more than the newcomer's (None otherwise).
        """
        most = max(
            (gates for gates in self.by_address.values() if any(not g.operator for g in gates)),
            key=len,
            default=[],
        )
        if len(most) <= newcomer_has:
            return None
        return next(g for g in most if not g.operator)

    def keep(self, transport: object) -> None:
        """The connection on ``transport`` is an identified operator's: never closed for others."""
        for gates in self.by_address.values():
            for gate in gates:
                if gate.handed is transport:
                    gate.operator = True

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
    accepted; beyond a limit it is closed at once: answered 503 on plain HTTP, and over TLS
    before its handshake, so a refused client costs the console no handshake. An admitted
    TLS connection is handed to aiohttp after its handshake (``auth_timeout_s`` at most).

    Args:
        server: the console.
    """

    def __init__(self, server: Door) -> None:
        self._door = server
        self._inner: asyncio.Protocol | None = None
        self._key: str | None = None  # counted under this address until it ends
        self._transport: asyncio.BaseTransport | None = None
        self.handed: asyncio.BaseTransport | None = None  # the transport aiohttp has
        self.operator = False  # an identified operator's WebSocket
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
            self._hand_over(transport)
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
        """To aiohttp (kept until aiohttp has the connection)."""
        if self._inner is not None:
            self._inner.data_received(data)
        else:
            self._early.append(data)

    def eof_received(self) -> bool | None:
        """To aiohttp (kept until aiohttp has the connection)."""
        if self._inner is not None:
            return self._inner.eof_received()
        self._eof = True
        return True  # keep the transport open until it is handed over

    def pause_writing(self) -> None:
        """To aiohttp."""
        if self._inner is not None:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        """To aiohttp."""
        if self._inner is not None:
            self._inner.resume_writing()
