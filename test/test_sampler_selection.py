"""Sampling settings of live_groups chosen on validation clips, in the build and in every fold."""

import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch
from synthetic_motion import synthetic_clips, write_dataset

from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.learning import sampler_selection
from audio2pose_ros.learning.evaluation import loso_predictions
from audio2pose_ros.learning.realism import speed_percentiles
from audio2pose_ros.learning.sampler_selection import (
    BODY_BUDGET_PCT,
    BURSTS,
    CORRELATIONS,
    PAUSE_MARGIN,
    PAUSE_TARGETS,
    SILENCE_TEMPERATURES,
    TEMPERATURES,
    choose_sampling,
    reference_percentiles,
    score,
    select_sampling,
    tail_distance,
)
from audio2pose_ros.learning.sampling_folds import FoldTuner, speaker_folds
from audio2pose_ros.learning.training import TrainSettings, train_on_clips
from audio2pose_ros.models.live_groups import SAMPLING_SETTINGS
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.offline.synthesis import synthesize_samples

torch.set_num_threads(1)

# The shipped grid, and the cut of it these tests choose on: 12 of its 63 settings (each a
# sampling of every validation clip). The tests check how a choice is made, which does not
# depend on the grid's size; the loso test's worker processes import the shipped grid.
SHIPPED_GRID = {"TEMPERATURES": TEMPERATURES, "BURSTS": BURSTS, "CORRELATIONS": CORRELATIONS}
TEST_GRID = {"TEMPERATURES": (0.5, 1.5, 3.0), "BURSTS": (0.0, 1.2), "CORRELATIONS": (0.95, 0.975)}


def use_grid(patch: pytest.MonkeyPatch, grid: dict[str, tuple[float, ...]]) -> None:
    for name, values in grid.items():
        patch.setattr(sampler_selection, name, values)


@pytest.fixture(scope="module", autouse=True)
def test_grid():
    with pytest.MonkeyPatch.context() as patch:
        use_grid(patch, TEST_GRID)
        yield


def grid_size() -> int:
    return (
        len(sampler_selection.TEMPERATURES)
        * len(sampler_selection.BURSTS)
        * len(sampler_selection.CORRELATIONS)
    )


@pytest.fixture(scope="module")
def clips(tmp_path_factory, robot):
    root = tmp_path_factory.mktemp("selection") / "data"
    return synthetic_clips(root, robot, {"train": 4, "validation": 2}, seconds=2.0, seed=5)


@pytest.fixture(scope="module")
def checkpoint(clips, robot):
    train = [c for c in clips if c.info.split == "train"]
    settings = TrainSettings(max_epochs=2, batch_size=4, show_progress=False)
    return train_on_clips("live_groups", train, robot, settings)[0]


@pytest.fixture(scope="module")
def selected(checkpoint, clips, robot):
    """The checkpoint's choice on its validation clips: (validation clips, tuned, choice)."""
    validation = [c for c in clips if c.info.split == "validation"]
    return (validation, *select_sampling(checkpoint, validation, robot, n_seeds=2))


def test_when_changing_sampling_settings_expect_the_same_weights_and_nothing_else_changeable():
    torch.manual_seed(0)
    model = build_model("live_groups", {"n_features": 4, "n_joints": 5, "hidden_units": 6})
    tuned = model.with_sampling(first_temperature=1.7, silence_temperature=0.2)
    assert (tuned.config.first_temperature, tuned.config.silence_temperature) == (1.7, 0.2)
    assert tuned.config.second_temperature == model.config.second_temperature
    for key, value in model.state_dict().items():
        torch.testing.assert_close(tuned.state_dict()[key], value)
    with pytest.raises(ConfigurationError, match="hidden_units"):
        model.with_sampling(hidden_units=3)


