"""What a node process tells its supervisor and the user's terminal, through inherited descriptors.

``audio2pose run`` (:mod:`audio2pose_ros.ros.supervisor`) passes a node process the write end of
a pipe (``HEARTBEAT_FD_ENV``) on which each heartbeat writes a byte, and its own stderr
(``TERMINAL_FD_ENV``) for the lines a user must see when the node's output goes to a log file.
``STACK_DUMP_SIGNAL`` asks a node for every thread's stack before a silent node is killed.
"""

from __future__ import annotations

import contextlib
import os
import signal

# A supervisor passes the write end of a pipe in this variable: each heartbeat also writes a byte
# there. Only the supervised process holds that descriptor, so no other process can fake it.
HEARTBEAT_FD_ENV = "AUDIO2POSE_HEARTBEAT_FD"
# A supervisor that writes a node's output to a log file passes its own stderr (the user's
# terminal) in this variable: what the user must act on is written there too (to_terminal).
TERMINAL_FD_ENV = "AUDIO2POSE_TERMINAL_FD"
# A node process given this signal writes every thread's Python stack to stderr and runs on.
STACK_DUMP_SIGNAL = signal.SIGUSR1


def beat_to_supervisor() -> None:
    """Write one heartbeat byte to the supervisor's pipe (``HEARTBEAT_FD_ENV``), if there is one.

    Never blocks: a full pipe (a supervisor that does not read) or a closed one is ignored.
    """
    fd = os.environ.get(HEARTBEAT_FD_ENV, "")
    if fd.isdigit():
        try:
            os.set_blocking(int(fd), False)
            os.write(int(fd), b".")
        except OSError:
            pass


def to_terminal(line: str) -> None:
    """Write ``line`` to the user's terminal as well, when the node's output goes to a log file.

    ``audio2pose run``, ``console`` and ``demo`` with a log directory send each node's stdout and
    stderr to ``<dir>/<node>.log`` and pass their own stderr in ``TERMINAL_FD_ENV``: the lines a
    user must see (the console's address with its token, a refused configuration) are written
    there too. Without it (output on a terminal already, or ``ros2 launch``) nothing is written.
    A terminal that is gone is ignored: the line is in the log either way.
    """
    fd = os.environ.get(TERMINAL_FD_ENV, "")
    if fd.isdigit():
        with contextlib.suppress(OSError):
            os.write(int(fd), (line.rstrip("\n") + "\n").encode("utf-8", "replace"))
