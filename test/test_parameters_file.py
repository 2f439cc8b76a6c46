"""Offline motion is filtered as motion_filter_node is configured by the same parameter file."""

import pytest
import yaml

from audio2pose_ros.errors import InputError
from audio2pose_ros.offline.parameters_file import motion_filter_from_file, node_parameters
from audio2pose_ros.resources import share_path


def write(tmp_path, data):
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_when_the_packaged_file_is_read_expect_the_nodes_defaults():
    packaged = yaml.safe_load(share_path("config", "pepper.yaml").read_text(encoding="utf-8"))
    motion = motion_filter_from_file()
    expected = packaged["motion_filter_node"]["ros__parameters"]["rate_hz"]
    assert motion.settings.rate_hz == expected


def test_when_a_value_is_in_both_sections_expect_the_nodes_own_to_win_as_in_rcl(tmp_path):
    path = write(
        tmp_path,
        {
            "/**": {"ros__parameters": {"rate_hz": 50.0, "smoothing": "lowpass"}},
            "motion_filter_node": {"ros__parameters": {"rate_hz": 100.0}},
        },
    )
    assert node_parameters(path, "motion_filter_node") == {"rate_hz": 100.0, "smoothing": "lowpass"}
    motion = motion_filter_from_file(path)
    assert (motion.settings.rate_hz, motion.settings.smoothing) == (100.0, "lowpass")


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (["not", "a", "mapping"], "a parameters file is a mapping of node names"),
        ({"motion_filter_node": {"ros__parameters": [1]}}, "ros__parameters must be a mapping"),
        ({"motion_filter_node": {"ros__parameters": {"rate_hz": -1.0}}}, "rate_hz"),
        ({"/**": {"ros__parameters": {"robot_description": 3}}}, "must be a string"),
    ],
)
def test_when_the_file_is_unusable_expect_one_input_error_naming_it(tmp_path, data, message):
    path = write(tmp_path, data)
    with pytest.raises(InputError, match=message) as raised:
        motion_filter_from_file(path)
    assert str(path) in str(raised.value)
