"""Seed 003 MLP: architecture, the numpy streaming path, learnability on a known mapping."""

import numpy as np
import pytest
import torch

from audio2pose_ros.models import build_model
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.training import TrainSettings, Utterance, train_model


def test_when_default_config_expect_seed_table_4_5_parameter_count():
    # Seed 003 Table 4.5, LogFB-26: N_l = 7 hidden layers of N_u = 8 units, 747 parameters.
    model = FramewiseMLP(MLPConfig())
    assert sum(p.numel() for p in model.parameters()) == 747


def test_when_streaming_predictor_expect_same_output_as_torch_forward():
    torch.manual_seed(1)
    model = FramewiseMLP(MLPConfig(hidden_units=16)).eval()
    frames = np.random.default_rng(0).normal(size=(50, 26))
    with torch.no_grad():
        expected = model(torch.tensor(frames, dtype=torch.float32)).numpy()
    predictor = model.streaming_predictor()
    got = np.array([predictor.step(f) for f in frames])
    np.testing.assert_allclose(got, expected, atol=1e-5)
    assert np.all((got > 0) & (got < 1))  # sigmoid output: inside the joint range


def test_when_unknown_model_or_config_expect_clear_error():
    with pytest.raises(ValueError, match="unknown model 'transformer'"):
        build_model("transformer", {})
    with pytest.raises(ValueError, match="bad config"):
        build_model("mlp", {"n_layers": 3})


def synthetic_utterances(n: int, frames: int, seed: int) -> list[Utterance]:
    """Motion that is a known smooth function of the current audio features."""
    rng = np.random.default_rng(seed)
    mixing = np.random.default_rng(99).normal(size=(26, 11)) / np.sqrt(26)
    out = []
    for i in range(n):
        feats = rng.normal(size=(frames, 26))
        targets = 1.0 / (1.0 + np.exp(-2.0 * np.tanh(feats @ mixing)))
        out.append(Utterance(f"u{i}", feats, targets, np.ones_like(targets, dtype=bool)))
    return out


def test_when_motion_is_function_of_features_expect_mlp_learns_it():
    train = synthetic_utterances(8, 400, seed=0)
    val = synthetic_utterances(2, 400, seed=1)
    torch.manual_seed(0)
    model = FramewiseMLP(MLPConfig(hidden_layers=2, hidden_units=64))
    baseline = float(np.mean([(u.targets - u.targets.mean(0)) ** 2 for u in val]))
    report = train_model(
        model,
        train,
        val,
        TrainSettings(max_epochs=150, learning_rate=3e-3, show_progress=False, window_frames=100),
    )
    # Predicting the mean scores ~0.04; a model that learned the mapping is 10x better.
    assert report.best_val_loss < 0.1 * baseline
    assert report.val_loss[0] > report.best_val_loss


def test_when_targets_masked_expect_masked_values_ignored():
    train = synthetic_utterances(4, 200, seed=2)
    poisoned = [
        Utterance(
            u.name,
            u.features,
            np.where(np.arange(11) == 0, 1e3, u.targets),
            np.broadcast_to(np.arange(11) != 0, u.targets.shape).copy(),
        )
        for u in train
    ]
    torch.manual_seed(0)
    model = FramewiseMLP(MLPConfig(hidden_layers=2, hidden_units=32))
    report = train_model(
        model, poisoned, poisoned[:1], TrainSettings(max_epochs=20, show_progress=False)
    )
    assert np.isfinite(report.best_val_loss)
    assert report.best_val_loss < 0.1


def test_when_split_empty_expect_value_error():
    model = FramewiseMLP(MLPConfig())
    with pytest.raises(ValueError, match="at least one training and one validation"):
        train_model(model, [], synthetic_utterances(1, 10, 0))
