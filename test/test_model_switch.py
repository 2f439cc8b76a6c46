"""A model switched live: the checkpoint checked before it replaces the running one, and the blend
from the old model's poses to the new one's (no jump), without ROS."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from personal_models import arms_noise_checkpoint, personal_folder

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.checkpoints.switch import load_replacement
from audio2pose_ros.checkpoints.torch_io import Checkpoint, save_checkpoint
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.blend import MAX_WEIGHT_SLOPE, PoseBlend, blend_step_bound, blend_weights
from audio2pose_ros.models.mlp import FramewiseMLP, MLPConfig
from audio2pose_ros.resources import default_checkpoint_path


@pytest.fixture(scope="module")
def running(robot):
    return load_streaming_model(default_checkpoint_path(), robot=robot)


@pytest.fixture(scope="module")
def personal(tmp_path_factory, robot):
    """The packaged model with its arms sampling at 4 times their temperature (an enrolment's)."""
    return arms_noise_checkpoint(tmp_path_factory.mktemp("personal") / "model.safetensors", robot)


def _mlp(path, robot, features: FeatureSpec):
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    checkpoint = Checkpoint(
        model=FramewiseMLP(MLPConfig(n_features=features.dim)).eval(),
        features=features,
        normalizer=FeatureNormalizer.fit(rng.normal(size=(100, features.dim))),
        robot=robot,
    )
    return save_checkpoint(path, checkpoint)


def test_when_a_checkpoint_fits_the_running_model_expect_it_loaded(running, personal, robot):
    model = load_replacement(str(personal), running, robot)
    assert model.features == running.features
    assert model.runtime == "numpy"
    assert load_replacement("", running, robot).name == running.name  # '' is the default


def test_when_a_checkpoint_cannot_replace_the_running_model_expect_the_reason(
    tmp_path, running, robot
):
    refusals = {
        "no such file": str(tmp_path / "missing.safetensors"),
        "a folder without style.yaml": str(tmp_path),
    }
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00" * 64)
    refusals["not an audio2pose checkpoint"] = str(junk)
    other = _mlp(tmp_path / "other.safetensors", robot, FeatureSpec(nfilt=40))
    refusals["other audio features"] = str(other)
    for reason, path in refusals.items():
        with pytest.raises(ConfigurationError, match=reason) as refused:
            load_replacement(path, running, robot)
        assert str(refused.value).startswith(f"model_path {path!r} refused: ")


def test_when_blended_expect_old_poses_first_new_poses_last_in_any_message_sizes():
    rng = np.random.default_rng(1)
    old, new = rng.uniform(-1, 1, (260, 11)), rng.uniform(-1, 1, (260, 11))
    blend, mixed, start = PoseBlend(100), [], 0
    while start < 100:
        n = int(rng.integers(1, 23))
        mixed.append(blend.mix(old[start : start + n], new[start : start + n]))
        start += n
    out = np.concatenate(mixed)
    assert blend.finished
    np.testing.assert_array_equal(out[0], old[0])  # weight 0 at the first frame
    np.testing.assert_allclose(out[100:], new[100:start])  # weight 1 from frame 100 on
    one_go = PoseBlend(100).mix(old[:start], new[:start])  # message sizes do not matter
    np.testing.assert_allclose(out, one_go)


def test_when_two_real_models_are_blended_expect_no_step_beyond_their_own_plus_the_bound(
    running, personal, robot, speech
):
    """Both models on the same real speech; the mix never steps further than the bound."""
    from audio2pose_ros.audio.features import extract_features

    frames = running.normalizer.apply(extract_features(speech, running.features))[:400]
    new_model = load_replacement(str(personal), running, robot)
    a = robot.denormalize(running.predictor(seed=0).run(frames))
    b = robot.denormalize(new_model.predictor(seed=0).run(frames))
    blend = PoseBlend(100)
    out = np.concatenate([blend.mix(a[i : i + 7], b[i : i + 7]) for i in range(0, len(a), 7)])
    step = np.abs(np.diff(out, axis=0))
    own_a, own_b = np.abs(np.diff(a, axis=0)), np.abs(np.diff(b, axis=0))
    gap = np.abs(b - a)[:-1]
    assert (step <= blend_step_bound(own_a, own_b, gap, 100) + 1e-12).all()
    # with the joints' ranges as the gap: a fixed bound per joint, above both models' steps
    ranges = robot.upper_rad - robot.lower_rad
    assert (step <= np.maximum(own_a, own_b) + MAX_WEIGHT_SLOPE / 100 * ranges + 1e-12).all()
    assert (out >= robot.lower_rad - 1e-9).all()
    assert (out <= robot.upper_rad + 1e-9).all()
    # the models do differ (the arms' noise): a direct switch would have stepped by the gap
    assert np.abs(b - a).max() > (step.max() + 1e-3)


def test_when_a_blend_has_no_frames_expect_a_refusal():
    with pytest.raises(ValueError, match="at least one frame"):
        PoseBlend(0)
    weights = blend_weights(0, 5, 4)
    np.testing.assert_allclose(weights, [0.0, 0.15625, 0.5, 0.84375, 1.0])


def test_when_given_a_personal_model_folder_expect_its_checkpoint_or_the_default(
    tmp_path, personal
):
    from audio2pose_ros.checkpoints.switch import resolve_model_path

    folder = tmp_path / "me"
    folder.mkdir()
    assert resolve_model_path(str(folder)) == folder  # no style: not a personal model
    personal_folder(folder)
    assert resolve_model_path(str(folder)) == default_checkpoint_path()  # the style alone
    personal_folder(folder, personal)
    assert resolve_model_path(str(folder)) == folder / "model.safetensors"
    assert resolve_model_path("") == default_checkpoint_path()
