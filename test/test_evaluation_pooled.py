"""Measures pooled over a sampler's samples; the model card's targets for the arms."""

import math

import numpy as np

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.learning import metrics
from audio2pose_ros.learning.model_card import SourceReport, source_checks
from audio2pose_ros.learning.quality import (
    PROSODY_RULE,
    REAL_FLOOR,
    STATIC,
    GroupRow,
    QualityEvaluation,
    quality_evaluation,
)
from audio2pose_ros.learning.sampler_selection import SamplingChoice


def test_when_adding_two_samples_segments_expect_summed_counts_and_moments():
    rng = np.random.default_rng(0)
    speech = np.ones(300, bool)
    a, b = (np.cumsum(rng.normal(0, 0.01, (300, 2)), axis=0) for _ in range(2))
    known = np.ones((300, 2), bool)
    one, two = (metrics.segment_statistics(m, known, speech, 100.0) for m in (a, b))
    both = metrics.sum_segments([one, two])
    np.testing.assert_array_equal(both.speed_counts, one.speed_counts + two.speed_counts)
    np.testing.assert_allclose(both.moments, one.moments + two.moments)


def test_when_a_sampler_gives_several_samples_expect_the_measures_to_pool_them(robot):
    rng = np.random.default_rng(1)
    head = robot.group_mask("head")
    audio = (0.3 * rng.standard_normal(48000)).astype(np.float32)
    n = 1 + (audio.size - 400) // 160
    angles = np.tile(robot.neutral_rad, (n, 1))
    angles[:, head] += 0.1 * np.sin(np.linspace(0, 12, n))[:, None]
    mask = np.zeros(angles.shape, bool)
    mask[:, head] = True
    clip = Clip(ClipInfo("c", "s", "x", "CC0-1.0", "test"), audio, angles, mask)
    still = np.tile(robot.neutral_rad, (n, 1))
    result = quality_evaluation([clip], {"m": {"c": [still, angles.copy()]}}, robot, n_resamples=5)
    row = next(r for r in result.rows if r.method == "m")
    # before: only the first (still) sample was measured, std ratio 0; now both, pooled
    assert 0.6 < row.measures["std ratio"][0] < 0.8  # sqrt(1/2) of the real spread
    assert row.rmse_deg > 1.0  # pointwise measures: still those of the first sample


def row(method, group, **values):
    measures = {k: (math.nan,) * 3 for k in ("H speed", "H accel", "std ratio")}
    measures |= {"speech/pause speed": (math.nan,) * 3}
    measures |= {k.replace("_", " "): v for k, v in values.items()}
    return GroupRow(method, group, measures, math.nan, math.nan, math.nan)


def test_when_listing_the_arm_goals_expect_size_and_the_static_and_rule_baselines():
    model = "live_groups (shipped)"
    arms = QualityEvaluation(
        [
            row(STATIC, "arms", H_speed=(0.7, 0.6, 0.8), H_accel=(0.5, 0.4, 0.6)),
            row(PROSODY_RULE, "arms", H_speed=(0.3, 0.25, 0.35), H_accel=(0.2, 0.15, 0.3)),
            row(
                model,
                "arms",
                H_speed=(0.2, 0.18, 0.24),
                H_accel=(0.17, 0.15, 0.2),
                std_ratio=(0.5, 0.4, 0.6),
            ),
        ],
        {},
        20.0,
        0.0,
        floors=[row(REAL_FLOOR, "arms", H_speed=(0.1, 0.05, 0.15))],
    )
    report = SourceReport("lecture", "arms and hip", [], arms, SamplingChoice({}, (), ()))
    lines = [" | ".join(map(str, check)) for check in source_checks(report)]
    assert "arms | std ratio | 0.7 to 1.4 | 0.50 [0.40, 0.60] | False" in lines
    assert any("H speed | below the static pose" in x and x.endswith("| True") for x in lines)
    assert any("H speed | below the prosody rule" in x and x.endswith("| True") for x in lines)
    # 0.17 is not below the rule's interval [0.15, 0.30]: not clearly better
    assert any("H accel | below the prosody rule" in x and x.endswith("False") for x in lines)
    assert any("H speed | <= 0.15" in x and x.endswith("False") for x in lines)


def test_when_checking_beats_expect_the_real_motions_own_margin_beside_the_models():
    from dataclasses import replace

    from audio2pose_ros.learning.model_card import _beat_check

    model = replace(row("m", "head"), realism={"BC": 0.866, "BC shuffled": 0.829})
    real = replace(row(REAL_FLOOR, "head"), realism={"BC": 0.852, "BC shuffled": 0.842})
    near, above = _beat_check(model, real)
    assert near[-1] is True  # 0.014 from real
    assert above[3] == "0.866 (shuffled 0.829; real 0.852, shuffled 0.842)"
    assert above[-1] is True  # 0.037 above shuffled
    close = replace(model, realism={"BC": 0.85, "BC shuffled": 0.84})
    assert _beat_check(close, real)[1][-1] is False  # 0.01 above: not clearly


def test_when_checking_percentiles_expect_those_within_25_percent_of_real_counted():
    from dataclasses import replace

    from audio2pose_ros.learning.model_card import _percentile_check

    speed, accel = np.array([[0.1, 0.4, 1.0], [0.1, 0.5, 1.4]]), np.full((2, 3), 5.0)
    real = replace(row(REAL_FLOOR, "head"), percentiles=(speed, accel))
    near = replace(row("m", "head"), percentiles=(speed * 1.2, accel * 0.8))
    far = replace(row("m", "head"), percentiles=(speed * [[1.0, 1.3, 1.0]] * [[1], [1]], accel))
    names = ["HeadPitch", "HeadYaw"]
    assert _percentile_check(near, real, names)[3:] == (
        "12 of 12 (model / real 0.80 to 1.20)",
        True,
    )
    assert _percentile_check(far, real, names)[3:] == (
        "10 of 12 (model / real 1.00 to 1.30)",
        False,
    )
    assert _percentile_check(row("m", "head"), real, names)[3:] == ("-", False)  # no percentiles
