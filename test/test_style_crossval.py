"""Enrolment cross-validated inside the recording: no further from the person than the default."""

import numpy as np
import pytest

from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.motion.style import IDENTITY, StyleSettings, style_trajectory
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.style.crossval import MEASURE_TOLERANCE, Measures, choose, folds, pull, toward
from audio2pose_ros.style.personal import (
    checkpoint_synthesizer,
    fit_personal,
    motion_distance,
    synthesized_over_clip,
)
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLES_PER_FRAME


def test_when_a_recording_is_cut_into_folds_expect_every_frame_held_out_once_trained_otherwise():
    lengths = [300, 700, 250]
    found = folds(lengths)
    assert len(found) == 4  # 12.5 s: four stretches of at least 2.5 s
    held = [np.zeros(n, dtype=int) for n in lengths]
    for training, out in found:
        trained = [np.zeros(n, dtype=bool) for n in lengths]
        for c, a, b in training:
            trained[c][a:b] = True
        for c, a, b in out:
            held[c][a:b] += 1
            assert not trained[c][a:b].any()  # never trained on what it is scored on
        assert sum(t.sum() for t in trained) + sum(b - a for _, a, b in out) == sum(lengths)
    assert all((h == 1).all() for h in held)


def test_when_a_recording_is_too_short_for_two_folds_expect_none():
    assert folds([400]) == []  # 4 s: not two stretches of 2.5 s


def test_when_folds_disagree_or_the_recording_is_short_expect_a_stronger_pull_to_the_default():
    agree, disagree = [0.1, 0.1, 0.11, 0.09], [0.4, -0.2, 0.3, -0.1]
    assert np.mean(agree) == pytest.approx(np.mean(disagree))
    assert pull(disagree, 60.0) < pull(agree, 60.0) < 1.0
    assert pull(agree, 10.0) < pull(agree, 60.0)
    assert pull([-0.1, -0.1, -0.05], 60.0) == 0.0


def test_when_a_style_is_taken_part_way_expect_sizes_geometric_offsets_linear_others_default():
    learned = StyleSettings(arms_gain=0.25, arms_rest_pitch_rad=0.4, head_gain=2.0)
    half = toward(learned, 0.5, "arms")
    assert half.arms_gain == pytest.approx(0.5)
    assert half.arms_rest_pitch_rad == pytest.approx(0.2)
    assert half.head_gain == 1.0  # another part keeps the default
    assert toward(learned, 0.0, "arms") == IDENTITY


def measures(values):
    return [Measures(*v) for v in values]


def test_when_a_fit_is_further_on_one_measure_out_of_sample_expect_the_default_kept_saying_which():
    default = measures([(0.2, 0.2, 0.2)] * 4)
    closer_size_worse_accel = measures([(0.1, 0.2 + 3 * MEASURE_TOLERANCE, 0.0)] * 4)
    verdict = choose("arms", default, {("style", 1.0): closer_size_worse_accel}, 30.0)
    assert verdict.kept_default
    assert "H accel" in verdict.reason
    assert "kept the default" in verdict.line()


def test_when_a_fit_is_closer_on_every_measure_in_every_fold_expect_it_taken_with_its_gain():
    default = measures([(0.2, 0.2, 0.3)] * 4)
    better = measures([(0.1, 0.15, 0.1), (0.12, 0.14, 0.12), (0.1, 0.16, 0.1), (0.11, 0.15, 0.1)])
    half = measures([(0.15, 0.18, 0.2)] * 4)
    verdict = choose("head", default, {("style", 1.0): better, ("style", 0.5): half}, 60.0)
    assert not verdict.kept_default
    gains = [d.total - b.total for d, b in zip(default, better, strict=True)]
    assert verdict.gain == pytest.approx(np.mean(gains))
    assert verdict.spread == pytest.approx(np.std(gains, ddof=1))
    assert verdict.strength == pytest.approx(pull(gains, 60.0), abs=1e-3)  # pulled from 1
    assert "±" in verdict.line()
    assert "closer" in verdict.line()


def test_when_no_fit_beats_the_default_out_of_sample_expect_the_default_and_the_numbers():
    default = measures([(0.1, 0.1, 0.1)] * 3)
    worse = measures([(0.2, 0.2, 0.3)] * 3)
    verdict = choose("head", default, {("style", 1.0): worse}, 20.0)
    assert verdict.kept_default
    assert "3 folds" in verdict.reason


@pytest.mark.slow
def test_when_the_person_moves_exactly_as_the_default_expect_the_default_kept_and_said(
    robot, speech_files
):
    """A person whose arms the default already has: a fit on a few seconds must not change them.

    The person's arms are the default model's own motion on their speech (seed 0, what the
    default runs), three sentences. Chosen on the seconds it was fitted to, the fit moved the
    arms anyway (a size of 0.98 or 1.02: the size grid has no 1; a height limit at the arms'
    own highest 1 %); cross-validated, nothing comes closer than the default.
    """
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    default = checkpoint_synthesizer(checkpoint)
    arms = robot.group_mask("arms")
    clips = []
    for path in speech_files[:3]:
        audio = read_wav(path)[0]
        info = ClipInfo(path.stem, "person", "test", "test data")
        n = audio.size // SAMPLES_PER_FRAME
        empty = np.zeros((n, robot.n_joints))
        angles = synthesized_over_clip(Clip(info, audio, empty, empty.astype(bool)), default)
        mask = np.zeros(angles.shape, dtype=bool)
        mask[:, arms] = True
        clips.append(Clip(info, audio, angles, mask))
    personal = fit_personal(clips, robot, checkpoint)
    assert personal.settings == IDENTITY
    assert personal.arms_noise == 1.0
    assert personal.checkpoint is checkpoint
    verdict = personal.verdicts["arms"]
    assert verdict.kept_default
    assert personal.report() == [f"arms: kept the default ({verdict.reason})"]
    real = [(c.angles_rad, c.mask) for c in clips]
    styled = [(style_trajectory(robot, personal.settings, a, FRAME_RATE_HZ), k) for a, k in real]
    assert motion_distance(real, styled, robot, "arms") == pytest.approx(0.0, abs=1e-12)


def test_when_a_fold_holds_a_few_seconds_expect_the_style_fitted_on_them(robot):
    """A fold of a short enrolment trains on 3 s: under the 5 s a style file needs, still fitted."""
    from audio2pose_ros.style.figures import measure_part, resolve

    n = 300
    t = np.arange(n)[:, None] / FRAME_RATE_HZ
    head = robot.group_mask("head")
    model = np.tile(robot.neutral_rad, (n, 1))
    model[:, head] += 0.05 * np.sin(2 * np.pi * 0.7 * t + np.arange(head.sum()))
    person = model.copy()
    person[:, head] = robot.neutral_rad[head] + 0.2 * (model[:, head] - robot.neutral_rad[head])
    known = np.ones(model.shape, dtype=bool)
    figures = {"head": measure_part([(person, known)], robot, "head", min_seconds=2.5)}
    assert resolve(figures, [(model, known)], robot) == IDENTITY  # a style file's 5 s
    fitted = resolve(figures, [(model, known)], robot, min_seconds=2.5)
    assert fitted.head_gain == pytest.approx(0.2, rel=0.1)
