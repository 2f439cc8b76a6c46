"""The live sampler's noise: offline and streaming agree, unit variance, bursts give heavy tails."""

import json

import numpy as np
import pytest
import torch

from audio2pose_ros.checkpoints.numpy_runtime import numpy_kernel_for
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.live import LiveConfig, LiveSampler
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.models.sampling_noise import (
    MAX_BURST,
    NORMAL_BLOCK,
    NoiseShape,
    NoiseStream,
    NormalBlocks,
)


@pytest.mark.parametrize(
    "shape",
    [
        NoiseShape(0.9),
        NoiseShape(0.95, 2),
        NoiseShape(0.975, 2, 1.2),
        NoiseShape(0.95, 2, (0.0, 1.2, 0.6, 2.0)),
    ],
)
def test_when_streaming_frame_by_frame_expect_the_offline_noise_of_the_same_draws(shape):
    white = np.random.default_rng(1).standard_normal((3, 400, shape.draws(4)))
    offline = shape.filter(white)
    for sequence, expected in zip(white, offline, strict=True):
        stream = NoiseStream(shape, 4)
        frames = [stream.start(sequence[0])] + [stream.next(d) for d in sequence[1:]]
        np.testing.assert_allclose(np.array(frames), expected, atol=1e-10)


def test_when_counting_draws_expect_one_per_joint_and_one_more_for_a_burst_envelope():
    assert NoiseShape(0.95, 2).draws(9) == 9  # unchanged for models without bursts
    assert NoiseShape(0.95, 2, 0.5).draws(9) == 10


@pytest.mark.parametrize("burst", [0.0, 0.6])
def test_when_bursty_expect_unit_variance_from_the_first_frame(burst):
    shape = NoiseShape(0.95, 2, burst)
    noise = shape.filter(np.random.default_rng(2).standard_normal((4000, 300, shape.draws(1))))
    assert abs(noise[:, 0].var() - 1.0) < 0.15  # stationary from frame 0
    assert abs(noise[:, -1].var() - 1.0) < 0.15


def test_when_very_bursty_expect_unit_variance_pooled_over_frames():
    # E[a^4] = exp(4 b^2) makes one frame's variance estimate too noisy: pool frames instead
    shape = NoiseShape(0.95, 2, 1.2)
    noise = shape.filter(np.random.default_rng(4).standard_normal((4000, 600, shape.draws(1))))
    assert abs(noise[:, 100:].var() - 1.0) < 0.25


def _speed_kurtosis(burst: float) -> float:
    shape = NoiseShape(0.95, 2, burst)
    noise = shape.filter(np.random.default_rng(3).standard_normal((20, 3000, shape.draws(1))))
    return _kurtosis(noise)[0]


def _kurtosis(noise: np.ndarray) -> np.ndarray:
    """Per joint, the kurtosis of the noise's frame-to-frame step (3 for Gaussian steps)."""
    speed = np.diff(noise, axis=1).reshape(-1, noise.shape[-1])
    return np.mean(speed**4, axis=0) / np.mean(speed**2, axis=0) ** 2


def test_when_bursty_per_joint_expect_each_joint_as_heavy_tailed_as_its_own_burstiness():
    shape = NoiseShape(0.95, 2, (0.0, 1.2))
    noise = shape.filter(np.random.default_rng(3).standard_normal((20, 3000, shape.draws(2))))
    steady, bursty = _kurtosis(noise)
    assert abs(steady - 3.0) < 0.3  # a joint of burstiness 0 keeps Gaussian speed
    assert bursty > steady + 2.0
    calm = np.abs(np.diff(noise[..., 1], axis=1)) < np.median(np.abs(np.diff(noise[..., 1])))
    # one envelope: the steady joint's steps do not care; the bursts are the envelope's alone
    steps = np.abs(np.diff(noise[..., 0], axis=1))
    assert abs(steps[calm].mean() / steps[~calm].mean() - 1.0) < 0.1
    many = shape.filter(np.random.default_rng(4).standard_normal((4000, 600, shape.draws(2))))
    np.testing.assert_allclose(many[:, 100:].var(axis=(0, 1)), 1.0, atol=0.25)  # unit variance


def test_when_every_joint_has_the_same_burstiness_expect_the_shared_bursts_draw_for_draw():
    white = np.random.default_rng(5).standard_normal((2, 500, 3))
    np.testing.assert_array_equal(
        NoiseShape(0.95, 2, (0.8, 0.8)).filter(white), NoiseShape(0.95, 2, 0.8).filter(white)
    )
    assert NoiseShape(0.95, 2, (0.0, 0.0)).draws(2) == 2  # no envelope: the steady draws


