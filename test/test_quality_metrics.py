"""Distribution measures per joint group, with bootstrap intervals and baselines."""

import numpy as np
import pytest

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.learning import metrics
from audio2pose_ros.learning.quality import MISMATCHED, STATIC, quality_evaluation

RATE = 100.0


def speech_audio(pattern_s, seed=0):
    """16 kHz audio: noise at speech level where the pattern says True, near silence else."""
    rng = np.random.default_rng(seed)
    parts = [
        (0.3 if speech else 0.0003) * rng.standard_normal(int(seconds * 16000))
        for seconds, speech in pattern_s
    ]
    return np.concatenate(parts).astype(np.float32)


def frames_of(audio):
    return 1 + (audio.size - 400) // 160


def test_when_pauses_are_short_or_long_expect_only_those_of_a_second_or_more_as_silence():
    audio = speech_audio([(1.5, True), (1.2, False), (0.5, True), (0.4, False), (1.0, True)])
    speech = metrics.energy_vad(audio, frames_of(audio))
    silence = metrics.long_silences(speech, RATE)
    assert speech[:140].all()
    assert speech[-90:].all()
    assert silence[160:260].all()  # inside the 1.2 s pause
    assert not silence[280:].any()  # the 0.4 s pause is speech time, not silence
    assert 100 <= silence.sum() <= 125


def segments(theta, speech=None):
    theta = np.asarray(theta, dtype=float)
    speech = np.ones(theta.shape[0], bool) if speech is None else speech
    return metrics.segment_statistics(theta, np.ones(theta.shape, bool), speech, RATE)


def test_when_one_joint_matches_and_one_is_still_expect_hellinger_averaged_over_joints():
    rng = np.random.default_rng(0)
    moving = np.cumsum(rng.normal(0, 0.01, (500, 2)), axis=0)
    generated = moving.copy()
    generated[:, 1] = 0.0  # second joint never moves: all its speeds in the first bin
    real_seg, gen_seg = segments(moving), segments(generated)
    one = metrics.hellinger(
        np.histogram(np.abs(np.diff(moving[:, 1])) * RATE, metrics.SPEED_BINS_RAD_S)[0],
        np.histogram(np.zeros(499), metrics.SPEED_BINS_RAD_S)[0],
    )
    values = metrics.distribution_measures(real_seg, gen_seg)
    assert values["H speed"] == pytest.approx(one / 2, rel=0.05)
    same = metrics.distribution_measures(real_seg, segments(moving))
    assert same["H speed"] == pytest.approx(0.0, abs=1e-9)
    assert same["std ratio"] == pytest.approx(1.0)
    assert values["std ratio"] == pytest.approx(0.5)  # joint 1: ratio 1, joint 2: ratio 0


def test_when_motion_stops_in_long_silences_expect_a_high_speech_to_silence_speed_ratio():
    audio = speech_audio([(2.0, True), (2.0, False), (2.0, True)])
    n = frames_of(audio)
    speech = metrics.energy_vad(audio, n)
    t = np.arange(n) / RATE
    wave = 0.2 * np.sin(2 * np.pi * 1.0 * t)
    resting = np.where(speech, wave, 0.0)[:, None]
    steady = wave[:, None]
    real = segments(steady, speech)
    assert (
        metrics.distribution_measures(real, segments(resting, speech))["speech/silence speed"] > 10
    )
    assert metrics.distribution_measures(real, segments(steady, speech))[
        "speech/silence speed"
    ] == pytest.approx(1.0, rel=0.1)


def test_when_bootstrapping_expect_an_interval_around_the_value_that_narrows_with_more_data():
    rng = np.random.default_rng(1)
    widths = []
    for seconds in (4, 40):
        real = np.cumsum(rng.normal(0, 0.01, (int(seconds * RATE), 1)), axis=0)
        gen = np.cumsum(rng.normal(0, 0.02, real.shape), axis=0)
        value, low, high = metrics.bootstrap_measures(segments(real), segments(gen), 100)["H speed"]
        assert low <= value <= high
        widths.append(high - low)
    assert widths[1] < widths[0]


def clip(clip_id, speaker, audio, angles, mask):
    return Clip(ClipInfo(clip_id, speaker, "synthetic", "CC0-1.0", "test"), audio, angles, mask)


def test_when_evaluating_groups_expect_baselines_rows_only_for_observed_groups_and_a_figure(
    robot, tmp_path
):
    rng = np.random.default_rng(2)
    head = robot.group_mask("head")
    clips, predictions = [], {"copy": {}, "still": {}}
    for k in range(3):
        audio = speech_audio([(1.5, True), (1.5, False), (1.0, True)], seed=k)
        n = frames_of(audio)
        angles = np.tile(robot.neutral_rad, (n, 1))
        angles[:, head] += np.cumsum(rng.normal(0, 0.004, (n, head.sum())), axis=0)
        mask = np.zeros(angles.shape, bool)
        mask[:, head] = True  # only the head is labelled, as in talking-head clips
        clips.append(clip(f"c{k}", f"s{k}", audio, angles, mask))
        noisy = angles + rng.normal(0, 1e-4, angles.shape)
        predictions["copy"][f"c{k}"] = [noisy, noisy + 0.01]
        predictions["still"][f"c{k}"] = [np.tile(robot.neutral_rad, (n, 1))]
    result = quality_evaluation(clips, predictions, robot, tmp_path / "hist.png", n_resamples=50)
    rows = {(r.group, r.method): r for r in result.rows}
    assert {g for g, _ in rows} == {"head"}
    assert set(m for _, m in rows) == {STATIC, MISMATCHED, "copy", "still"}
    static, copy = rows[("head", STATIC)], rows[("head", "copy")]
    assert static.measures["H speed"][0] > 0.5
    assert copy.measures["H speed"][0] < 0.2
    assert rows[("head", MISMATCHED)].measures["H speed"][0] < static.measures["H speed"][0]
    assert copy.diversity_deg == pytest.approx(np.degrees(0.01), rel=1e-3)
    assert np.isnan(rows[("head", "still")].diversity_deg)
    assert copy.lcca > 0.9
    assert copy.rmse_deg < 0.1
    assert result.silence_seconds > 2.0
    assert (tmp_path / "hist.png").stat().st_size > 1000
    assert "mismatched real motion" in result.table()


def test_when_pairing_mismatched_clips_expect_a_permutation_across_speakers():
    from audio2pose_ros.learning.quality import mismatched_order

    speakers = ["obama"] * 5 + [f"grid{k}" for k in range(8)]
    order = mismatched_order(speakers)
    assert sorted(order) == list(range(13))  # every clip's motion used once
    assert all(speakers[i] != speakers[j] for i, j in enumerate(order))


def test_when_a_pause_is_inserted_expect_a_silence_of_a_second_or_more_in_the_middle():
    from audio2pose_ros.learning.quality import PAUSE_S, with_pause

    audio = speech_audio([(2.0, True)])
    paused = with_pause(audio)
    assert paused.size == audio.size + int(PAUSE_S * 16000)
    silence = metrics.long_silences(metrics.energy_vad(paused, frames_of(paused)), RATE)
    assert silence[110:230].all()
    assert 1.0 <= silence.sum() / RATE <= PAUSE_S
