"""Realism measures beyond speed histograms: windows, ratios, beats, tails, bias correction."""

import numpy as np
import pytest

from audio2pose_ros.learning import metrics, realism

RATE = 100.0


def clicks(times_s, seconds=4.0):
    """16 kHz audio: quiet noise with a loud 50 ms burst at each time."""
    rng = np.random.default_rng(0)
    audio = 0.001 * rng.standard_normal(int(seconds * 16000))
    for t in times_s:
        start = int(t * 16000)
        audio[start : start + 800] += 0.5 * rng.standard_normal(800)
    return audio.astype(np.float32)


def test_when_bursts_start_expect_onsets_at_their_starts_or_just_before():
    times = np.array([0.5, 1.3, 2.2, 3.1])
    onsets = realism.audio_onsets(clicks(times))
    assert len(onsets) == len(times)
    # backtracked to the energy minimum before the rise (within the 25 ms window's reach)
    assert np.all((onsets <= times + 0.02) & (onsets >= times - 0.06))


def test_when_motion_rests_at_the_onsets_expect_beat_consistency_near_one_and_lower_shuffled():
    times = np.array([0.5, 1.3, 2.2, 3.1])
    t = np.arange(400) / RATE
    # speed falls to zero at every onset: |sin| of a phase that passes zero there
    phase = np.interp(t, np.concatenate([[0.0], times, [4.0]]), np.arange(times.size + 2) * np.pi)
    angles = np.stack([0.1 * np.cos(phase), np.zeros_like(t)], axis=1)
    beats = realism.motion_beats(angles)
    total, count = realism.beat_consistency(times, beats)
    assert count == 4
    assert total / count > 0.95
    shifted, _ = realism.beat_consistency(times + 0.45, beats)
    assert shifted / count < 0.6
    assert realism.beat_consistency(times, np.zeros(0)) == (0.0, 4)


def _resting_at(times, seconds):
    """Angles whose speed falls to zero at each of ``times`` (and moves in between).

    Each rest is half a frame late, so that one frame interval holds it: a strict minimum.
    """
    t = np.arange(int(seconds * RATE)) / RATE
    knots = np.concatenate([[0.0], np.asarray(times) + 0.5 / RATE, [seconds]])
    phase = np.interp(t, knots, np.arange(knots.size) * np.pi)
    angles = np.stack([0.1 * np.cos(phase), np.zeros_like(t)], axis=1)
    return angles, np.ones(angles.shape, bool)


def test_when_the_paired_motion_is_shorter_expect_bc_over_the_time_both_cover():
    # a's onsets every 0.8 s over 8 s; b is a's first 4 s of motion: it rests at a's onsets
    onsets_a = np.arange(0.5, 8.0, 0.8)
    long_a = _resting_at(onsets_a, 8.0)
    short_b = (long_a[0][:400], long_a[1][:400])
    onsets_b = onsets_a[onsets_a < 4.0]
    own = realism.pooled_beat_consistency([onsets_a, onsets_b], [long_a, short_b], [0, 1])
    swapped = realism.pooled_beat_consistency([onsets_a, onsets_b], [long_a, short_b], [1, 0])
    assert own > 0.95
    # a's onsets after b's end have no motion to be timed against: they do not count
    assert swapped == pytest.approx(own, abs=0.02)
    assert np.isnan(realism.pooled_beat_consistency([np.zeros(0)], [short_b], [0]))


def test_when_motion_is_scaled_expect_l1_diversity_and_jerk_ratios_of_the_scale():
    rng = np.random.default_rng(1)
    real = np.cumsum(rng.normal(0, 0.01, (300, 2)), axis=0)
    known = np.ones(real.shape, bool)
    ratios = realism.motion_ratios([(real, known)], [(2.0 * real, known)])
    assert ratios["L1div ratio"] == pytest.approx(2.0)
    assert ratios["jerk ratio"] == pytest.approx(4.0)  # J is squared


def test_when_comparing_windows_expect_the_copy_near_its_floor_and_a_still_pose_far():
    rng = np.random.default_rng(2)
    clips = [np.cumsum(rng.normal(0, 0.01, (400, 2)), axis=0) for _ in range(6)]
    real = [(c, np.ones(c.shape, bool)) for c in clips]
    copy = realism.frechet_windows(real, clips)
    assert copy.generated == pytest.approx(copy.floor)
    still = realism.frechet_windows(real, [np.zeros_like(c) for c in clips])
    assert still.generated > 3 * copy.floor
    assert 1 <= still.components <= realism.MAX_COMPONENTS


def test_when_percentiles_of_a_constant_speed_expect_that_speed():
    angles = np.stack([np.arange(200) * 0.005, np.zeros(200)], axis=1)  # 0.5 rad/s
    speed, accel = realism.speed_percentiles([(angles, np.ones(angles.shape, bool))])
    np.testing.assert_allclose(speed[0], 0.5)
    np.testing.assert_allclose(speed[1], 0.0)
    np.testing.assert_allclose(accel, 0.0, atol=1e-9)


def test_when_resamples_are_biased_upwards_expect_the_corrected_interval_to_hold_its_estimate():
    point = 0.14
    draws = list(np.linspace(0.16, 0.22, 200))  # every resample above the point, as seen on data
    estimate, low, high = metrics.bias_corrected(point, draws)
    assert low <= estimate <= high
    assert estimate == pytest.approx(point - (np.mean(draws) - point))
    assert metrics.bias_corrected(0.01, [0.2] * 10)[0] == 0.0  # distances stay non-negative


def test_when_halves_of_one_motion_are_compared_expect_a_small_split_half_floor():
    rng = np.random.default_rng(3)
    theta = np.cumsum(rng.normal(0, 0.01, (3000, 1)), axis=0)
    segments = metrics.segment_statistics(
        theta, np.ones(theta.shape, bool), np.ones(3000, bool), RATE
    )
    floor = metrics.split_half_floor(segments, 50)
    value, low, high = floor["H speed"]
    assert low <= value <= high
    assert value < 0.1
