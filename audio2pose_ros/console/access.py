"""Who may use the console: loopback or network binds, tokens, Host and Origin checks.

Safe by default:

- The console listens on 127.0.0.1 unless ``host`` says otherwise. There, no token is needed
  (only this machine's users reach it), unless one is set.
- Any other bind needs HTTPS (``certfile`` and ``keyfile``: browsers give the microphone to a
  page only on localhost or HTTPS, and the token must not cross the network in clear) and a
  token: the one set with ``token`` (16 characters at least) or a random one made at start and
  printed with the address. Tokens are compared in constant time (:func:`token_matches`).
- A WebSocket is accepted only from the console's own page: its ``Origin`` must be the address
  the browser asked for (``Host``), so another web site open in the operator's browser cannot
  drive the robot; on a loopback bind ``Host`` must also be a loopback name, which defeats DNS
  rebinding (a foreign name resolved to 127.0.0.1).
- Wrong tokens are slowed per client address (:class:`TokenThrottle`): after each wrong token,
  that address waits twice as long before its next token is checked (from
  :data:`TOKEN_BASE_DELAY_S` up to :data:`TOKEN_MAX_DELAY_S`), one attempt at a time; the
  wrong tokens are logged in summaries (:meth:`TokenThrottle.summary`), not one line each. A
  client address is its IPv4 address or its IPv6 /64 network (:func:`client_key`): one host
  can have a whole /64 to itself.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.errors import ConfigurationError

__all__ = [
    "MIN_TOKEN_CHARS",
    "TOKEN_BASE_DELAY_S",
    "TOKEN_MAX_DELAY_S",
    "Access",
    "TokenThrottle",
    "client_key",
    "is_loopback",
    "request_problem",
    "resolve_access",
]

MIN_TOKEN_CHARS = 16  # a network token shorter than this is refused
TOKEN_BYTES = 24  # a generated token: 24 random bytes, 32 URL-safe characters
LOOPBACK_NAMES = ("localhost",)
TOKEN_BASE_DELAY_S = 0.5  # the wait before the token after an address's first wrong one ...
TOKEN_MAX_DELAY_S = 30.0  # ... doubling with each further wrong one, up to this
TOKEN_FORGET_S = 600.0  # an address's wrong tokens are forgotten this long after its last one
MAX_TOKEN_ADDRESSES = 1024  # addresses with wrong tokens remembered at once, at most


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a bind address or a Host header's name) is this machine only."""
    name = host.strip().strip("[]").lower()
    if name in LOOPBACK_NAMES or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class Access:
    """The console's resolved bind and access rules.

    Attributes:
        host: the bind address.
        port: the TCP port (0 until the server has bound one).
        token: the token a page must present, or '' when none is needed.
        certfile: PEM certificate ('' = plain HTTP).
        keyfile: PEM private key ('' = plain HTTP).
        loopback: the bind reaches this machine only.
    """

    host: str
    port: int
    token: str
    certfile: str
    keyfile: str
    loopback: bool

    @property
    def scheme(self) -> str:
        """``https`` with a certificate, else ``http``."""
        return "https" if self.certfile else "http"

    def url(self, port: int | None = None) -> str:
        """The address to open in a browser, with the token in the fragment (never sent)."""
        host = self.host
        if host in ("0.0.0.0", "::", ""):
            host = socket.getfqdn()
        elif ":" in host:
            host = f"[{host}]"
        address = f"{self.scheme}://{host}:{self.port if port is None else port}/"
        return address + (f"#token={self.token}" if self.token else "")

    def token_matches(self, presented: str) -> bool:
        """Whether ``presented`` is the token (always True when none is needed)."""
        return not self.token or token_matches(self.token, presented)


def token_matches(expected: str, presented: str) -> bool:
    """Compare tokens in constant time (the time does not tell how many characters matched)."""
    return hmac.compare_digest(expected.encode("utf-8"), presented.encode("utf-8"))


