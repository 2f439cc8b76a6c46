"""Seed 003 section 3.4 metrics, GENEA Hellinger distances and diversity, on hand-worked arrays."""

import numpy as np
import pytest

from audio2pose_ros.learning import metrics


def test_when_errors_known_expect_rmse_per_joint_and_overall_in_degrees():
    true = np.zeros((2, 2))
    pred = np.array([[0.1, 0.0], [0.1, 0.2]])
    # eq. 3.11: joint 0 sqrt((0.01 + 0.01) / 2) = 0.1 rad; joint 1 sqrt(0.04 / 2) rad
    np.testing.assert_allclose(
        metrics.rmse_deg_per_joint(true, pred), np.degrees([0.1, np.sqrt(0.02)])
    )
    # eq. 3.12: sqrt(0.06 / 4) rad
    assert metrics.rmse_deg(true, pred) == pytest.approx(np.degrees(np.sqrt(0.015)))
    mask = np.array([[True, True], [True, False]])
    assert metrics.rmse_deg(true, pred, mask) == pytest.approx(np.degrees(np.sqrt(0.02 / 3)))
    np.testing.assert_allclose(metrics.rmse_deg_per_joint(true, pred, mask), [5.729578, 0.0], 1e-6)


def test_when_normalised_errors_known_expect_loss_l_is_their_mean_square():
    true = np.array([[0.0, 1.0], [0.5, 0.5]])
    pred = np.array([[0.1, 0.8], [0.5, 0.2]])
    # eq. 3.15: (0.01 + 0.04 + 0 + 0.09) / 4
    assert metrics.loss_l(true, pred) == pytest.approx(0.035)
    assert metrics.loss_l(true, pred, np.array([[1, 1], [0, 0]], bool)) == pytest.approx(0.025)


def test_when_y_is_affine_in_x_expect_cca_one_and_constant_gives_zero():
    x = np.arange(6.0)[:, None]
    assert metrics.cca(x, 2 * x + 1) == pytest.approx(1.0)
    assert metrics.cca(x, -x) == pytest.approx(1.0)  # correlation of the best projections
    assert metrics.cca(x, np.ones((6, 2))) == 0.0


def covariance_cca(x, y):
    """Reference: rho^2 = largest eigenvalue of Sxx^-1 Sxy Syy^-1 Syx."""
    xc, yc = x - x.mean(0), y - y.mean(0)
    sxx, syy, sxy = xc.T @ xc, yc.T @ yc, xc.T @ yc
    matrix = np.linalg.solve(sxx, sxy) @ np.linalg.solve(syy, sxy.T)
    return float(np.sqrt(np.max(np.linalg.eigvals(matrix).real)))


def test_when_random_small_data_expect_cca_equals_covariance_reference_and_brute_force():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(12, 2))
    y = np.column_stack([x[:, 0] + 0.5 * rng.normal(size=12), rng.normal(size=12)])
    rho = metrics.cca(x, y)
    assert rho == pytest.approx(covariance_cca(x, y), abs=1e-10)
    # Brute force over directions: no pair of projections correlates more than rho, and the
    # best of a fine grid comes within 1e-3 of it.
    angles = np.linspace(0, np.pi, 400)
    dirs = np.column_stack([np.cos(angles), np.sin(angles)])
    u, v = x @ dirs.T, y @ dirs.T  # (12, 400) each
    uc, vc = (u - u.mean(0)) / u.std(0), (v - v.mean(0)) / v.std(0)
    correlations = np.abs(uc.T @ vc / 12)
    assert correlations.max() <= rho + 1e-9
    assert correlations.max() > rho - 1e-3