def part_scores(trials, setting, robot):
    """Joint-count weighted score per tried (correlation, burst, temperature) of one part."""
    out = {}
    for t in trials:
        if t.setting == setting:
            out.setdefault((t.correlation, t.burst, t.value), []).append(t)
    return {
        key: np.average(
            [score(t.measures) for t in rows],
            weights=[robot.group_mask(t.group).sum() for t in rows],
        )
        for key, rows in out.items()
    }


def test_when_selecting_expect_each_part_at_its_best_validation_score_and_the_liveliest_gate(
    checkpoint, selected, robot
):
    validation, tuned, choice = selected
    parts = {"first_temperature": "first_burst", "second_temperature": "second_burst"}
    scores = {setting: part_scores(choice.trials, setting, robot) for setting in parts}
    shared = {
        s: {k: v for k, v in at.items() if not (isinstance(k[1], tuple) or isinstance(k[2], tuple))}
        for s, at in scores.items()
    }
    for setting in parts:
        assert len(shared[setting]) == grid_size() < 42
    # the head's burstiness is then also tried per joint (pitch, yaw), where the shared grid's
    # best correlation and temperature were, and at the temperatures beside it
    # the arms: one burst for all; then the hip tries every other temperature of the grid,
    # with the arms at the grid's best (a part's smaller groups get their own temperature)
    per_group = {k for k in scores["second_temperature"] if isinstance(k[2], tuple)}
    assert len(scores["second_temperature"]) == grid_size() + len(per_group)
    correlation, _, value = min(shared["first_temperature"], key=shared["first_temperature"].get)
    grid, bursts = sampler_selection.TEMPERATURES, sampler_selection.BURSTS
    beside = grid[max(grid.index(value) - 1, 0) : grid.index(value) + 2]
    per_joint = set(scores["first_temperature"]) - set(shared["first_temperature"])
    assert per_joint == {
        (correlation, (a, b), t) for a in bursts for b in bursts if a != b for t in beside
    }

    # a part's cost: how far over the arms' body budget, then its score (lowest wins)
    over = {
        (t.correlation, t.burst, t.value): max(0.0, t.measures["near body %"] - BODY_BUDGET_PCT)
        for t in choice.trials
        if t.setting == "second_temperature" and t.group == "arms"
    }
    costs = {
        s: {k: (over.get(k, 0.0) if s == "second_temperature" else 0.0, v) for k, v in at.items()}
        for s, at in scores.items()
    }

    arms = robot.group_mask("arms")[checkpoint.model.groups[1]]
    arm_cost = costs["second_temperature"]
    arm_best = min(shared["second_temperature"], key=arm_cost.get)  # the grid's choice
    assert {(k[0], k[1], tuple(np.asarray(k[2])[arms])) for k in per_group} == {
        (arm_best[0], arm_best[1], (arm_best[2],) * int(arms.sum()))
    }
    hip = {float(np.asarray(k[2])[~arms][0]) for k in per_group}
    assert hip == set(sampler_selection.TEMPERATURES) - {arm_best[2]}

    correlations = {
        "first_temperature": "first_correlation",
        "second_temperature": "second_correlation",
    }
    for setting, burst in parts.items():
        chosen = (
            choice.settings[correlations[setting]],
            choice.settings[burst],
            choice.settings[setting],
        )
        assert chosen == min(costs[setting], key=costs[setting].get)
    assert "noise_correlation" not in choice.settings  # each part has its own
    met = [
        rest
        for rest in SILENCE_TEMPERATURES
        if all(
            t.measures["speech/pause speed"] >= PAUSE_MARGIN * PAUSE_TARGETS[t.group]
            for t in choice.trials
            if t.setting == "silence_temperature" and t.value == rest
        )
        and any(t.value == rest for t in choice.trials if t.setting == "silence_temperature")
    ]
    assert choice.settings["silence_temperature"] == (met[0] if met else SILENCE_TEMPERATURES[-1])
    config = tuned.model.config
    assert {k: getattr(config, k) for k in choice.settings} == choice.settings
    assert tuned.info["sampling_chosen_on"] == [c.info.clip_id for c in validation]
    for key, value in checkpoint.model.state_dict().items():
        torch.testing.assert_close(tuned.model.state_dict()[key], value)
    starred = [line.split() for line in choice.table().splitlines()[2:] if "*" in line]
    chosen_part_rows = {(row[0], row[4]) for row in starred if row[0] in parts}
    assert chosen_part_rows == {(t.setting, t.group) for t in choice.trials if t.setting in parts}