def resolve_access(
    settings: ConsoleSettings, make_token: Callable[[int], str] = secrets.token_urlsafe
) -> Access:
    """Check the bind, certificate and token settings as a whole.

    Args:
        settings: the console's settings.
        make_token: random token generator (bytes -> text), for a network bind without one.

    Returns:
        The access rules the server applies.

    Raises:
        ConfigurationError: a network bind without a certificate and key, half a certificate,
            a missing certificate file, or a network token shorter than
            :data:`MIN_TOKEN_CHARS`; the message names the parameter.
    """
    host = settings.host.strip()
    if not host:
        raise ConfigurationError("parameter host: value '' names no address")
    loopback = is_loopback(host)
    if bool(settings.certfile) != bool(settings.keyfile):
        raise ConfigurationError(
            "parameters certfile and keyfile: give both (HTTPS) or neither (plain HTTP, "
            "loopback only)"
        )
    for name in ("certfile", "keyfile"):
        path = getattr(settings, name)
        if path and not Path(path).expanduser().is_file():
            raise ConfigurationError(f"parameter {name}: {path!r} is not a readable file")
    token = settings.token
    if not loopback:
        if not settings.certfile:
            raise ConfigurationError(
                f"parameter host: value {host!r} is reachable from the network, which needs "
                "HTTPS (browsers allow the microphone only on localhost or HTTPS, and the token "
                "must not travel in clear): set certfile and keyfile (doc/console.md: On a "
                "network), or use host 127.0.0.1"
            )
        if not token:
            token = make_token(TOKEN_BYTES)
        elif len(token) < MIN_TOKEN_CHARS:
            raise ConfigurationError(
                f"parameter token: {len(token)} characters is too short for a network bind; "
                f"allowed: at least {MIN_TOKEN_CHARS} (or '' for a random one, printed at start)"
            )
    return Access(
        host=host,
        port=settings.port,
        token=token,
        certfile=str(Path(settings.certfile).expanduser()) if settings.certfile else "",
        keyfile=str(Path(settings.keyfile).expanduser()) if settings.keyfile else "",
        loopback=loopback,
    )


def request_problem(access: Access, host_header: str | None, origin: str | None) -> str:
    """Why a WebSocket request must be refused ('' when it may proceed to the token).

    Args:
        access: the console's access rules.
        host_header: the request's ``Host`` header.
        origin: the request's ``Origin`` header (browsers always send it for a WebSocket).
    """
    if not host_header:
        return "no Host header"
    host_name = urlsplit(f"//{host_header}").hostname or ""
    if access.loopback and not is_loopback(host_name):
        return f"Host {host_header!r} is not a loopback name on a loopback console"
    if not origin:
        return "no Origin header"
    expected = f"{access.scheme}://{host_header}".lower()
    if origin.strip().lower() != expected:
        return f"Origin {origin!r} is not this console ({expected})"
    return ""


def client_key(address: str) -> str:
    """The client address that connection and token limits count by.

    An IPv4 address (an IPv4-mapped IPv6 one included) is itself; an IPv6 address counts as its
    /64 network, which a single host may hold entirely. Anything else (a Unix socket's name,
    '?') is kept as it is.
    """
    try:
        ip = ipaddress.ip_address(address.split("%", 1)[0])
    except ValueError:
        return address
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        return str(ipaddress.IPv6Network((ip, 64), strict=False))
    return str(ip)


@dataclass
class _Failures:
    """One address's recent wrong tokens."""

    count: int = 0
    last_s: float = 0.0
    waiting: bool = False  # one of its attempts is waiting for its turn or being checked


@dataclass
class _Window:
    """Wrong tokens and unchecked refusals since the last summary."""

    wrong: int = 0
    unchecked: int = 0
    by_address: dict[str, int] = field(default_factory=dict)  # at most MAX_TOKEN_ADDRESSES