@pytest.mark.parametrize(
    "burst", [(0.6,), (0.6, 0.6, 0.6), (0.6, float("nan")), (0.6, -0.1), (True, 0.6), "0.6"]
)
def test_when_a_per_joint_burst_is_malformed_expect_a_configuration_error_and_no_kernel(burst):
    config = {"n_features": 4, "n_joints": 3, "first_group": 3}
    with pytest.raises(ConfigurationError, match="first_burst"):
        build_model("live_groups", {**config, "first_burst": burst})
    groups = build_model("live_groups", config).config_dict()
    assert numpy_kernel_for("live_groups", {**groups, "first_burst": burst}) is None
    assert numpy_kernel_for("live_groups", {**groups, "first_burst": [0.0, 1.2]}) is not None


def test_when_a_checkpoint_holds_a_per_joint_burst_as_a_list_expect_a_tuple_that_round_trips():
    model = build_model("live_groups", {"n_features": 4, "n_joints": 3, "first_burst": [0, 1.2]})
    assert model.config.first_burst == (0.0, 1.2)
    assert model.samplers()[0].config.noise_burst == (0.0, 1.2)
    again = build_model("live_groups", json.loads(json.dumps(model.config_dict())))
    assert again.config == model.config


def test_when_bursty_expect_heavier_tailed_speed_than_steady_noise():
    steady, bursty = _speed_kurtosis(0.0), _speed_kurtosis(1.2)
    assert abs(steady - 3.0) < 0.3  # Gaussian speed
    assert bursty > steady + 2.0  # long quiet stretches and short quick movements


@pytest.mark.parametrize("burst", [-0.1, MAX_BURST + 0.1, float("nan")])
def test_when_a_burst_is_out_of_range_expect_a_configuration_error_and_no_numpy_kernel(burst):
    with pytest.raises(ConfigurationError, match="noise_burst"):
        LiveSampler(LiveConfig(noise_burst=burst))
    config = build_model("live", {"n_features": 4, "n_joints": 3}).config_dict()
    assert numpy_kernel_for("live", {**config, "noise_burst": burst}) is None
    groups = build_model("live_groups", {"n_features": 4, "n_joints": 3}).config_dict()
    assert numpy_kernel_for("live_groups", {**groups, "second_burst": burst}) is None
    assert numpy_kernel_for("live_groups", groups) is not None


def test_when_a_model_has_no_burst_expect_its_config_without_the_key():
    assert "noise_burst" not in build_model("live", {"n_features": 4, "n_joints": 3}).config_dict()
    bursty = build_model("live", {"n_features": 4, "n_joints": 3, "noise_burst": 0.5})
    assert bursty.config_dict()["noise_burst"] == 0.5


@pytest.mark.parametrize("correlation", [-0.1, 1.0, float("nan")])
@pytest.mark.parametrize("key", ["first_correlation", "second_correlation"])
def test_when_a_part_correlation_is_out_of_range_expect_a_configuration_error_and_no_kernel(
    correlation, key
):
    with pytest.raises(ConfigurationError, match="correlation"):
        build_model("live_groups", {"n_features": 4, "n_joints": 3, key: correlation})
    groups = build_model("live_groups", {"n_features": 4, "n_joints": 3}).config_dict()
    assert key not in groups  # parts that share the correlation keep the keys they had
    assert numpy_kernel_for("live_groups", {**groups, key: correlation}) is None
    assert numpy_kernel_for("live_groups", {**groups, key: 0.5}) is not None


def test_when_one_part_has_its_own_correlation_expect_only_that_part_to_move_otherwise():
    torch.manual_seed(0)
    model = build_model("live_groups", {"n_features": 4, "n_joints": 3, "first_group": 1})
    features = torch.randn(1, 300, 4)
    generator = torch.Generator().manual_seed(3)
    shared = model.sample(features, 1, generator)
    quick = model.with_sampling(first_correlation=0.5).sample(features, 1, generator)
    assert model.with_sampling(first_correlation=0.5).part_correlations() == (
        0.5,
        model.config.noise_correlation,
    )
    torch.testing.assert_close(quick[..., 1:], shared[..., 1:])  # the second part: unchanged
    head_speed = [np.abs(np.diff(m[0, 0, :, 0].numpy())).mean() for m in (shared, quick)]
    assert head_speed[1] > 1.5 * head_speed[0]  # less correlated noise moves faster


@pytest.mark.parametrize("draws", [1, 4, 9])
def test_when_normals_are_drawn_in_blocks_expect_the_numbers_of_drawing_frame_by_frame(draws):
    """A streaming sampler draws a block of frames at once: the same numbers, block after block."""
    frame_by_frame = np.random.default_rng(5)
    blocks = NormalBlocks(np.random.default_rng(5), draws)
    for _ in range(3 * NORMAL_BLOCK + 7):
        assert np.array_equal(blocks.next(), frame_by_frame.standard_normal(draws))
