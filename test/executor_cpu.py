"""The CPU time a node process's executor thread uses, read while a test listens to the node.

The flood tests judge a node's timers by this clock rather than the wall clock: once a paced
timer's output falls due (DiagnosedNode's PacedTimer), the executor thread, which runs every
callback, runs at most a quarter period and the one callback running then before the output.
A machine that is slow or busy gives the node less CPU time, not more of it while an output is
due; a node whose timers wait behind a backlog of messages spends its CPU time on them instead.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

# A paced timer's output falls due at the latest one and a half periods after the one before
# (one period, or half a period more when a late executor event ran it early).
DUE_WITHIN_PERIODS = 1.5
# While a heartbeat (0.5 s) is due, at most a quarter period and a callback, here under floods at
# most 0.09 s; starving nodes used 0.1-3.5 s: room for callbacks several times slower than here.
BEAT_LATE_CPU_S = 0.25


def executor_cpu_s(pid: int) -> float:
    """CPU time (s) process ``pid``'s main thread has used: where its executor runs callbacks.

    The scheduler's own figure, in nanoseconds (schedstat); the user and system times of the
    thread's stat, counted in clock ticks (10 ms), where the kernel has no schedstat.
    """
    task = Path(f"/proc/{pid}/task/{pid}")
    try:
        return int((task / "schedstat").read_text().split()[0]) * 1e-9
    except FileNotFoundError:
        fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class ExecutorCpu:
    """Readings of a node process's executor CPU time, each between two wall-clock times.

    Read it as often as the test can while the node works (each read takes microseconds); the
    stamps the node puts on its outputs are on the same wall clock.
    """

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.readings: list[tuple[float, float, float]] = []  # (began, CPU s, ended)

    def read(self) -> None:
        began = time.time()
        cpu_s = executor_cpu_s(self.pid)
        self.readings.append((began, cpu_s, time.time()))

    @property
    def start_s(self) -> float:
        return self.readings[0][0]

    @property
    def end_s(self) -> float:
        return self.readings[-1][2]

    def total_s(self) -> float:
        """CPU time from the first reading to the last."""
        return self.readings[-1][1] - self.readings[0][1]

    def most_after_due(self, stamps: list[float], period_s: float) -> float:
        """The most CPU time the executor surely used after an output fell due, before it came.

        ``stamps``: the outputs of one timer of period ``period_s``, by the node's stamps. An
        output falls due at the latest DUE_WITHIN_PERIODS periods after the one before; counted
        from the first reading begun after that to the last one ended before the output came
        (after the last output: to the last reading).
        """
        began, cpu_s, ended = (np.array(column) for column in zip(*self.readings, strict=True))
        times = sorted(stamps)
        most = 0.0
        for previous, output in zip(times, [*times[1:], np.inf], strict=True):
            first = np.searchsorted(began, previous + DUE_WITHIN_PERIODS * period_s)
            last = np.searchsorted(ended, output, side="right") - 1
            if first < last:
                most = max(most, float(cpu_s[last] - cpu_s[first]))
        return most