def amplified(clip: Clip, joints: np.ndarray, gain: float) -> Clip:
    angles = clip.angles_rad.copy()
    centre = angles[:, joints].mean(axis=0)
    angles[:, joints] = centre + gain * (angles[:, joints] - centre)
    return replace(clip, angles_rad=angles)


def test_when_the_validation_head_moves_more_expect_a_head_temperature_at_least_as_high(
    checkpoint, selected, robot
):
    head = robot.group_mask("head")
    validation, _, small = selected
    _, large = select_sampling(checkpoint, [amplified(c, head, 4.0) for c in validation], robot, 2)
    assert large.settings["first_temperature"] >= small.settings["first_temperature"]
    assert large.settings["first_temperature"] > TEMPERATURES[0]


def test_when_a_model_is_not_a_grouped_sampler_expect_it_unchanged(clips, robot):
    train = [c for c in clips if c.info.split == "train"]
    mlp, _ = train_on_clips("mlp", train, robot, TrainSettings(max_epochs=1, show_progress=False))
    same, choice = select_sampling(mlp, clips[-1:], robot)
    assert same is mlp
    assert choice.settings == {}


def test_when_evaluating_leave_one_speaker_out_expect_tuning_on_the_folds_training_side_only(
    tmp_path, robot
):
    dataset = write_dataset(tmp_path / "loso", robot, {"train": 4}, seconds=1.5, seed=2)
    speakers = sorted({c.speaker for c in dataset.clips})
    seen = []

    def tune(fold, training):
        seen.append(training)
        return replace(fold, model=fold.model.with_sampling(first_temperature=0.0))

    settings = TrainSettings(max_epochs=1, batch_size=4, show_progress=False)
    clips, predictions, _ = loso_predictions(
        dataset, robot, ["live_groups"], settings, n_samples=2, tune=tune
    )
    assert len(seen) == len(speakers)
    for held_out, training in zip(speakers, seen, strict=True):
        assert training
        assert held_out not in {c.info.speaker for c in training}
    head = robot.group_mask("head")
    for clip in clips:  # the tuned checkpoint predicts: a head at temperature 0 ignores the seed
        first, second = predictions["live_groups (LOSO)"][clip.info.clip_id]
        np.testing.assert_array_equal(first[:, head], second[:, head])


def test_when_splitting_by_speaker_expect_every_speaker_to_validate_once_and_never_train_there(
    clips,
):
    renamed = [replace(c, info=replace(c.info, speaker=f"p{i % 5}")) for i, c in enumerate(clips)]
    folds = speaker_folds(renamed, 3)
    assert len(folds) == 3
    validating = [s for _, v in folds for s in sorted({c.info.speaker for c in v})]
    assert sorted(validating) == [f"p{i}" for i in range(5)]
    for training, validation in folds:
        assert not {c.info.speaker for c in training} & {c.info.speaker for c in validation}
        assert len(training) + len(validation) == len(renamed)
    assert speaker_folds(renamed, 3) == folds
    assert speaker_folds(renamed[:1], 3) == []


def test_when_folds_observe_different_groups_expect_each_part_scored_on_its_own_groups(
    checkpoint, clips, robot
):
    head = robot.group_mask("head")
    validation = [c for c in clips if c.info.split == "validation"]
    heads_only = [replace(c, mask=c.mask & head) for c in validation[:1]]
    body_only = [replace(c, mask=c.mask & ~head) for c in validation[1:]]
    choice = choose_sampling([(checkpoint, heads_only), (checkpoint, body_only)], robot, 2)
    groups = {(t.setting, t.group) for t in choice.trials if t.setting != "silence_temperature"}
    assert groups == {
        ("first_temperature", "head"),
        ("second_temperature", "arms"),
        ("second_temperature", "hip"),
    }
    assert choice.n_models == 2
    assert choice.validation == tuple(c.info.clip_id for c in heads_only + body_only)


