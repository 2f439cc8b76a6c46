"""Streaming models start an utterance settled: no start jump, offline and online alike."""

from dataclasses import replace

import numpy as np
import pytest

from audio2pose_ros.checkpoints.numpy_runtime import load_streaming_model
from audio2pose_ros.checkpoints.torch_io import load_checkpoint, save_checkpoint
from audio2pose_ros.models.warm_start import WARM_START_FRAMES, WarmStarted, with_warm_start
from audio2pose_ros.offline.synthesis import normalized_features, predict_normalized
from audio2pose_ros.resources import default_checkpoint_path


def test_when_warming_up_expect_the_first_frame_repeated_in_front_and_nothing_else_changed():
    frames = np.arange(12.0).reshape(4, 3)
    warmed = with_warm_start(frames, 5)
    assert warmed.shape == (9, 3)
    np.testing.assert_array_equal(warmed[:5], np.tile(frames[0], (5, 1)))
    np.testing.assert_array_equal(warmed[5:], frames)
    batch = with_warm_start(np.stack([frames, frames + 1]), 2)
    assert batch.shape == (2, 6, 3)
    np.testing.assert_array_equal(batch[1, :2], np.tile(frames[0] + 1, (2, 1)))
    with pytest.raises(ValueError, match="first frame"):
        with_warm_start(np.zeros((0, 3)))


class _Counter:
    """A stateful predictor: the pose is the number of frames seen, then the frame's sum."""

    def __init__(self) -> None:
        self.seen = 0

    def step(self, features: np.ndarray) -> np.ndarray:
        self.seen += 1
        return np.array([self.seen, features.sum()])

    def reset(self) -> None:
        self.seen = 0

    def run(self, frames: np.ndarray) -> np.ndarray:
        return np.array([self.step(f) for f in frames])


def test_when_a_wrapped_predictor_starts_expect_it_warmed_up_once_per_reset():
    frames = np.arange(6.0).reshape(3, 2)
    wrapped = WarmStarted(_Counter(), n=4)
    first = wrapped.step(frames[0])
    np.testing.assert_array_equal(first, [5, 1])  # 4 warm-up frames before it
    np.testing.assert_array_equal(wrapped.run(frames[1:]), [[6, 5], [7, 9]])  # no second warm-up
    wrapped.reset()
    np.testing.assert_array_equal(wrapped.run(frames), [[5, 1], [6, 5], [7, 9]])
    assert len(wrapped.run(np.zeros((0, 2)))) == 0


class _Sampler(_Counter):
    """A sampling predictor that records the temperature of every frame it samples."""

    def __init__(self) -> None:
        super().__init__()
        self.temperature = 1.5
        self.temperatures: list[float] = []

    def step(self, features: np.ndarray) -> np.ndarray:
        self.temperatures.append(self.temperature)
        return super().step(features)


def test_when_a_sampler_warms_up_expect_its_most_likely_poses_then_its_own_temperature():
    """Noise during the warm-up swung a trained sampler's head to its yaw limit and back."""
    sampler = _Sampler()
    wrapped = WarmStarted(sampler, n=4)
    out = wrapped.run(np.ones((3, 2)))
    np.testing.assert_array_equal(out[:, 0], [5, 6, 7])
    assert sampler.temperatures == [0.0] * 4 + [1.5] * 3
    assert sampler.temperature == 1.5


@pytest.mark.parametrize("temperature", [0.0, 1.0])
def test_when_the_packaged_model_starts_an_utterance_expect_no_start_jump(speech, temperature):
    """The first frames change no faster than the model later does (it jumped 0.4 rad)."""
    checkpoint = load_checkpoint(default_checkpoint_path())
    robot = checkpoint.robot
    angles = robot.denormalize(predict_normalized(checkpoint, speech, temperature=temperature))
    step = np.abs(np.diff(angles, axis=0))
    later = step[20:].max(axis=0)
    assert (step[:20].max(axis=0) <= later + 1e-3).all(), (step[:20].max(axis=0), later)


# Body-aware sampling reads the arms' clearance from coal, whose distance search stops within
# 1e-6 m of the answer, at a point that depends on the searches before it: the batch and the
# stream compute the same poses in another order (last-bit differences), so their searches stop
# at other points within that tolerance. Through the 3 cm band that is 3e-5 of the arm noise,
# and the sampler's recurrence carries it on: over the five bundled clips and seeds 3 and 4, the
# two agree to 1e-5 on most clips; on one they differ by more than 1e-3 in 1 % of values and
# by up to 7.6e-3 of a joint's range (1.7 degrees on a 4.2 rad range). So with the body in mind
# the stream must give the batch's poses to 1e-3 in all but 2 % of values and nowhere by more
# than 1e-2; without it, to 1e-5 everywhere.
BODY_AWARE_TOLERANCE = 1e-3
BODY_AWARE_OUTLIERS = 0.02
BODY_AWARE_MAX = 1e-2


@pytest.mark.parametrize(
    ("settings", "atol"), [({"body_band_m": 0.0}, 1e-5), ({}, BODY_AWARE_TOLERANCE)]
)
def test_when_the_packaged_model_runs_online_expect_the_offline_synthesis_poses(
    speech, tmp_path, settings, atol
):
    shipped = load_checkpoint(default_checkpoint_path())
    checkpoint = replace(shipped, model=shipped.model.with_sampling(**settings))
    path = save_checkpoint(tmp_path / "model.safetensors", checkpoint)
    online = load_streaming_model(path).predictor(seed=3)
    frames = normalized_features(checkpoint, speech)
    offline = predict_normalized(checkpoint, speech, seed=3)
    halves = np.concatenate([online.run(frames[:37]), *[online.step(f)[None] for f in frames[37:]]])
    difference = np.abs(halves - offline)
    if atol == BODY_AWARE_TOLERANCE:
        assert np.mean(difference > atol) <= BODY_AWARE_OUTLIERS, np.mean(difference > atol)
        assert difference.max() <= BODY_AWARE_MAX
    else:
        np.testing.assert_allclose(halves, offline, atol=atol)
    assert np.ptp(offline, axis=0).max() > 100 * atol  # the motion is not flat
    assert WARM_START_FRAMES >= 50  # the default sampler settles within about 20 frames
