"""live_groups sampling limits: each joint's own temperature, steps the robot can follow."""

import json

import numpy as np
import pytest
import torch

from audio2pose_ros.checkpoints.numpy_runtime import numpy_kernel_for
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.learning.model_card import _part_temperature
from audio2pose_ros.models.registry import build_model
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.timebase import FRAME_PERIOD_S

SMALL = {"n_features": 4, "n_joints": 11}


def _steps_rad(robot, poses: np.ndarray) -> np.ndarray:
    """(..., T, J) normalised poses -> (..., T - 1, J) absolute steps in radians."""
    return np.abs(np.diff(robot.denormalize(poses), axis=-2))


def _hot_model(robot, **config):
    """A small untrained model sampled hot enough that raw steps outrun Pepper's joints."""
    torch.manual_seed(0)
    model = build_model(
        "live_groups",
        {**SMALL, "first_temperature": 40.0, "second_temperature": 40.0, **config},
    )
    model.bind_robot(robot)
    return model


def test_when_the_velocity_limit_is_on_expect_every_sampled_step_within_the_robot_speed(robot):
    features = torch.randn(2, 300, 4)
    bound = robot.max_velocity_rad_s * FRAME_PERIOD_S
    free = _hot_model(robot).sample(features, 2, torch.Generator().manual_seed(3))
    assert (_steps_rad(robot, free.double().numpy()) > bound).any()  # the limit has work to do
    limited = _hot_model(robot, velocity_limit=1.0)
    poses = limited.sample(features, 2, torch.Generator().manual_seed(3)).double().numpy()
    assert (_steps_rad(robot, poses) <= bound + 1e-6).all()  # float32 output: 1e-6 rad
    half = _hot_model(robot, velocity_limit=0.5).sample(features, 2, torch.Generator())
    assert (_steps_rad(robot, half.double().numpy()) <= 0.5 * bound + 1e-6).all()
    # so the motion filter's input gate, which drops steps faster than the robot, drops none
    settings = MotionFilterSettings()
    gate = robot.max_velocity_rad_s / settings.rate_hz + settings.outlier_tolerance_rad
    assert (_steps_rad(robot, poses) <= gate).all()


def test_when_the_velocity_limit_is_on_expect_batch_and_stream_alike_after_a_quiet_warm_up(robot):
    model = _hot_model(robot, velocity_limit=1.0)
    features = torch.randn(1, 200, 4)
    batch = model.sample(features, 1, torch.Generator().manual_seed(4), quiet_frames=50)
    batch = batch[0, 0].double().numpy()
    predictor = model.streaming_predictor(seed=4)
    predictor.temperature = 0.0  # the warm-up samples the most likely poses, unbounded
    frames = features[0].double().numpy()
    warm = [predictor.step(f) for f in frames[:50]]
    predictor.temperature = 1.0
    stream = np.array(warm + [predictor.step(f) for f in frames[50:]])
    np.testing.assert_allclose(stream, batch, atol=1e-5)
    unbound = build_model("live_groups", model.config_dict())
    unbound.load_state_dict(model.state_dict())  # the same weights, no robot: no limit
    free = unbound.sample(features, 1, torch.Generator().manual_seed(4), quiet_frames=50)
    np.testing.assert_allclose(free[0, 0, :50].double().numpy(), batch[:50], atol=1e-6)
    assert np.abs(free[0, 0].double().numpy() - batch).max() > 0.01


@pytest.mark.parametrize("value", [-0.1, 1.5, float("nan"), float("inf"), True, "1"])
def test_when_the_velocity_limit_is_malformed_expect_a_configuration_error_and_no_kernel(value):
    with pytest.raises(ConfigurationError, match="velocity_limit"):
        build_model("live_groups", {**SMALL, "velocity_limit": value})
    config = build_model("live_groups", SMALL).config_dict()
    assert "velocity_limit" not in config  # off: checkpoints keep the keys they always had
    assert numpy_kernel_for("live_groups", {**config, "velocity_limit": value}) is None
    assert numpy_kernel_for("live_groups", {**config, "velocity_limit": 1.0}) is not None


