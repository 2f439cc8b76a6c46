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
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from audio2pose_ros.console.settings import ConsoleSettings
from audio2pose_ros.errors import ConfigurationError

__all__ = ["MIN_TOKEN_CHARS", "Access", "is_loopback", "request_problem", "resolve_access"]

MIN_TOKEN_CHARS = 16  # a network token shorter than this is refused
TOKEN_BYTES = 24  # a generated token: 24 random bytes, 32 URL-safe characters
LOOPBACK_NAMES = ("localhost",)


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