def test_when_no_clip_observes_the_arm_part_expect_the_head_chosen_and_the_arm_part_untouched(
    checkpoint, clips, robot
):
    """Recordings of talking heads only: the part of the arms and hip has nothing to score."""
    head = robot.group_mask("head")
    heads_only = [replace(c, mask=c.mask & head) for c in clips if c.info.split == "validation"]
    choice = choose_sampling([(checkpoint, heads_only)], robot, 2)
    parts = {t.setting for t in choice.trials if t.setting != "silence_temperature"}
    assert parts == {"first_temperature"}
    assert "second_temperature" not in choice.settings
    assert choice.settings["first_temperature"] in sampler_selection.TEMPERATURES


def test_when_a_fold_is_tuned_expect_a_choice_made_on_its_training_speakers_and_applied(
    tmp_path, checkpoint, robot
):
    # the fold's training speakers: four clips of two speakers, shorter than the module's
    # (the tuner samples each at every setting of the grid, N_SEEDS times)
    train = synthetic_clips(tmp_path / "data", robot, {"train": 4}, seconds=1.0, seed=5)
    tune = FoldTuner(robot, TrainSettings(max_epochs=1, batch_size=4, show_progress=False))
    tuned = tune(checkpoint, train)
    note = tuned.info["sampling_choice"]
    assert f"on {len(train)} validation clips" in note
    listed = dict(item.split(" = ") for item in note.split(" (on ")[0].split(", "))
    assert {"first_temperature", "second_temperature", "silence_temperature"} <= set(listed)
    assert set(listed) <= set(SAMPLING_SETTINGS)
    for name, value in listed.items():  # a per-joint burstiness reads "0/1.2"
        applied = np.atleast_1d(getattr(tuned.model.config, name))
        np.testing.assert_allclose([float(v) for v in value.split("/")], applied, rtol=1e-5)
    assert set(tuned.info["sampling_chosen_on"]) <= {c.info.clip_id for c in train}
    mlp, _ = train_on_clips("mlp", train, robot, TrainSettings(max_epochs=1, show_progress=False))
    assert tune(mlp, train) is mlp
    assert pickle.loads(pickle.dumps(tune)) == tune  # workers receive it


def test_when_loso_folds_train_in_two_processes_expect_the_serial_results(
    tmp_path, robot, monkeypatch
):
    use_grid(monkeypatch, SHIPPED_GRID)  # what the spawned workers import
    dataset = write_dataset(tmp_path / "loso", robot, {"train": 4}, seconds=1.0, seed=4)
    settings = TrainSettings(max_epochs=2, batch_size=4, show_progress=False)
    serial_choices, parallel_choices = {}, {}
    tune = FoldTuner(robot, settings)
    _, serial, _ = loso_predictions(
        dataset, robot, ["live_groups"], settings, 2, None, tune, 1, serial_choices
    )
    _, parallel, _ = loso_predictions(
        dataset, robot, ["live_groups"], settings, 2, None, tune, 2, parallel_choices
    )
    assert serial_choices.keys() == parallel_choices.keys() == set(dataset.speakers)
    for clip_id, samples in serial["live_groups (LOSO)"].items():
        for a, b in zip(samples, parallel["live_groups (LOSO)"][clip_id], strict=True):
            np.testing.assert_allclose(a, b, atol=1e-3)