def test_when_every_joint_of_a_part_has_the_same_temperature_expect_the_shared_one_exactly():
    torch.manual_seed(1)
    shared = build_model("live_groups", {**SMALL, "second_temperature": 2.0})
    per_joint = shared.with_sampling(second_temperature=(2.0,) * 9)
    features = torch.randn(1, 150, 4)
    a = shared.sample(features, 2, torch.Generator().manual_seed(5))
    b = per_joint.sample(features, 2, torch.Generator().manual_seed(5))
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    stream = per_joint.streaming_predictor(seed=5)
    stepped = np.array([stream.step(f) for f in features[0].double().numpy()])
    np.testing.assert_allclose(stepped, a[0, 0].double().numpy(), atol=1e-5)


def test_when_one_joint_is_sampled_colder_expect_it_to_move_less_and_the_stream_to_agree(robot):
    torch.manual_seed(2)
    model = build_model("live_groups", {**SMALL, "second_temperature": 3.0})
    hip = int(np.flatnonzero(robot.group_mask("hip"))[0])
    colder = [3.0] * 9
    colder[list(model.groups[1]).index(hip)] = 0.3
    cold = model.with_sampling(second_temperature=tuple(colder))
    features = torch.randn(1, 400, 4)
    hot_hip = model.sample(features, 8, torch.Generator().manual_seed(6))[..., hip]
    cold_hip = cold.sample(features, 8, torch.Generator().manual_seed(6))[..., hip]
    assert cold_hip.std() < 0.5 * hot_hip.std()
    stream = cold.streaming_predictor(seed=6)
    stepped = np.array([stream.step(f) for f in features[0].double().numpy()])
    np.testing.assert_allclose(stepped[:, hip], cold_hip[0, 0].double().numpy(), atol=1e-5)


@pytest.mark.parametrize(
    "value",
    [
        (2.0,) * 8,
        (2.0,) * 10,
        (2.0,) * 8 + (float("nan"),),
        (2.0,) * 8 + (-1.0,),
        -0.5,
        float("inf"),
        (True,) * 9,
        "2",
    ],
)
def test_when_a_part_temperature_is_malformed_expect_a_configuration_error_and_no_kernel(value):
    with pytest.raises(ConfigurationError, match="second_temperature"):
        build_model("live_groups", {**SMALL, "second_temperature": value})
    config = build_model("live_groups", SMALL).config_dict()
    listed = list(value) if isinstance(value, tuple) else value
    assert numpy_kernel_for("live_groups", {**config, "second_temperature": listed}) is None
    assert numpy_kernel_for("live_groups", {**config, "second_temperature": [1.0] * 9})


def test_when_a_checkpoint_holds_per_joint_temperatures_as_a_list_expect_a_round_trip():
    model = build_model("live_groups", {**SMALL, "second_temperature": [4, 4, 4, 4, 4, 4, 4, 4, 1]})
    assert model.config.second_temperature == (4.0,) * 8 + (1.0,)
    again = build_model("live_groups", json.loads(json.dumps(model.config_dict())))
    assert again.config == model.config


def test_when_the_card_names_a_part_temperature_expect_one_per_joint_group(robot):
    model = build_model("live_groups", {**SMALL, "second_temperature": [4.0] * 8 + [1.5]})
    arms_and_hip = model.groups[1]
    assert _part_temperature(3.0, model.groups[0], robot) == "3"
    assert _part_temperature((4.0,) * 8 + (1.5,), arms_and_hip, robot) == "4 (arms), 1.5 (hip)"
    mixed = (4.0,) * 7 + (2.0, 1.5)  # the arm joints differ: each joint's value
    assert _part_temperature(mixed, arms_and_hip, robot) == "4x7/2/1.5"
