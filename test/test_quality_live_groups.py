"""The live_groups model: a streaming sampler per joint group, seeded, trained per group."""

import numpy as np
import pytest
import torch

from audio2pose_ros.models.registry import build_model

torch.set_num_threads(1)


@pytest.fixture
def model():
    torch.manual_seed(0)
    return build_model("live_groups", {"n_features": 4, "n_joints": 5, "hidden_units": 6})


def stream(predictor, features):
    return np.stack([predictor.step(f) for f in features])


def test_when_streaming_with_a_seed_expect_the_same_motion_and_another_seed_differs(model):
    features = np.random.default_rng(0).normal(size=(60, 4))
    first = stream(model.streaming_predictor(seed=7), features)
    again = stream(model.streaming_predictor(seed=7), features)
    other = stream(model.streaming_predictor(seed=8), features)
    np.testing.assert_array_equal(first, again)
    assert np.abs(first - other).max() > 1e-3
    predictor = model.streaming_predictor(seed=8)
    stream(predictor, features[:10])
    predictor.reset(seed=7)
    np.testing.assert_array_equal(stream(predictor, features), first)


def test_when_temperature_is_zero_expect_streaming_equals_forward_in_joint_order(model):
    features = np.random.default_rng(1).normal(size=(40, 4))
    predictor = model.streaming_predictor(seed=3, temperature=0.0)
    with torch.no_grad():
        offline = model(torch.tensor(features[None], dtype=torch.float32))[0].numpy()
    np.testing.assert_allclose(stream(predictor, features), offline, atol=1e-5)


def test_when_a_clip_labels_only_the_head_expect_only_the_head_part_to_learn(model):
    features = torch.randn(2, 30, 4)
    targets = torch.rand(2, 30, 5)
    mask = torch.zeros(2, 30, 5, dtype=torch.bool)
    mask[..., :2] = True  # joints 0 and 1: the first group (first_group = 3)
    model.zero_grad()
    model.training_loss(features, targets, mask).backward()
    head, body = model.parts
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())
    assert all(p.grad is None or p.grad.abs().sum() == 0 for p in body.parameters())


def test_when_the_first_group_selects_no_or_all_joints_expect_a_configuration_error():
    from audio2pose_ros.errors import ConfigurationError

    for bits in (0, 31, 64):
        with pytest.raises(ConfigurationError, match="first_group"):
            build_model("live_groups", {"n_joints": 5, "first_group": bits})


@pytest.mark.parametrize("name", ["mlp", "lstm", "live", "live_groups"])
def test_when_any_streaming_model_is_given_a_seed_expect_a_predictor(name):
    model = build_model(name, {"n_features": 4, "n_joints": 5})
    predictor = model.streaming_predictor(seed=5)
    assert predictor.step(np.zeros(4)).shape == (5,)


def silence_speed(model, features, seed=0):
    poses = stream(model.streaming_predictor(seed=seed), features)
    return np.abs(np.diff(poses[300:], axis=0)).mean()  # 1 s after speech stopped


def test_when_speech_stops_expect_the_speech_gate_to_still_the_sampling_noise():
    rng = np.random.default_rng(4)
    features = np.concatenate([rng.normal(0.3, 1.0, (200, 4)), np.full((200, 4), -1.5)])
    speeds = {}
    for rest in (1.0, 0.05):
        torch.manual_seed(0)
        config = {"n_features": 4, "n_joints": 5, "hidden_units": 6, "silence_temperature": rest}
        model = build_model("live_groups", config)
        with torch.no_grad():  # a wide output distribution, so the noise dominates the motion
            for part in model.parts:
                part.out.bias[part.config.n_joints :] = -1.0
        speeds[rest] = silence_speed(model, features)
        np.testing.assert_array_equal(speeds[rest], silence_speed(model, features))
    assert speeds[0.05] < 0.3 * speeds[1.0]


def test_when_sampling_offline_with_a_seed_expect_the_streaming_motion_of_that_seed(model):
    features = np.random.default_rng(5).normal(size=(80, 4))
    generator = torch.Generator().manual_seed(11)
    offline = model.sample(torch.tensor(features[None], dtype=torch.float32), 1, generator)
    online = stream(model.streaming_predictor(seed=11), features)
    np.testing.assert_allclose(offline[0, 0].numpy(), online, atol=1e-5)