@pytest.mark.parametrize(
    ("measure", "group", "budget", "other"),
    [
        ("near body %", "arms", "BODY_BUDGET_PCT", "GATE_BUDGET_PCT"),
        ("gate refused %", None, "GATE_BUDGET_PCT", "BODY_BUDGET_PCT"),
    ],
)
def test_when_arm_settings_lean_on_a_safety_stage_expect_the_best_setting_within_its_budget(
    checkpoint, selected, robot, monkeypatch, measure, group, budget, other
):
    """The guard and the filter's gate stay on the robot; the sampling settings keep them idle.

    Settings whose arms come near the body, or whose raw steps the filter's gate would refuse,
    lose to every setting within budget. The budget is set at the median of the measure over
    the arm settings, so some settings are over it.
    """
    validation, _, free = selected
    if measure == "gate refused %":  # the sampler's own velocity limit leaves the gate idle
        assert all(t.measures.get(measure, 0.0) == 0.0 for t in free.trials)
        monkeypatch.setattr(sampler_selection, "VELOCITY_LIMIT", 0.0)  # as a model without it
        free = select_sampling(checkpoint, validation, robot, n_seeds=2)[1]
    per_setting: dict = {}
    for t in free.trials:
        if t.setting == "second_temperature" and group in (None, t.group):
            key = (t.correlation, t.burst, t.value)
            per_setting[key] = per_setting.get(key, 0.0) + t.measures[measure]
    assert grid_size() <= len(per_setting) < 42
    assert len(set(per_setting.values())) > 1, f"every arm setting has the same {measure}"
    limit = float(np.median(list(per_setting.values())))
    monkeypatch.setattr(sampler_selection, budget, limit)
    monkeypatch.setattr(sampler_selection, other, 100.0)
    chosen, best, table = _arm_choice(
        checkpoint, validation, robot, lambda k: per_setting[k] <= limit
    )
    assert chosen == best
    assert measure in table


def _arm_choice(checkpoint, validation, robot, allowed):
    """Select again: (the arm part's chosen setting, the best-scoring allowed one, the table)."""
    _, bound = select_sampling(checkpoint, validation, robot, n_seeds=2)
    settings = bound.settings
    chosen = (
        settings["second_correlation"],
        settings["second_burst"],
        settings["second_temperature"],
    )
    scores = part_scores(bound.trials, "second_temperature", robot)
    within = {k: v for k, v in scores.items() if allowed(k)}
    assert within, "the median budget leaves no setting"
    return chosen, min(within, key=within.get), bound.table()


def test_when_speech_without_arm_motion_is_given_expect_it_counted_for_the_body_budget_only(
    checkpoint, clips, selected, robot
):
    """The arms learned from one lecturer: their body budget is checked on other speech too."""
    validation, _, free = selected
    others = [c.audio for c in clips if c.info.split == "train"][:2]
    more = choose_sampling([(checkpoint, validation)], robot, 2, body_audio=others)

    def arms(choice, key):
        return {
            (t.correlation, t.burst, t.value): t.measures.get(key)
            for t in choice.trials
            if t.setting == "second_temperature" and t.group == "arms"
        }

    for key in ("H speed", "H accel", "std ratio"):  # nothing to compare their motion with
        assert arms(more, key) == arms(free, key)
    near_free, near_more = arms(free, "near body %"), arms(more, "near body %")
    assert near_more != near_free, "the other speech was not sampled"
    assert more.validation == free.validation
    assert more.body_seconds == pytest.approx(sum(len(a) for a in others) / 16000)
    assert "body budget also on" in more.summary()
    assert free.body_seconds == 0.0


