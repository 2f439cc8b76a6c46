"""The fault campaign (`audio2pose faults`) against the live graph: every case must pass.

Each case is an attack observed on the live graph: bad poses, stamps and sizes, head
inputs, stop behaviours, run-time parameters, a killed, a stopped and a restarted filter, audio
format bombs. The campaign runs real node processes over real DDS.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from audio2pose_ros.ros.tools.fault_campaign import cases, run_campaign, table
from audio2pose_ros.ros.tools.fault_harness import Case, Commands, Outcome


def test_commands_measure_deviation_gaps_and_non_finite_commands():
    commands = Commands(
        np.array([0.0, 0.01, 0.25]), np.array([[0.0, 1.0], [0.05, 1.0], [0.0, 0.9]])
    )
    assert commands.worst_deviation(np.array([0.0, 1.0])) == pytest.approx(0.1)
    assert commands.longest_gap_s() == pytest.approx(0.24)
    broken = Commands(np.array([0.0]), np.array([[math.nan, 1.0]]))
    assert broken.worst_deviation(np.array([0.0, 1.0])) == math.inf


def test_table_marks_failures():
    rows = [
        (Case("a", "stay", lambda c: Outcome("", True)), Outcome("stayed", True, 0.0)),
        (Case("b", "stay", lambda c: Outcome("", True)), Outcome("moved", False, 0.5)),
    ]
    text = table(rows)
    assert "| a | stay | stayed | pass | 0.000 |" in text
    assert "| b | stay | moved | FAIL | 0.500 |" in text


@pytest.mark.long  # about 3 min of real-time cases: make test-long
@pytest.mark.slow
@pytest.mark.ros
def test_every_fault_case_passes_against_the_live_graph(tmp_path):
    rows = run_campaign(cases(), log_dir=tmp_path / "logs", progress=lambda line: None)
    print(table(rows))
    failed = [f"{case.name}: {outcome.did}" for case, outcome in rows if not outcome.passed]
    assert not failed, "\n".join(failed)
    assert len(rows) == len(cases())
