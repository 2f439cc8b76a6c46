"""The default head over people: chosen on speakers held out, and kept as close as recorded."""

import json

import numpy as np
import pytest
import torch

from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.style import population
from audio2pose_ros.timebase import FRAME_RATE_HZ


def head_motion(robot, size, rate_hz, seconds=6.0, phase=0.0):
    """A head nodding at ``rate_hz`` with amplitude ``size`` (rad), every head frame known."""
    n = int(seconds * FRAME_RATE_HZ)
    t = np.arange(n)[:, None] / FRAME_RATE_HZ
    angles = np.tile(robot.neutral_rad, (n, 1))
    head = robot.group_mask("head")
    angles[:, head] += size * np.sin(2 * np.pi * rate_hz * t + phase + np.arange(head.sum()))
    mask = np.zeros(angles.shape, dtype=bool)
    mask[:, head] = True
    return angles, mask


def test_when_speakers_differ_expect_each_scored_at_the_style_chosen_without_them(robot):
    """Two calm speakers and a lively one: whoever is held out, the others choose for them."""
    sizes = {"a": 0.02, "b": 0.025, "c": 0.08}
    real = {s: [head_motion(robot, size, 0.5)] for s, size in sizes.items()}
    # "temperature" t: a head of size 0.01 t at the same pace
    generated = {
        s: {t: [head_motion(robot, 0.01 * t, 0.5, phase=1.0)] for t in (1.0, 2.0, 3.0, 8.0)}
        for s in sizes
    }
    result = population.nested(real, generated, robot)
    # without the lively one, the two calm ones choose a calm head; with it, a livelier one
    assert result.chosen["c"] == 2.0
    assert result.chosen["a"] > 2.0
    assert result.chosen["b"] > 2.0
    assert result.per_speaker["c"].log_size == pytest.approx(np.log(4.0), rel=0.05)
    assert set(result.per_speaker) == set(sizes)
    speed, accel = result.spread()
    assert speed >= 0.0
    assert accel >= 0.0


def test_when_a_speaker_is_held_out_expect_the_build_split_without_any_clip_of_theirs():
    """A fold trains as the shipped model does, less the held-out speaker's clips."""

    class Info:
        def __init__(self, clip_id, speaker, split="train"):
            self.clip_id, self.speaker, self.split = clip_id, speaker, split

    class Item:
        def __init__(self, *args):
            self.info = Info(*args)

    clips = [
        Item("g1", "grid1"),
        Item("g2", "grid2"),
        Item("o1", "obama"),
        Item("o2", "obama"),
        Item("l1", "lecturer"),
        Item("l2", "lecturer"),
        Item("l3", "lecturer", "test"),
    ]
    stopping = {"g2", "o1", "l2"}
    for speaker in ("grid1", "grid2", "obama"):
        training, validation = population.speaker_fold(clips, stopping, speaker)
        seen = {c.info.speaker for c in training + validation}
        assert speaker not in seen
        assert "lecturer" in seen  # the arms' clips train as in the build
        assert {c.info.clip_id for c in validation} <= stopping
        assert not {c.info.clip_id for c in training} & stopping
        assert "l3" not in {c.info.clip_id for c in training + validation}  # never trained on
        others = {c.info.clip_id for c in clips if c.info.speaker != speaker} - {"l3"}
        assert {c.info.clip_id for c in training + validation} == others


def test_when_a_fold_is_sampled_expect_the_shipped_sampler_on_the_folds_weights(robot):
    """A fold's model scores the sampler that ships (its settings), with the fold's weights."""
    from dataclasses import replace

    from audio2pose_ros.models.live_groups import SAMPLING_SETTINGS
    from audio2pose_ros.models.registry import build_model

    shipped = load_checkpoint(default_checkpoint_path(), robot=robot)
    config = shipped.model.config_dict()
    del config["velocity_limit"]  # as a fold trains: the configured sampler
    fresh = build_model("live_groups", config)
    fresh = fresh.with_sampling(first_temperature=1.0, first_burst=0.0, silence_temperature=0.3)
    assert fresh.config.velocity_limit != shipped.model.config.velocity_limit
    fold = replace(shipped, model=fresh)
    sampled = population.with_sampling_of(fold, shipped)
    for key in SAMPLING_SETTINGS:
        assert getattr(sampled.model.config, key) == getattr(shipped.model.config, key), key
    for name, tensor in sampled.model.state_dict().items():
        assert torch.equal(tensor, fresh.state_dict()[name]), name


@pytest.fixture(scope="module")
def recorded():
    path = default_checkpoint_path().parent / population.FIGURES_FILE
    return json.loads(path.read_text(encoding="utf-8"))


def test_when_the_default_speaks_expect_its_head_as_close_to_people_as_recorded(robot, recorded):
    """The shipped head against the pooled motion of every head speaker, on speech of others.

    ``population.json`` records, when the default's head was chosen over speakers held out, its
    figures on the bundled speech (speakers no step of the build used) against the people's
    pooled head motion, and a margin: the standard error over the held-out speakers of the
    held-out figure. A change that moves the head away from people by more fails here.
    """
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    figures = recorded["bundled_speech"]
    motions = population.bundled_motions(checkpoint, figures["seeds"])
    h_speed, h_accel, ratio = population.against_reference(motions, recorded, robot)
    margin = figures["margin"]
    assert 0.0 < margin < 0.1  # a spread, not a blank cheque
    assert h_speed <= figures["h_speed"] + margin
    assert h_accel <= figures["h_accel"] + margin
    assert abs(np.log(ratio / figures["size_ratio"])) <= margin
    assert checkpoint.model.config.first_temperature == recorded["head_temperature"]


def test_when_the_card_ships_expect_its_description_to_be_the_shipped_checkpoints(robot):
    """The card states the temperatures and configuration of the model it ships with.

    The population step changes the shipped head's temperature after the build wrote the card;
    the card's "What it is" section must follow, or it describes a model nobody gets.
    """
    from audio2pose_ros.learning.model_card import WHAT_BEGIN, WHAT_END, what_it_is
    from audio2pose_ros.learning.style_card import section_of

    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    card = (default_checkpoint_path().parent / "MODEL_CARD.md").read_text(encoding="utf-8")
    section = section_of(card, WHAT_BEGIN, WHAT_END)
    assert section, "the card has no generated 'What it is' section"
    assert what_it_is(checkpoint) in section
    config = checkpoint.model.config_dict()
    assert f"samples at temperature\n{config['first_temperature']:g} " in section