def test_when_a_holdout_task_chooses_expect_its_unlabelled_training_speech_in_the_body_budget(
    clips, robot, monkeypatch
):
    from audio2pose_ros.learning import source_holdout

    arms = robot.group_mask("arms")
    train = [c for c in clips if c.info.split == "train"]
    heads = [replace(c, mask=c.mask & ~arms) for c in train[:2]]  # talking heads: no arms
    given: list = []

    references: list = []

    styles: list = []

    def spy(folds, robot, n_seeds=2, body_audio=(), reference=(), style_of=None):
        given.extend(body_audio)
        references.append(reference)
        styles.append(style_of)
        return choose_sampling(folds, robot, 1)

    monkeypatch.setattr(source_holdout, "choose_sampling", spy)
    task = source_holdout.HoldoutTask(
        "shipped",
        tuple(heads + train[2:]),
        tuple(c for c in clips if c.info.split == "validation"),
        scored := (train[0],),
        robot,
        TrainSettings(max_epochs=1, batch_size=4, show_progress=False),
        2,
        3,
    )
    result = task()
    # the scored clip is sampled once: the offline synthesis and the unsmoothed poses the
    # command path's tables filter come from the same draws of seeds 3 and 4
    audio = scored[0].audio
    for smooth, got in ((True, result.samples), (False, result.raw)):
        expected = synthesize_samples(result.checkpoint, audio, range(3, 5), smooth)
        assert len(got[scored[0].info.clip_id]) == 2
        for mine, theirs in zip(got[scored[0].info.clip_id], expected, strict=True):
            np.testing.assert_allclose(mine, theirs, atol=1e-2)  # coal's search history: <1e-2
    first = result.raw[scored[0].info.clip_id][0]
    assert (
        np.abs(np.diff(first, 2, axis=0)).mean()
        > 2 * np.abs(np.diff(result.samples[scored[0].info.clip_id][0], 2, axis=0)).mean()
    )  # unsmoothed
    assert len(given) == len(heads)
    for audio, clip in zip(given, heads, strict=True):
        assert audio is clip.audio
    # the head's percentile targets and the arms' calm budget: real motion of the training and
    # validation clips, each recording source a style of its own
    (reference,) = references
    assert {c.info.clip_id for c in reference} == {
        c.info.clip_id for c in task.training + task.validation
    }
    assert styles == [source_holdout.clip_style]


def test_when_validation_holds_a_reader_and_an_addresser_expect_the_head_sized_between_them(
    clips, robot
):
    """No model can guess a new speaker's style: the size term is least between the sources."""
    from audio2pose_ros.learning.sampler_selection import between_styles
    from audio2pose_ros.learning.source_holdout import clip_style

    def as_speaker(clip, speaker):
        return replace(clip, info=replace(clip.info, speaker=speaker))

    clip = clips[0]
    assert clip_style(as_speaker(clip, "grid_s3")) == "GRID"
    assert clip_style(as_speaker(clip, "obama")) == "Obama"
    assert clip_style(as_speaker(clip, "someone")) == "someone"  # a user's speaker: its own
    reader = {"H speed": 0.2, "H accel": 0.4, "std ratio": 4.0}  # the model moves 4x the reader
    addresser = {"H speed": 0.4, "H accel": 0.2, "std ratio": 0.25}  # ... and 1/4 the addresser
    both = between_styles([reader, addresser])
    assert both["H speed"] == pytest.approx(0.3)
    assert both["H accel"] == pytest.approx(0.3)
    assert both["std ratio"] == pytest.approx(1.0)  # the geometric mean of the two sizes
    assert score(both) < score(reader)
    assert score(both) < score(addresser)
    assert between_styles([reader]) == reader


def test_when_styles_are_given_expect_the_head_percentile_targets_between_them(clips, robot):
    head = robot.group_mask("head")
    still, lively = clips[0], clips[1]
    neutral = robot.neutral_rad[head]
    still = replace(still, angles_rad=still.angles_rad.copy())
    still.angles_rad[:, head] = neutral + 0.25 * (still.angles_rad[:, head] - neutral)
    one = reference_percentiles([still], robot)["head"]
    other = reference_percentiles([lively], robot)["head"]
    between = reference_percentiles([still, lively], robot, lambda c: c.info.clip_id)["head"]
    for k in range(2):
        np.testing.assert_allclose(between[k], np.sqrt(one[k] * other[k]), rtol=1e-9)


