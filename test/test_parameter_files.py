"""A node checks every value its parameter files give it, even those rcl's merge drops."""

from __future__ import annotations

from pathlib import Path

import pytest
from node_processes import configuration_error_line

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.resources import share_path
from audio2pose_ros.ros.node_parameters import check_parameter_files, parameter_files
from audio2pose_ros.ros.nodes.motion_filter_node import PARAMETERS

PACKAGE_PARAMS = share_path("config", "pepper.yaml")


def override(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "mine.yaml"
    path.write_text(text)
    return path


def test_when_argv_has_params_files_expect_them_in_order():
    argv = ["node", "--ros-args", "--params-file", "a.yaml", "-r", "x:=y", "--params-file", "b"]
    assert parameter_files(argv) == [Path("a.yaml"), Path("b")]
    assert parameter_files(["node", "--params-file", "not-ros.yaml"]) == []


@pytest.mark.parametrize(
    ("section", "value", "problem"),
    [
        ("motion_filter_node", "fast", "rate_hz"),
        ("/**", "fast", "rate_hz"),
        ("/**/motion_filter_node", "-5.0", "rate_hz"),
        ("/motion_filter_node", "true", "rate_hz"),
    ],
)
def test_when_an_override_file_has_a_wrong_value_expect_it_named_with_its_file(
    tmp_path, section, value, problem
):
    mine = override(tmp_path, f"{section}:\n  ros__parameters:\n    rate_hz: {value}\n")
    with pytest.raises(ConfigurationError, match=rf"mine\.yaml: .*{problem}"):
        check_parameter_files("motion_filter_node", "/", PARAMETERS, [PACKAGE_PARAMS, mine])


def test_when_another_nodes_section_is_wrong_expect_this_node_unaffected(tmp_path):
    mine = override(tmp_path, "inference_node:\n  ros__parameters:\n    rate_hz: fast\n")
    check_parameter_files("motion_filter_node", "/", PARAMETERS, [PACKAGE_PARAMS, mine])


def test_when_a_section_names_another_nodes_parameter_expect_it_left_alone(tmp_path):
    """launch hands one override set (model_path for all) to every node's own section."""
    mine = override(tmp_path, "motion_filter_node:\n  ros__parameters:\n    model_path: m.ckpt\n")
    check_parameter_files("motion_filter_node", "/", PARAMETERS, [PACKAGE_PARAMS, mine])


def test_when_the_real_node_gets_a_wrong_type_in_a_second_file_expect_exit_78_naming_both(
    tmp_path,
):
    mine = override(tmp_path, "motion_filter_node:\n  ros__parameters:\n    rate_hz: fast\n")
    line = configuration_error_line(
        "motion_filter_node", "--params-file", str(PACKAGE_PARAMS), "--params-file", str(mine)
    )
    assert "rate_hz" in line
    assert "mine.yaml" in line


def test_when_a_parameter_name_is_misspelt_expect_a_warning_naming_the_likely_one():
    from audio2pose_ros.ros.node_parameters import unknown_parameter_warnings

    specs = {spec.name: spec for spec in PARAMETERS}
    given = [
        "arms_gian",  # a typo of this node's parameter
        "model_pth",  # a typo of another node's parameter
        "arms_gain",  # this node's
        "feature_limit_sd",  # another node's: launch and /** give every node the same set
        "use_sim_time",  # rclpy's own
        "qos_overrides./audio/audio.subscription.depth",
        "zzz",
    ]
    lines = unknown_parameter_warnings(given, specs)
    assert lines == [
        "parameter arms_gian is not a parameter of any audio2pose_ros node and was ignored; "
        "did you mean arms_gain?",
        "parameter model_pth is not a parameter of any audio2pose_ros node and was ignored; "
        "did you mean model_path?",
        "parameter zzz is not a parameter of any audio2pose_ros node and was ignored",
    ]
    assert unknown_parameter_warnings(["arms_gain", "use_sim_time"], specs) == []


def test_when_the_packaged_parameters_file_is_given_expect_no_unknown_name():
    """config/pepper.yaml names only parameters some node declares."""
    import yaml

    from audio2pose_ros.ros.node_parameters import unknown_parameter_warnings

    document = yaml.safe_load(share_path("config", "pepper.yaml").read_text())
    names = {name for section in document.values() for name in section["ros__parameters"]}
    assert names
    assert unknown_parameter_warnings(names, {}) == []
