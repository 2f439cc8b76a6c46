"""Connections that hold the console's door: TCP connections that send nothing, each reopened
the moment the console closes it (test_console.py, test_console_browser.py)."""

from __future__ import annotations

import selectors
import socket
import threading


class Hogs:
    """``count`` TCP connections to ``port`` that send nothing, from ``sources`` in turn, each
    opened again the moment the console closes it, by a thread, until :meth:`stop`."""

    def __init__(self, port: int, sources: list[str], count: int) -> None:
        self.port = port
        self.selector = selectors.DefaultSelector()
        self.reopened = 0
        self.stopping = threading.Event()
        for i in range(count):
            self._open(sources[i % len(sources)])
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self, source: str) -> None:
        sock = socket.socket()
        sock.bind((source, 0))
        sock.connect(("127.0.0.1", self.port))
        sock.setblocking(False)
        self.selector.register(sock, selectors.EVENT_READ, source)

    def _run(self) -> None:
        while not self.stopping.is_set():
            for key, _ in self.selector.select(0.05):
                sock = key.fileobj
                assert isinstance(sock, socket.socket)
                try:
                    if sock.recv(4096):
                        continue  # a 503 before the end: read on to it
                except OSError:
                    pass
                self.selector.unregister(sock)
                sock.close()
                if not self.stopping.is_set():
                    self._open(key.data)
                    self.reopened += 1

    def stop(self) -> None:
        self.stopping.set()
        self.thread.join()
        for key in list(self.selector.get_map().values()):
            key.fileobj.close()  # type: ignore[union-attr]