@pytest.mark.slow  # every arm setting is commanded through the filter, twice
def test_when_arm_settings_are_livelier_than_people_commanded_expect_the_best_within_the_calm(
    checkpoint, selected, robot, monkeypatch
):
    """Arms at the acceleration limit or above the shoulders more often than people lose."""
    from audio2pose_ros.learning.arm_calm import CALM_KEYS
    from audio2pose_ros.robot.body import BodyModel

    validation, _, _ = selected
    # every arm setting is also commanded through the filter: a smaller grid
    use_grid(
        monkeypatch, {"TEMPERATURES": (0.5, 1.5, 3.0), "BURSTS": (0.0,), "CORRELATIONS": (0.95,)}
    )
    people = sampler_selection.calm_reference(validation, robot, BodyModel.load(robot))
    assert set(people) == set(CALM_KEYS)  # the people's figures, commanded
    # a budget no setting meets: every arm setting's figures are measured
    unmet = dict.fromkeys(CALM_KEYS, -1.0)
    with monkeypatch.context() as patch:
        patch.setattr(sampler_selection, "calm_reference", lambda *args: unmet)
        free = choose_sampling([(checkpoint, validation)], robot, 2, reference=validation)
    assert "calm budget" in free.summary()
    assert "at limit %" in free.table()
    arm_trials = [t for t in free.trials if t.setting == "second_temperature" and t.group == "arms"]
    assert all("at limit %" in t.measures for t in arm_trials)
    per_setting = {(t.correlation, t.burst, t.value): t.measures["at limit %"] for t in arm_trials}
    assert len(set(per_setting.values())) > 1, "every arm setting is as calm"
    limit = float(np.median(list(per_setting.values())))
    budget = {"at limit %": limit, "wrist up %": 100.0, "wrist high %": 100.0}
    monkeypatch.setattr(sampler_selection, "calm_reference", lambda *args: budget)
    monkeypatch.setattr(sampler_selection, "BODY_BUDGET_PCT", 100.0)
    monkeypatch.setattr(sampler_selection, "GATE_BUDGET_PCT", 100.0)
    bound = choose_sampling([(checkpoint, validation)], robot, 2, reference=validation)
    settings = bound.settings
    chosen = (
        settings["second_correlation"],
        settings["second_burst"],
        settings["second_temperature"],
    )
    scores = part_scores(bound.trials, "second_temperature", robot)
    within = {k: v for k, v in scores.items() if per_setting.get(k, limit) <= limit}
    assert chosen == min(within, key=within.get)
    assert per_setting[chosen] <= limit


def test_when_a_later_sample_raises_the_arms_expect_the_calm_figures_to_count_it(
    checkpoint, selected, robot, monkeypatch
):
    """The robot runs with any seed: a raised arm in any sample drawn counts, not the first's."""
    from audio2pose_ros.offline import synthesis
    from audio2pose_ros.robot.body import BodyModel

    validation, _, _ = selected
    use_grid(monkeypatch, {"TEMPERATURES": (0.5,), "BURSTS": (0.0,), "CORRELATIONS": (0.95,)})
    arms = robot.group_mask("arms")
    raised = robot.neutral_rad.copy()
    for side in "LR":
        raised[robot.names.index(f"{side}ShoulderPitch")] = -1.2  # forward and up
    heights = BodyModel.load(robot).wrist_heights(np.stack([robot.neutral_rad, raised]))
    assert (heights[0] < 0.0).all()  # arms down
    assert (heights[1] > 0.1).all()  # well above the shoulders
    sample = synthesis.sample_normalized

    def last_one_raised(checkpoint, frames, n_samples=1, seed=0, temperature=1.0):
        poses = sample(checkpoint, frames, n_samples, seed, temperature)
        poses[0][:, arms] = robot.normalize(robot.neutral_rad)[arms]  # the first: arms down
        poses[-1][:, arms] = robot.normalize(raised)[arms]  # the last holds them up
        return poses

    monkeypatch.setattr(synthesis, "sample_normalized", last_one_raised)
    choice = choose_sampling([(checkpoint, validation)], robot, 2, reference=validation)
    calm = [t.measures for t in choice.trials if t.group == "arms" and "wrist up %" in t.measures]
    assert calm
    for measures in calm:  # the worst sample's figures: the raised one, in every frame
        assert measures["wrist up %"] == pytest.approx(100.0)
        assert measures["wrist high %"] == pytest.approx(100.0)


