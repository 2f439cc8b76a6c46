"""``bench --busy-loops``: the other work beside a benchmark spins, and is gone afterwards."""

from __future__ import annotations

import os
import time

import pytest

from audio2pose_ros.ros.tools.process_stats import busy_loops, cpu_s


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a killed child that is not yet reaped is a zombie: not running
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().rsplit(")", 1)[1].split()[0] != "Z"


def test_when_busy_loops_run_expect_them_spinning_then_gone():
    with busy_loops(2) as pids:
        assert len(pids) == 2
        start = [cpu_s(pid) for pid in pids]
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not all(
            cpu_s(pid) > s + 0.05 for pid, s in zip(pids, start, strict=True)
        ):
            time.sleep(0.05)
        assert all(cpu_s(pid) > s + 0.05 for pid, s in zip(pids, start, strict=True))
    assert not any(_alive(pid) for pid in pids)


def test_when_the_benchmark_fails_expect_the_loops_gone_too():
    with pytest.raises(RuntimeError), busy_loops(1) as pids:
        raise RuntimeError("the benchmark failed")
    assert not any(_alive(pid) for pid in pids)


def test_when_no_loops_asked_expect_none():
    with busy_loops(0) as pids:
        assert pids == []
