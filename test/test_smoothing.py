"""Smoothing of seed 003 section 4.2.3 (Butterworth 5th order, 4 Hz) and 4.4.2 (Kalman)."""

import numpy as np
import pytest

from audio2pose_ros.motion.smoothing import CausalLowPass, KalmanSmoother, butterworth_zero_phase

RATE = 100.0


def sine(freq_hz: float, seconds: float = 4.0) -> np.ndarray:
    t = np.arange(int(seconds * RATE)) / RATE
    return np.sin(2 * np.pi * freq_hz * t)[:, None]


def amplitude(x: np.ndarray) -> float:
    middle = x[len(x) // 4 : -len(x) // 4]  # away from edge effects
    return float(np.sqrt(2) * middle.std())


def test_when_zero_phase_butterworth_expect_1hz_kept_10hz_removed_no_delay():
    slow, fast = sine(1.0), sine(10.0)
    smoothed_slow = butterworth_zero_phase(slow)
    assert amplitude(smoothed_slow) == pytest.approx(1.0, abs=0.01)
    assert amplitude(butterworth_zero_phase(fast)) < 0.01  # 5th order: ~ -40 dB at 10 Hz
    # Zero phase: the peak of the smoothed 1 Hz sine is where the input's is.
    middle = slice(100, 200)
    assert np.argmax(smoothed_slow[middle]) == np.argmax(slow[middle])


def test_when_cutoff_above_nyquist_expect_error():
    with pytest.raises(ValueError, match="cutoff_hz 60"):
        butterworth_zero_phase(sine(1.0), cutoff_hz=60.0)


def test_when_causal_lowpass_reset_expect_no_transient_and_10hz_attenuated():
    lp = CausalLowPass(n_joints=2)
    lp.reset(np.array([0.3, -0.2]))
    np.testing.assert_allclose(lp.step(np.array([0.3, -0.2])), [0.3, -0.2], atol=1e-12)
    lp.reset(np.zeros(2))
    out = np.array([lp.step(np.array([v, v])) for v in sine(10.0)[:, 0]])
    assert amplitude(out[:, :1]) < 0.02


def test_when_kalman_tracks_step_expect_convergence_without_overshoot_blowup():
    kf = KalmanSmoother(n_joints=3, dt_s=0.01, q=0.5, r=0.01)
    kf.reset(np.zeros(3))
    target = np.array([0.5, -0.3, 0.0])
    outputs = np.array([kf.step(target) for _ in range(300)])
    np.testing.assert_allclose(outputs[-1], target, atol=1e-3)
    assert np.max(np.abs(outputs[:, 0])) < 0.5 * 1.5  # overshoot bounded
    # Smoothing: the first step moves only part of the way.
    assert 0.0 < outputs[0, 0] < 0.5


def test_when_kalman_gets_nan_expect_prediction_only_and_finite():
    kf = KalmanSmoother(n_joints=2)
    kf.reset(np.array([0.1, 0.1]))
    out = kf.step(np.array([np.nan, 0.1]))
    assert np.all(np.isfinite(out))
    assert out[0] == pytest.approx(0.1)


def test_when_kalman_noise_not_positive_expect_error():
    with pytest.raises(ValueError, match="must be positive"):
        KalmanSmoother(n_joints=1, q=0.0)
