"""Silence what pybullet's C code prints (its build date, URDF importer warnings).

pybullet writes straight to the process's file descriptors 1 and 2, past Python's ``sys.stdout``,
so :func:`quiet_c_output` points those descriptors at ``/dev/null`` while it loads a URDF.
Failures still surface: pybullet raises ``pybullet.error`` for them.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def quiet_c_output() -> Iterator[None]:
    """Silence C-level stdout and stderr for the duration of the context."""
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    try:
        with open(os.devnull, "wb") as devnull:
            for fd in saved:
                os.dup2(devnull.fileno(), fd)
        yield
    finally:
        libc.fflush(None)  # what C stdio buffered goes to /dev/null now, not later
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
