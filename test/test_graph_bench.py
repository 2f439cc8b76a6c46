"""``audio2pose bench --graph``: steady-state CPU, both modes, the footprint targets."""

from __future__ import annotations

import numpy as np
import pytest

from audio2pose_ros.ros.graph_bench import GraphFigures, measure_graph, report, targets


def _figures(mode: str, cpu: dict[str, float], rss: dict[str, float]) -> GraphFigures:
    return GraphFigures(
        mode=mode,
        audio_s=10.0,
        latency_raw_ms=np.full(100, 2.0),
        latency_command_ms=np.r_[np.full(98, 3.0), 12.0, 12.0],
        startup_first_command_s=1.2,
        startup_first_response_s=1.4,
        cpu_ms_per_frame=cpu,
        steady_cpu_ms_per_frame=cpu,
        rss_mb=rss,
    )


def test_when_three_processes_are_measured_expect_their_sums_against_the_three_process_targets():
    three = _figures(
        "three-process", {"a": 0.3, "b": 0.3, "c": 0.3}, {"a": 70.0, "b": 70.0, "c": 120.0}
    )
    verdicts = {t["figure"]: (t["value"], t["target"], t["met"]) for t in targets(three)}
    cpu = verdicts["steady CPU of the node processes per 10 ms frame"]
    assert cpu == (pytest.approx(0.9), 1.0, True)
    assert verdicts["resident memory of the node processes"] == (260.0, 250.0, False)
    assert verdicts["first command after start"] == (1.2, 1.5, True)
    latency = verdicts["latency audio -> /joint_angles p99"]
    assert latency[0] == pytest.approx(12.0)
    assert latency[2] is False


def test_when_one_process_is_measured_expect_the_single_process_targets():
    single = _figures("single-process", {"audio2pose_nodes": 0.6}, {"audio2pose_nodes": 140.0})
    verdicts = {t["figure"]: (t["target"], t["met"]) for t in targets(single)}
    assert verdicts["steady CPU of the node processes per 10 ms frame"] == (0.5, False)
    assert verdicts["resident memory of the node processes"] == (150.0, True)


@pytest.mark.ros
@pytest.mark.slow
def test_when_the_single_process_graph_is_benched_expect_steady_cpu_and_targets(
    speech: np.ndarray,
) -> None:
    figures = report(measure_graph(speech, duration_s=3.0, single_process=True))
    assert figures["mode"] == "single-process"
    assert set(figures["steady_cpu_ms_per_frame"]) == {"audio2pose_nodes"}
    assert 0.0 < figures["steady_cpu_ms_per_frame"]["audio2pose_nodes"] < 10.0
    assert figures["latency_audio_to_raw_pose"]["n"] >= 250
    assert len(figures["targets"]) == 4


def _console_figures(lost: int) -> dict:
    latency = {"n": 1440, "p50_ms": 11.0, "p99_ms": 25.0}
    return {
        "audio_s": 30.0,
        "chunks": 1500,
        "chunks_lost": lost,
        "ambiguous_pairs": 3,
        "latency_browser_to_joint_angles": latency,
        "motion_lag_behind_sound": {"n": 0},
        "console_live_estimate_ms": {},
        "console_node_cpu_ms_per_audio_s": 90.0,
        "console_node_cpu_percent": 9.0,
        "console_node_rss_mb": 90.0,
    }


@pytest.mark.parametrize("lost", [0, 7])
def test_when_console_chunks_were_paired_expect_no_claim_that_none_matched(capsys, lost):
    from audio2pose_ros.cli.main import _print_console

    _print_console(_console_figures(lost))
    out = capsys.readouterr().out
    assert "p50 / p99: 11.0 / 25.0 ms" in out
    assert "no command matched" not in out
    assert ("7 of 1500 chunks never reached audio/audio" in out) == (lost == 7)