def test_when_sliding_window_expect_lcca_is_mean_of_window_ccas():
    rng = np.random.default_rng(1)
    x, y = rng.normal(size=(7, 2)), rng.normal(size=(7, 1))
    # eq. 3.18: d - N_tau + 1 = 7 - 4 + 1 = 4 windows, stride 1
    expected = np.mean([metrics.cca(x[i : i + 4], y[i : i + 4]) for i in range(4)])
    assert metrics.lcca(x, y, 4) == pytest.approx(expected)
    assert metrics.lcca(x, y, 10) == pytest.approx(metrics.cca(x, y))  # shorter: one window
    assert metrics.window_frames_for(100.0) == 300  # N_tau = 3 s * f_f


def test_when_true_equals_prediction_expect_lcca_theta_one_and_delta_lcca_zero():
    t = np.linspace(0, 4, 400)
    theta = np.column_stack([np.sin(3 * t), np.cos(2 * t)])
    features = np.column_stack([np.sin(3 * t + 0.3), t])
    assert metrics.lcca_theta(theta, theta, 100.0) == pytest.approx(1.0)
    assert metrics.delta_lcca(features, theta, theta, 100.0) == pytest.approx(0.0)


def test_when_cubic_trajectory_expect_seed_jerk_formula_value():
    # theta_i = i^3 at f_f = 10 Hz: the third forward difference is 6 rad per frame^3, times
    # f_f^3 = 6000 rad/s^3; N_fr = 5 gives 2 terms: J = 2 * 6000^2 / (2 * 10 * 2) = 1.8e6.
    theta = np.column_stack([np.arange(5.0) ** 3, np.full(5, 0.3)])
    assert metrics.jerk(theta, 10.0) == pytest.approx(1.8e6)
    assert metrics.delta_jerk(theta, np.zeros((5, 2)), 10.0) == pytest.approx(1.8e6)
    linear = np.column_stack([np.arange(5.0), np.arange(5.0)])
    assert metrics.jerk(linear, 10.0) == pytest.approx(0.0)
    # eq. 3.22: means over sequences
    jerk_mean, delta_mean = metrics.jerk_means([theta, theta], [theta, linear], 10.0)
    assert (jerk_mean, delta_mean) == pytest.approx((0.9e6, 0.9e6))
    with pytest.raises(ValueError, match="at least 4 frames"):
        metrics.jerk(theta[:3], 10.0)


def test_when_partly_known_joint_expect_jerk_uses_complete_joints_only():
    theta = np.column_stack([np.arange(5.0) ** 3, np.arange(5.0) ** 3])
    mask = np.ones((5, 2), bool)
    mask[2, 1] = False
    assert metrics.jerk(theta, 10.0, mask) == pytest.approx(1.8e6)


def test_when_histograms_known_expect_hellinger_distance():
    assert metrics.hellinger([1, 2, 3], [2, 4, 6]) == pytest.approx(0.0)
    assert metrics.hellinger([1, 0], [0, 1]) == pytest.approx(1.0)
    assert metrics.hellinger([1, 0], [1, 1]) == pytest.approx(np.sqrt(1 - np.sqrt(0.5)))


def test_when_speeds_differ_expect_hellinger_speed_large_and_same_motion_zero():
    t = np.arange(200) / 100.0
    slow = np.column_stack([0.1 * t, 0.05 * t])  # 0.1 and 0.05 rad/s: first speed bin
    fast = np.column_stack([2.0 * t, 3.0 * t])  # 2 and 3 rad/s
    assert metrics.hellinger_speed(slow, slow, 100.0) == pytest.approx(0.0)
    assert metrics.hellinger_speed(slow, fast, 100.0) == pytest.approx(1.0)
    assert metrics.hellinger_acceleration(slow, fast, 100.0) == pytest.approx(0.0)  # both 0


def test_when_samples_offset_expect_diversity_mean_pairwise_rms_in_degrees():
    base = np.zeros((10, 3))
    samples = np.stack([base, base + 0.01, base + 0.03])
    # pairwise RMS: 0.01, 0.03, 0.02 rad -> mean 0.02 rad
    assert metrics.diversity_deg(samples) == pytest.approx(np.degrees(0.02))
    with pytest.raises(ValueError, match="at least 2 samples"):
        metrics.diversity_deg(samples[:1])
