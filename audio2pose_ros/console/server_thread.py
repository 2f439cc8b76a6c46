"""The console's server in its own thread and asyncio loop, next to rclpy's executor."""

from __future__ import annotations

import asyncio
import contextlib
import threading

from audio2pose_ros.console.server import ConsoleServer
from audio2pose_ros.errors import ConfigurationError

__all__ = ["ServerThread"]


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
