"""The launch file's single_process argument: one process, the same configuration."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from launch_arguments import arguments as launch_arguments

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.ros.launch_support import plan_launch, single_process_arguments


def test_when_single_process_is_not_given_expect_three_processes() -> None:
    assert not plan_launch(launch_arguments()).single_process
    assert plan_launch(launch_arguments(single_process="True")).single_process


def test_when_single_process_is_not_a_boolean_expect_a_refusal() -> None:
    with pytest.raises(ConfigurationError, match="single_process"):
        plan_launch(launch_arguments(single_process="yes please"))


def test_when_single_process_expect_the_three_nodes_parameters_and_remappings(
    tmp_path: Path,
) -> None:
    plan = plan_launch(
        launch_arguments(
            single_process="1",
            model_path="/models/1",
            audio_ns="/mic",
            controller_topic="/arm_controller/joint_trajectory",
        )
    )
    arguments = single_process_arguments(plan, tmp_path)
    assert arguments[:3] == ["--ros-args", "--params-file", str(plan.params_file)]
    override = Path(arguments[4])
    assert arguments[3] == "--params-file"
    assert yaml.safe_load(override.read_text()) == {
        "audio_features_node": {"ros__parameters": {"model_path": "/models/1"}},
        "inference_node": {"ros__parameters": {"model_path": "/models/1"}},
    }
    remaps = [arguments[i + 1] for i, a in enumerate(arguments) if a == "-r"]
    assert remaps == [
        "audio/audio:=/mic/audio",
        "audio/audio_info:=/mic/audio_info",
        "joint_trajectory_controller/joint_trajectory:=/arm_controller/joint_trajectory",
    ]
    without_model = single_process_arguments(plan_launch(launch_arguments()), tmp_path)
    assert without_model.count("--params-file") == 1
