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
def test_when_the_person_already_moves_like_the_default_expect_enrolment_no_further_on_new_speech(
    robot, speech_files
):
    """A person whose arms the default already has: a fit on few seconds must not shrink them.

    The person is the default model itself at another seed (its size and pace, other motion);
    enrolled on three sentences, scored on two it never heard, against the default.
    """
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    other_seed = checkpoint_synthesizer(checkpoint)  # the synthesizer of seed 0 is the default's
    from audio2pose_ros.offline.synthesis import synthesize

    arms = robot.group_mask("arms")
    clips = []
    for path in speech_files[:5]:
        audio = read_wav(path)[0]
        n = audio.size // SAMPLES_PER_FRAME
        angles = synthesize(checkpoint, audio, seed=7, body_margin_m=None)[1][:n]
        mask = np.zeros(angles.shape, dtype=bool)
        mask[:, arms] = True
        info = ClipInfo(path.stem, "person", "test", "test data")
        clips.append(Clip(info, audio, angles, mask))
    enrol, held = clips[:3], clips[3:]
    personal = fit_personal(enrol, robot, checkpoint)
    real = [(c.angles_rad, c.mask) for c in held]
    default, enrolled = [], []
    run = checkpoint_synthesizer(personal.checkpoint)
    for clip in held:
        default.append((synthesized_over_clip(clip, other_seed), clip.mask))
        angles = synthesized_over_clip(clip, run)
        enrolled.append(
            (style_trajectory(robot, personal.settings, angles, FRAME_RATE_HZ), clip.mask)
        )
    assert (
        motion_distance(real, enrolled, robot, "arms")
        <= motion_distance(real, default, robot, "arms") + 0.01
    )
    assert set(personal.verdicts) == {"arms"}
    assert personal.report()  # says what it expects, or why it kept the default
