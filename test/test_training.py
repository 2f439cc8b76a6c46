"""Training: learning-rate schedule of seed 002, resumable runs, data set splits."""

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors import safe_open

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.learning import training
from audio2pose_ros.learning.batches import TrainingError, prepare_training_data
from audio2pose_ros.learning.train_state import state_path_for
from audio2pose_ros.learning.training import TrainSettings, train_from_dataset, train_model
from audio2pose_ros.models.registry import build_model

sys.path.insert(0, str(Path(__file__).parent))
from synthetic_motion import synthetic_utterances, write_dataset

torch.set_num_threads(1)
FAST = {"window_frames": 100, "batch_size": 8, "show_progress": False}


def test_when_seed002_model_plateaus_expect_lr_divided_by_10_down_to_1e_5():
    train, val = synthetic_utterances(4, 200, 0), synthetic_utterances(1, 200, 1)
    torch.manual_seed(0)
    model = build_model("blstm", {"hidden_units": 8, "layers": 1})
    report = train_model(model, train, val, TrainSettings(max_epochs=300, patience=1, **FAST))
    stage = report.stages[0]
    # RMSprop from 1e-3; every plateau reloads the best weights and divides by 10; training
    # stops at the first plateau once 1e-5 is reached.
    assert stage.learning_rate == pytest.approx(1e-5)
    assert stage.epochs < 300
    assert model.recipe.optimizer == "rmsprop"
    assert build_model("mlp", {}).recipe.optimizer == "adam"


@pytest.mark.parametrize("name", ["lstm", "dae_gru"])
def test_when_run_interrupted_and_resumed_expect_same_result_as_uninterrupted(
    name, tmp_path, monkeypatch
):
    train, val = synthetic_utterances(4, 200, 0), synthetic_utterances(1, 200, 1)
    config = {"hidden_units": 8, "dense_layers": 1} if name == "dae_gru" else {}
    settings = TrainSettings(max_epochs=3, **FAST)

    def run(state, resume):
        torch.manual_seed(0)
        model = build_model(name, config)
        return model, train_model(model, train, val, settings, state, resume)

    straight, straight_report = run(None, False)
    state = tmp_path / "m.train-state.safetensors"
    original_save = training.save_state
    saves = []

    def save_then_crash(*args):
        original_save(*args)
        saves.append(1)
        if len(saves) == 2:  # killed after the second epoch
            raise KeyboardInterrupt

    monkeypatch.setattr(training, "save_state", save_then_crash)
    with pytest.raises(KeyboardInterrupt):
        run(state, False)
    monkeypatch.setattr(training, "save_state", original_save)
    resumed, resumed_report = run(state, True)
    assert resumed_report.val_loss == pytest.approx(straight_report.val_loss, rel=1e-6)
    for key, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[key], value)
    with safe_open(str(state), "pt") as stored:  # tensors + JSON metadata, no pickle
        assert "rng.torch" in set(stored.keys())
        assert "audio2pose_train_state" in stored.metadata()


def test_when_state_belongs_to_other_model_expect_training_error(tmp_path):
    train, val = synthetic_utterances(2, 200, 0), synthetic_utterances(1, 200, 1)
    state = tmp_path / "s.safetensors"
    torch.manual_seed(0)
    train_model(build_model("lstm", {}), train, val, TrainSettings(max_epochs=1, **FAST), state)
    with pytest.raises(TrainingError, match="training state of model lstm"):
        train_model(
            build_model("mlp", {}), train, val, TrainSettings(max_epochs=1, **FAST), state, True
        )


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory, robot):
    root = tmp_path_factory.mktemp("data") / "tiny"
    write_dataset(root, robot, {"train": 4, "test": 2}, seconds=2.0, seed=0)
    return Dataset.open(root, robot)


def test_when_no_validation_split_expect_clips_or_speakers_held_out(tiny_dataset, robot):
    by_clip = prepare_training_data(tiny_dataset, robot, FeatureSpec(), holdout="clip")
    assert len(by_clip.train) == 3
    assert len(by_clip.validation) == 1
    by_speaker = prepare_training_data(tiny_dataset, robot, FeatureSpec(), holdout="speaker")
    speakers = {c.clip_id: c.speaker for c in tiny_dataset.clips}
    held = {speakers[u.name] for u in by_speaker.validation}
    assert held.isdisjoint({speakers[u.name] for u in by_speaker.train})
    one = prepare_training_data(tiny_dataset, robot, FeatureSpec(), speaker="s0")
    assert {speakers[u.name] for u in one.train + one.validation} == {"s0"}
    assert np.all((one.train[0].targets >= 0) & (one.train[0].targets <= 1))
    with pytest.raises(TrainingError, match="no speaker 'nobody'"):
        prepare_training_data(tiny_dataset, robot, FeatureSpec(), speaker="nobody")


def test_when_finetuned_on_one_speaker_expect_subject_dependent_checkpoint(
    tiny_dataset, robot, tmp_path
):
    settings = TrainSettings(max_epochs=2, **FAST)
    si = tmp_path / "si.safetensors"
    train_from_dataset(tiny_dataset.root, si, robot, "mlp", settings=settings)
    sd, _ = train_from_dataset(
        tiny_dataset.root,
        tmp_path / "sd.safetensors",
        robot,
        speaker="s1",
        finetune=si,
        settings=settings,
    )
    assert sd.info["subject"] == "dependent"
    assert sd.info["finetuned_from"] == str(si)
    assert sd.info["speakers"] == ["s1"]
    # the base's speakers stay known (a rebuild's fold must not start from weights that saw them)
    assert sd.info["started_from"] == {"speakers": ["s0", "s1"]}
    assert state_path_for(tmp_path / "sd.safetensors").exists()
    with pytest.raises(TrainingError, match="differs from the fine-tuned"):
        train_from_dataset(
            tiny_dataset.root, tmp_path / "x.safetensors", robot, "lstm", finetune=si
        )