def test_when_ranking_settings_expect_calm_figures_measured_only_where_they_can_decide(robot):
    """Commanding is slow: a setting that loses whatever its calm figures is not commanded."""
    from audio2pose_ros.learning.sampler_selection import _best, _Calm, _Scored

    measured = []

    class Counted(_Calm):
        def overrun(self, budget):
            measured.append(self.arms["at limit %"])
            return super().overrun(budget)

    def tried(over, total, at_limit):
        calm = Counted(robot, None, [], {"at limit %": at_limit})  # figures already known
        return _Scored(over, total, 0.95, 0.0, 1.0, calm)

    trials = [tried(0.0, 0.3, 9.0), tried(0.0, 0.5, 4.0), tried(0.0, 0.4, 6.0)]
    trials += [tried(0.0, 0.9, 1.0), tried(2.0, 0.1, 0.0), tried(0.0, 0.5, 4.0)]
    budget = {"at limit %": 5.0}
    # measuring all: over the budgets 4, 0, 1, 0, 2, 0 points; the lowest score among the
    # zeros is 0.5, first tried wins the tie
    assert _best(trials, budget) is trials[1]
    assert measured == [9.0, 6.0, 4.0]  # by score, until no later one can win
    assert _best(trials[:1], budget) is trials[0]  # none within: the least over wins


def _head_motion(seconds: float, nods: bool, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(frames, 2) head angles: slow drift, with or without quick nods (0.15 s, 0.1 rad)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 100)
    angles = np.cumsum(rng.normal(0.0, 0.001, (n, 2)), axis=0)
    if nods:
        for start in rng.integers(0, n - 15, n // 100):
            angles[start : start + 15, 0] += 0.1 * np.sin(np.linspace(0.0, np.pi, 15))
    return angles, np.ones((n, 2), bool)


def test_when_a_head_lacks_the_references_quick_nods_expect_a_larger_tail_distance():
    reference = [_head_motion(60.0, True, 0)]
    percentiles = speed_percentiles(reference)
    assert tail_distance(reference, percentiles) == pytest.approx(0.0, abs=1e-12)
    like = tail_distance([_head_motion(60.0, True, 1)], percentiles)
    still = tail_distance([_head_motion(60.0, False, 1)], percentiles)
    assert like < 0.3
    assert still > like + 0.3
    # twice as fast everywhere: every ratio is 2
    doubled = [(2.0 * angles, known) for angles, known in reference]
    assert tail_distance(doubled, percentiles) == pytest.approx(np.log(2.0))
    # a motionless head is far, not infinitely far
    frozen = [(np.zeros_like(angles), known) for angles, known in reference]
    assert np.isfinite(tail_distance(frozen, percentiles))


def test_when_a_reference_is_given_expect_the_head_scored_on_its_percentiles_too(
    checkpoint, clips, robot
):
    validation = [c for c in clips if c.info.split == "validation"]
    train = [c for c in clips if c.info.split == "train"]
    targets = reference_percentiles(train, robot)
    assert set(targets) == {"head"}
    with_tail = choose_sampling([(checkpoint, validation)], robot, 1, reference=train)
    without = choose_sampling([(checkpoint, validation)], robot, 1)
    head_trials = [t for t in with_tail.trials if t.group == "head" and "std ratio" in t.measures]
    assert head_trials
    assert all(t.measures["tail"] >= 0.0 for t in head_trials)
    assert all("tail" not in t.measures for t in with_tail.trials if t.group != "head")
    assert all("tail" not in t.measures for t in without.trials)
    for t in head_trials:  # the score adds the tail term
        base = {k: v for k, v in t.measures.items() if k != "tail"}
        assert score(t.measures) == pytest.approx(score(base) + t.measures["tail"])
    assert " tail " in with_tail.table().splitlines()[1]
