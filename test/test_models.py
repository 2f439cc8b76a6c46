"""Every model family: learnability, streaming equality, offline refusal, sampling."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.learning.batches import TrainingError, Utterance
from audio2pose_ros.learning.training import TrainSettings, evaluate_loss, train_model
from audio2pose_ros.models.base import OfflineOnlyModelError, require_streaming
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.models.registry import MODEL_REGISTRY, build_model
from audio2pose_ros.models.span import recombine_spans, span_loss

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_motion import mean_baseline_mse
from synthetic_motion import synthetic_utterances as loudness_utterances


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
    with pytest.raises(ConfigurationError, match="unknown model 'transformer'"):
        build_model("transformer", {})
    with pytest.raises(ConfigurationError, match=r"unknown config keys \['n_layers'\]"):
        build_model("mlp", {"n_layers": 3})


@pytest.mark.parametrize(
    ("config", "problem"),
    [
        ({"hidden_units": 10**9}, r"hidden_units=1000000000 is outside \[0, 1024\]"),
        ({"hidden_layers": 2.5}, "hidden_layers=2.5 is not an integer"),
        ({"hidden_units": "8"}, "hidden_units='8' is not an integer"),
        ({"dropout": float("nan")}, "dropout=nan is not finite"),
        ({"dropout": [0.1]}, r"dropout=\[0.1\] is not a number"),
    ],
)
def test_when_config_value_is_absurd_expect_configuration_error_before_any_allocation(
    config, problem
):
    with pytest.raises(ConfigurationError, match=problem):
        build_model("mlp", config)


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


def test_when_split_empty_expect_training_error():
    model = FramewiseMLP(MLPConfig())
    with pytest.raises(TrainingError, match="at least one training and one validation"):
        train_model(model, [], synthetic_utterances(1, 10, 0))


# --- every model family ----------------------------------------------------------------------

torch.set_num_threads(1)

# Small sizes so that each family trains in a few seconds on one core.
FAST_CONFIGS = {
    "mlp": {"hidden_layers": 2, "hidden_units": 32},
    "lstm": {},
    "dae_gru": {"dense_layers": 1, "dae_learning_rate": 3e-3},
    "blstm": {},
    "blstm_prior": {},
    "cvae": {},
    "live": {},
}
FAST_EPOCHS = {"dae_gru": 30}


def train_fast(name, train, val, epochs=40, lr=None):
    torch.manual_seed(0)
    model = build_model(name, FAST_CONFIGS[name])
    settings = TrainSettings(
        max_epochs=FAST_EPOCHS.get(name, epochs),
        window_frames=100,
        batch_size=8,
        show_progress=False,
        learning_rate=3e-3 if name == "dae_gru" else lr,
    )
    report = train_model(model, train, val, settings)
    return model, report


@pytest.fixture(scope="module")
def loudness_data():
    return loudness_utterances(8, 400, seed=0), loudness_utterances(2, 400, seed=1)


def test_when_registry_listed_expect_all_seed_families_and_the_live_models():
    seeds = {"mlp", "lstm", "dae_gru", "blstm", "blstm_prior", "cvae"}
    assert set(MODEL_REGISTRY) == seeds | {"live", "live_groups"}
    streaming = {n for n, (cls, _) in MODEL_REGISTRY.items() if cls.streaming}
    assert streaming == {"mlp", "lstm", "live", "live_groups"}


@pytest.mark.parametrize("name", sorted(FAST_CONFIGS))
def test_when_motion_is_function_of_loudness_expect_each_model_beats_mean_by_4x(
    name, loudness_data
):
    train, val = loudness_data
    baseline = mean_baseline_mse(train, val)  # ~0.015 in [0, 1] units
    model, report = train_fast(name, train, val)
    loss = evaluate_loss(model, val)
    # Every family learns the causal loudness -> motion map to a quarter of the mean baseline.
    assert loss < 0.25 * baseline, f"{name}: L {loss:.5f} vs mean baseline {baseline:.5f}"
    assert report.best_val_loss < report.val_loss[-report.stages[-1].epochs]  # it improved


@pytest.mark.parametrize("name", ["mlp", "lstm", "live"])
def test_when_streaming_frame_by_frame_expect_same_output_as_whole_sequence(name):
    torch.manual_seed(3)
    model = build_model(name, {}).eval()
    frames = np.random.default_rng(0).normal(size=(150, 26))
    with torch.no_grad():
        whole = model(torch.tensor(frames[None], dtype=torch.float32))[0].numpy()
    predictor = (
        model.streaming_predictor(temperature=0.0)
        if name == "live"
        else model.streaming_predictor()
    )
    for _ in range(2):  # reset() starts a new utterance with the same result
        got = np.array([predictor.step(f) for f in frames])
        np.testing.assert_allclose(got, whole, atol=1e-5)
        predictor.reset()


@pytest.mark.parametrize("name", ["dae_gru", "blstm", "blstm_prior", "cvae"])
def test_when_offline_model_used_online_expect_refusal_pointing_to_synth(name):
    model = build_model(name, {})
    with pytest.raises(OfflineOnlyModelError, match="audio2pose synth"):
        model.streaming_predictor()
    with pytest.raises(OfflineOnlyModelError, match=r"m\.safetensors: .*audio2pose synth"):
        require_streaming(model, "m.safetensors")
    require_streaming(build_model("lstm", {}), "ok.safetensors")


def test_when_spans_recombined_expect_mean_of_predictions_per_frame():
    # k = 2, T = 3, J = 1: frame 0 gets slot 0 of step 0; frame 1 slot 0 of step 1 and slot 1
    # of step 0; frame 2 slot 0 of step 2 and slot 1 of step 1.
    spans = torch.tensor([[[[1.0], [2.0]], [[3.0], [4.0]], [[5.0], [6.0]]]])
    np.testing.assert_allclose(recombine_spans(spans)[0, :, 0].numpy(), [1.0, 2.5, 4.5])
    targets = torch.tensor([[[1.0], [2.0], [5.0]]])
    # errors: slot 0 -> 0, 1, 0; slot 1 -> (2-2)=0, (4-5)=-1 ; mean of 5 squares = 2 / 5
    loss = span_loss(spans, targets, torch.ones_like(targets, dtype=torch.bool))
    assert float(loss) == pytest.approx(2.0 / 5.0)


@pytest.fixture(scope="module")
def one_to_many_data():
    """Per-clip offsets on two joints that the audio does not reveal."""
    return (
        loudness_utterances(16, 400, seed=0, offset_std=0.1),
        loudness_utterances(2, 400, seed=1, offset_std=0.1),
    )


@pytest.mark.parametrize("name", ["cvae", "live"])
def test_when_sampling_same_audio_expect_samples_differ_from_each_other_and_the_mean(
    name, one_to_many_data
):
    train, val = one_to_many_data
    model, _ = train_fast(name, train, val)
    x = torch.tensor(val[0].features[None], dtype=torch.float32)
    with torch.no_grad():
        samples = model.sample(x, 4, torch.Generator().manual_seed(0))[:, 0]  # (S, T, J)
        mean = model(x)[0]
        again = model.sample(x, 4, torch.Generator().manual_seed(0))[:, 0]
    torch.testing.assert_close(samples, again)  # seeded: reproducible
    pairwise = [
        float((samples[a] - samples[b]).pow(2).mean().sqrt()) for a in range(4) for b in range(a)
    ]
    # The offsets have std 0.1 on 2 of 11 joints (RMS 0.04 over all joints); samples differ by
    # a sizeable part of that, and still follow the audio (error near the training error).
    assert min(pairwise) > 0.008, pairwise
    assert float((samples - mean).pow(2).mean().sqrt()) > 0.005
    truth = torch.tensor(val[0].targets, dtype=torch.float32)
    assert float((samples - truth).pow(2).mean()) < 0.5 * mean_baseline_mse(train, val)


def test_when_live_predictor_reseeded_expect_reproducible_and_seed_dependent_samples():
    torch.manual_seed(0)
    model = build_model("live", {}).eval()
    frames = np.random.default_rng(1).normal(size=(60, 26))
    predictor = model.streaming_predictor(seed=5, temperature=1.0)
    first = np.array([predictor.step(f) for f in frames])
    predictor.reset()
    np.testing.assert_array_equal(np.array([predictor.step(f) for f in frames]), first)
    predictor.reset(seed=6)
    other = np.array([predictor.step(f) for f in frames])
    assert np.abs(other - first).max() > 1e-3
    assert np.all((first >= 0) & (first <= 1))


@pytest.mark.parametrize(
    ("metadata", "problem"),
    [
        ("[" * 10_000 + "]" * 10_000, "training state metadata nests too deeply"),
        ("[1, 2]", "training state metadata is not a JSON object"),
        ('{"model": []}', "malformed training state"),
    ],
)
def test_when_a_training_state_is_crafted_expect_training_error_not_a_crash(
    tmp_path, metadata, problem
):
    from safetensors.torch import save_file

    state = tmp_path / "m.train-state.safetensors"
    save_file({"x": torch.zeros(1)}, str(state), metadata={"audio2pose_train_state": metadata})
    model = FramewiseMLP(MLPConfig())
    utterances = synthetic_utterances(2, 20, 0)
    with pytest.raises(TrainingError, match=problem):
        train_model(model, utterances[:1], utterances[1:], TrainSettings(max_epochs=1), state, True)
