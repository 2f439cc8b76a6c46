"""The rebuild started from a pretrained checkpoint, and the folds that must not start from it.

A model pretrained on many clips of one source (for example GRID's speaker s1, 50 minutes of a
still reader) may start every training of the default model's rebuild, except a fold that holds
out a source the pretrained model learned from: that fold is scored on the held-out source, so
its weights must never have seen it.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import pytest
import torch
from synthetic_motion import synthetic_clips
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.checkpoints.torch_io import save_checkpoint
from audio2pose_ros.data.dataset import ClipInfo
from audio2pose_ros.learning import training
from audio2pose_ros.learning.batches import TrainingError
from audio2pose_ros.learning.model_card import _started_from
from audio2pose_ros.learning.source_holdout import (
    GRID,
    LECTURE,
    OBAMA,
    SHIPPED,
    holdout_tasks,
    learned_sources,
)
from audio2pose_ros.learning.training import TrainSettings, train_on_clips

torch.set_num_threads(1)

SETTINGS = TrainSettings(max_epochs=1, batch_size=4, show_progress=False)


@pytest.fixture(scope="module")
def clips(tmp_path_factory, robot):
    root = tmp_path_factory.mktemp("start") / "data"
    return synthetic_clips(root, robot, {"train": 3, "validation": 1}, seconds=2.0, seed=3)


@pytest.fixture(scope="module")
def pretrained(clips, robot):
    train = [c for c in clips if c.info.split == "train"]
    validation = [c for c in clips if c.info.split == "validation"]
    return train_on_clips("live_groups", train, robot, SETTINGS, None, validation)[0]


def with_speakers(checkpoint, *speakers: str, started_from: dict | None = None):
    info = {**checkpoint.info, "speakers": list(speakers)}
    if started_from is not None:
        info["started_from"] = started_from
    return replace(checkpoint, info=info)


def state(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def test_when_training_from_a_checkpoint_expect_its_weights_first_and_the_checkpoint_unchanged(
    clips, pretrained, robot, monkeypatch
):
    given = state(pretrained.model)
    at_start: list[dict[str, torch.Tensor]] = []
    real_train_model = training.train_model

    def spy(model, *args, **kwargs):
        at_start.append(state(model))
        return real_train_model(model, *args, **kwargs)

    monkeypatch.setattr(training, "train_model", spy)
    train = [c for c in clips if c.info.split == "train"]
    started, _ = train_on_clips("live_groups", train, robot, SETTINGS, start=pretrained)
    fresh, _ = train_on_clips("live_groups", train, robot, SETTINGS)

    started_state, fresh_state = at_start
    assert all(torch.equal(started_state[k], given[k]) for k in given)
    assert not all(torch.equal(fresh_state[k], given[k]) for k in given)
    assert all(torch.equal(v, given[k]) for k, v in pretrained.model.state_dict().items())
    assert started.model is not pretrained.model
    assert started.info["started_from"] == {"speakers": pretrained.info["speakers"]}
    assert "started_from" not in fresh.info


def test_when_the_checkpoint_is_another_model_family_expect_a_training_error(
    clips, pretrained, robot
):
    train = [c for c in clips if c.info.split == "train"]
    with pytest.raises(TrainingError, match="cannot start mlp from a live_groups checkpoint"):
        train_on_clips("mlp", train, robot, SETTINGS, start=pretrained)


def test_when_a_checkpoint_started_from_another_expect_the_sources_of_both(pretrained):
    inner = {"speakers": ["grid_s1"]}
    outer = with_speakers(pretrained, "obama", started_from=inner)
    assert learned_sources(outer) == {GRID, OBAMA}
    assert learned_sources(with_speakers(pretrained, "someone")) == {"someone"}


@pytest.mark.parametrize(
    ("speakers", "fresh"),
    [
        (("grid_s1",), {GRID}),
        (("obama", "grid_bbaf2n"), {GRID, OBAMA}),
        (("lewin",), set()),
        (("a_new_speaker",), set()),
    ],
)
def test_when_the_rebuild_starts_from_a_checkpoint_expect_folds_of_its_sources_from_new_weights(
    clips, pretrained, robot, speakers, fresh
):
    heads = [
        replace(clips[0], info=ClipInfo("grid_a", "grid_a", "GRID", "CC BY 4.0")),
        replace(clips[1], info=ClipInfo("obama_a", "obama", "Obama", "public domain")),
        replace(clips[2], info=ClipInfo("obama_b", "obama", "Obama", "public domain")),
    ]
    start = with_speakers(pretrained, *speakers)
    tasks = holdout_tasks(heads, {"obama_b"}, robot, SETTINGS, 1, 0, start)
    assert [t.name for t in tasks] == [SHIPPED, GRID, OBAMA]
    for task in tasks:
        assert (task.start is None) == (task.name in fresh), task.name
    assert all(t.start is None for t in holdout_tasks(heads, {"obama_b"}, robot, SETTINGS, 1, 0))


def test_when_a_fold_started_fresh_expect_the_card_to_say_which_and_whose_data_the_start_held(
    pretrained,
):
    started = {"speakers": ["grid_s1"]}
    results = [
        SimpleNamespace(
            name=SHIPPED, checkpoint=with_speakers(pretrained, "obama", started_from=started)
        ),
        SimpleNamespace(name=GRID, checkpoint=with_speakers(pretrained, "obama")),
        SimpleNamespace(
            name=OBAMA, checkpoint=with_speakers(pretrained, "x", started_from=started)
        ),
    ]
    text = _started_from(results)
    assert "shipped, Obama started from a checkpoint" in text
    assert "1 speaker(s) (grid_s1)" in text
    assert "GRID started from new weights: each holds out a source" in text
    assert _started_from(results[1:2]) == ""
    assert LECTURE not in text


def test_when_build_default_is_given_a_bad_start_expect_one_line_before_any_import(
    clips, pretrained, robot, tmp_path, capsys
):
    heads = tmp_path / "talking_heads"
    heads.mkdir()
    lecture = tmp_path / "lecture.webm"
    lecture.write_bytes(b"")
    train = [c for c in clips if c.info.split == "train"]
    mlp = tmp_path / "mlp.safetensors"
    save_checkpoint(mlp, train_on_clips("mlp", train, robot, SETTINGS)[0])
    live = tmp_path / "live.safetensors"
    save_checkpoint(live, pretrained)
    out = tmp_path / "out"
    base = ("dataset", "build-default", heads, "-o", out, "--lecture", lecture)

    status, err = audio2pose(capsys, *base, "--start", mlp)
    assert status == 2
    assert_one_line(err, "a mlp checkpoint; the rebuild trains live_groups")
    status, err = audio2pose(capsys, *base, "--start", tmp_path / "missing.safetensors")
    assert status == 1
    assert_one_line(err, "missing.safetensors")
    status, err = audio2pose(capsys, *base, "--arms", "prosody", "--start", live)
    assert status == 2
    assert_one_line(err, "--start needs --arms learned")
    assert not out.exists() or not any(out.iterdir())
