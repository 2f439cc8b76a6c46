"""The console page's clock offset (web/src/clock_offset.js), run in node as the page runs it.

The page stamps each audio chunk on the console's clock, from an offset it reads off pings. A
console busy when a ping comes stamps it late and answers late: such a ping's offset is off by
half the delay. The console's voice-to-command latency is then off by as much (a median of the
pings read -7 ms for a p50 latency on a loaded machine). The offset of the ping with the
shortest round trip is believed instead.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

MODULE = Path(__file__).resolve().parents[1] / "web" / "src" / "clock_offset.js"
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(
    NODE is None, reason="node is not installed (make setup builds the console's page with it)"
)


def offsets_read(pings: list[tuple[float, float | None, float]], kept: int = 9) -> list[float]:
    """The offset the page believes after each ping (t0, server stamp, t1), in ms."""
    script = (
        f"import {{ ClockOffset }} from {json.dumps(MODULE.as_uri())};\n"
        f"const clock = new ClockOffset({kept});\n"
        "const read = [];\n"
        f"for (const [t0, server, t1] of {json.dumps(pings)}) {{\n"
        "  clock.add(t0, server, t1);\n"
        "  read.push(clock.value());\n"
        "}\n"
        "console.log(JSON.stringify(read));\n"
    )
    assert NODE is not None
    done = subprocess.run(
        [NODE, "--input-type=module", "-e", script],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return [float(v) for v in json.loads(done.stdout)]


def test_when_the_console_is_busy_for_most_pings_expect_the_offset_of_the_quick_ones():
    offset = 1000.0  # the console's clock is 1 s ahead
    pings = []
    for k in range(9):
        t0 = 2000.0 * k
        # two of three pings wait 30 ms in a busy console before it stamps and answers them
        delay = 0.0 if k % 3 == 0 else 30.0
        server = t0 + 0.5 + delay + offset
        pings.append((t0, server, t0 + 1.0 + delay))
    read = offsets_read(pings)
    assert abs(read[-1] - offset) <= 0.5  # off by at most half the quick round trip
    assert all(abs(r - offset) <= 0.5 for r in read)  # from the first ping on


def test_when_pings_leave_the_kept_window_expect_only_the_kept_ones_believed():
    # a quick ping long ago, then slow ones only: the old one is forgotten after `kept` pings
    pings = [(0.0, 1000.5, 1.0)] + [
        (2000.0 * k, 2000.0 * k + 1020.0, 2000.0 * k + 40.0) for k in range(1, 5)
    ]
    read = offsets_read(pings, kept=3)
    assert read[0] == pytest.approx(1000.0)
    assert read[-1] == pytest.approx(1000.0)  # 1020 - 40 / 2: the slow ones' own offset


def test_when_a_pong_is_broken_or_runs_backwards_expect_it_ignored():
    # null: a stamp that is no number (JSON has no NaN); then a pong that came before its ping
    read = offsets_read([(0.0, 1000.5, 1.0), (2000.0, None, 2001.0), (4000.0, 5000.0, 3990.0)])
    assert read == [pytest.approx(1000.0)] * 3