class TokenThrottle:
    """Slows wrong tokens per client address, with bounded memory, and sums them up for the log.

    An address with no recent wrong token is checked at once. After its ``n``-th wrong token an
    address's next token is checked only ``base_delay_s * 2 ** (n - 1)`` (at most
    ``max_delay_s``) after that wrong one, and only one attempt of that address waits or is
    checked at a time: another one meanwhile is refused unchecked. So one address, however
    many connections it opens, gets at most one guess per delay. The delay is taken before the
    check, whatever the token: how long an answer takes tells nothing about the token.

    At most ``max_addresses`` addresses are remembered; a new one beyond that first makes room
    by forgetting those whose wrong tokens are older than ``forget_s``, then the one with the
    fewest (the oldest among equals): many addresses with a wrong token each cannot wash out an
    address that has guessed many times.

    Args:
        base_delay_s: the wait after an address's first wrong token.
        max_delay_s: the longest wait.
        forget_s: an address's wrong tokens are forgotten this long after its last one.
        max_addresses: addresses remembered at once, at most.
        clock: monotonic seconds (tests pass their own).
    """

    def __init__(
        self,
        base_delay_s: float = TOKEN_BASE_DELAY_S,
        max_delay_s: float = TOKEN_MAX_DELAY_S,
        forget_s: float = TOKEN_FORGET_S,
        max_addresses: int = MAX_TOKEN_ADDRESSES,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.base_delay_s = base_delay_s
        self.max_delay_s = max_delay_s
        self.forget_s = forget_s
        self.max_addresses = max_addresses
        self._clock = clock
        self._failures: dict[str, _Failures] = {}
        self._window = _Window()
        self.wrong_tokens = 0  # since the start
        self.refused_unchecked = 0

    def delay_s(self, failures: int) -> float:
        """The wait before the next token of an address with ``failures`` recent wrong ones."""
        if failures <= 0:
            return 0.0
        return float(min(self.max_delay_s, self.base_delay_s * 2.0 ** min(failures - 1, 64)))

    def failures(self, key: str) -> int:
        """The recent wrong tokens of ``key`` remembered."""
        entry = self._failures.get(key)
        return entry.count if entry is not None else 0

    def __len__(self) -> int:
        """Addresses remembered."""
        return len(self._failures)

    def wait_s(self, key: str) -> float | None:
        """How long the attempt of ``key`` that has just come waits before its token is checked.

        Returns:
            The wait (0.0: at once), or None when an attempt of ``key`` is already waiting or
            being checked: this one is refused unchecked. Unless None, the caller must call
            :meth:`done` for this attempt, whatever becomes of it.
        """
        now = self._clock()
        entry = self._failures.get(key)
        if entry is not None and not entry.waiting and now - entry.last_s >= self.forget_s:
            del self._failures[key]
            entry = None
        if entry is None:
            return 0.0
        if entry.waiting:
            self.refused_unchecked += 1
            self._window.unchecked += 1
            return None
        entry.waiting = True
        return max(0.0, entry.last_s + self.delay_s(entry.count) - now)

    def done(self, key: str, matched: bool | None) -> None:
        """The attempt of ``key`` has ended.

        Args:
            key: the client address.
            matched: its token matched, did not, or (None) was never checked.
        """
        entry = self._failures.get(key)
        if entry is not None:
            entry.waiting = False
        if matched is not False:
            return
        if entry is None:
            entry = self._remember(key)
        entry.count += 1
        entry.last_s = self._clock()
        self.wrong_tokens += 1
        window = self._window
        window.wrong += 1
        if key in window.by_address or len(window.by_address) < self.max_addresses:
            window.by_address[key] = window.by_address.get(key, 0) + 1

    def _remember(self, key: str) -> _Failures:
        if len(self._failures) >= self.max_addresses:
            now = self._clock()
            for old in [
                k
                for k, e in self._failures.items()
                if not e.waiting and now - e.last_s >= self.forget_s
            ]:
                del self._failures[old]
        if len(self._failures) >= self.max_addresses:
            idle = [(e.count, e.last_s, k) for k, e in self._failures.items() if not e.waiting]
            if idle:
                del self._failures[min(idle)[2]]
        entry = self._failures[key] = _Failures()
        return entry

    def summary(self) -> str:
        """The wrong tokens since the last summary, in one line ('' if none); starts a new one."""
        window, self._window = self._window, _Window()
        if not window.wrong and not window.unchecked:
            return ""
        worst = sorted(window.by_address.items(), key=lambda item: -item[1])[:3]
        most = ", ".join(f"{address} {count}" for address, count in worst)
        counts = [self._failures[a].count for a in window.by_address if a in self._failures]
        longest = self.delay_s(max(counts, default=0))
        unchecked = (
            f"; {window.unchecked} attempt(s) refused unchecked while another of their address "
            "waited"
            if window.unchecked
            else ""
        )
        return (
            f"{window.wrong} wrong token(s) from {len(window.by_address)} address(es)"
            + (f" (most: {most})" if most else "")
            + unchecked
            + f"; the slowest of them now waits {longest:g} s before its next token is checked"
        )
