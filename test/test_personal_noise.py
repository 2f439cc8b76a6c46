"""A personal model's own arm noise: fitted to the person, kept in the personal checkpoint."""

import numpy as np
import pytest

from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.cli.main import main
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.style.figures import measure_part
from audio2pose_ros.style.personal import (
    checkpoint_digest,
    checkpoint_synthesizer,
    fit_arms_noise,
    model_and_style,
    motion_distance,
    style_overrides,
    with_arms_noise,
)
from audio2pose_ros.timebase import SAMPLES_PER_FRAME


@pytest.fixture(scope="module")
def checkpoint(robot):
    return load_checkpoint(default_checkpoint_path(), robot=robot)


def speech_clip(robot, speech, angles=None):
    n = speech.size // SAMPLES_PER_FRAME
    angles = np.tile(robot.neutral_rad, (n, 1)) if angles is None else angles
    info = ClipInfo("person", "someone", "test", "test data")
    return Clip(info, speech, angles, np.ones(angles.shape, dtype=bool))


@pytest.mark.parametrize("factor", [1.0, 3.0])
def test_when_a_person_moves_like_the_model_with_its_arm_noise_scaled_expect_that_scale(
    robot, speech, checkpoint, factor
):
    noisier = checkpoint if factor == 1.0 else with_arms_noise(checkpoint, factor)
    clip = speech_clip(robot, speech)
    angles = checkpoint_synthesizer(noisier)(clip)
    person = measure_part([(angles, np.ones(angles.shape, dtype=bool))], robot, "arms")
    found, model = fit_arms_noise([clip], person, checkpoint)
    assert found == factor
    assert np.array_equal(checkpoint_synthesizer(model)(clip), angles)


def test_when_arm_noise_is_scaled_expect_only_the_arm_joints_temperature_scaled(checkpoint):
    base = checkpoint.model.config
    scaled = with_arms_noise(checkpoint, 4.0).model.config
    arms = checkpoint.robot.group_mask("arms")[checkpoint.model.groups[1]]
    second = np.broadcast_to(base.second_temperature, arms.shape)
    np.testing.assert_allclose(scaled.second_temperature, np.where(arms, 4.0, 1.0) * second)
    assert scaled.first_temperature == base.first_temperature  # the head
    assert checkpoint.model.config == base  # the given model is left as it was


def test_when_a_lively_person_enrolls_expect_a_personal_checkpoint_with_their_arm_noise(
    tmp_path, robot, speech, checkpoint, capsys
):
    n = speech.size // SAMPLES_PER_FRAME
    t = np.arange(n)[:, None] / 100.0
    angles = np.tile(robot.neutral_rad, (n, 1))
    arms = robot.group_mask("arms")
    phases = np.arange(arms.sum())[None, :]
    angles[:, arms] += 0.3 * np.sin(2 * np.pi * 1.3 * t + phases) * np.sin(np.pi * 0.4 * t)
    mask = np.zeros(angles.shape, dtype=bool)
    mask[:, arms] = True
    dataset = Dataset.create(tmp_path / "data", robot)
    dataset.add(
        Clip(ClipInfo("lively", "someone", "test", "test data"), speech, angles, mask), robot
    )
    assert main(["enroll", str(tmp_path / "data"), "-o", str(tmp_path / "me")]) == 0
    printed = capsys.readouterr().out
    own, style = model_and_style(str(tmp_path / "me"))
    assert own == tmp_path / "me" / "model.safetensors"
    assert style.fitted[0] == checkpoint_digest(own)
    personal = load_checkpoint(own, robot=robot)
    factor = np.asarray(personal.model.config.second_temperature) / np.broadcast_to(
        checkpoint.model.config.second_temperature, arms.sum() + 1
    )
    in_second = arms[checkpoint.model.groups[1]]
    assert np.all(factor[in_second] > 1.0)
    assert np.all(factor[~in_second] == 1.0)  # the hip
    assert personal.model.config.first_temperature == checkpoint.model.config.first_temperature
    assert load_streaming_model(own, robot, allow_torch=False)  # the live numpy runtime
    assert style.fitted[1].head_gain == 1.0  # the head is not seen
    # the command says what it fitted: the noise, and the style the folder runs with it
    noise = next(line for line in printed.splitlines() if "the arms' sampling noise:" in line)
    assert float(noise.split(": ")[1].split()[0]) == pytest.approx(factor[in_second][0])
    assert str(own) in noise
    folder = printed.split("style parameters of the folder (what --model applies):\n")[1]
    fitted = [line.strip() for line in folder.splitlines()[: len(style_overrides(style.fitted[1]))]]
    assert fitted == style_overrides(style.fitted[1])
    assert "use it: audio2pose run --model" in printed


def test_when_motion_is_the_person_own_expect_distance_zero_and_more_for_other_motion(
    robot, speech, checkpoint
):
    clip = speech_clip(robot, speech)
    real, other = (
        [(angles, np.ones(angles.shape, dtype=bool))]
        for angles in (
            checkpoint_synthesizer(checkpoint)(clip),
            checkpoint_synthesizer(with_arms_noise(checkpoint, 3.0))(clip),
        )
    )
    assert motion_distance(real, real, robot, "arms") == pytest.approx(0.0, abs=1e-12)
    assert motion_distance(real, other, robot, "arms") > 0.1
