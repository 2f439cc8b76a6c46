"""CPU time and resident memory of a node process, read from Linux's /proc.

The graph benchmark reads both to report the nodes' cost; the fault campaign and the tests read
the resident memory to show that an attack does not make a node grow. :func:`busy_loops` puts
other work on the machine beside a benchmark (``audio2pose bench --busy-loops N``).
"""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

_CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """CPU time (user + system, s) process ``pid`` has used (fields 14 and 15 of its stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / _CLOCK_TICKS_PER_S


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` (MB); NaN once the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


@contextlib.contextmanager
def busy_loops(count: int) -> Iterator[list[int]]:
    """``count`` processes that spin on the CPU (other work on the machine), for a benchmark.

    Each is a Python interpreter in an endless loop at normal priority; all are killed when the
    block ends, whatever ends it. Yields their process ids.
    """
    processes = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield [process.pid for process in processes]
    finally:
        for process in processes:
            process.kill()
        for process in processes:
            process.wait()
