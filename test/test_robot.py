"""The robot description: one YAML, the seed's joint order and limits (seed 003 Table 3.1)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.robot.description import MAX_FILE_BYTES, RobotDescriptionError, load_robot

SEED_TABLE_3_1 = {  # name: (lower, upper) in rad, in the seed's order theta_1..theta_11
    "HeadPitch": (-0.7068, 0.4451),
    "HeadYaw": (-2.0857, 2.0857),
    "LShoulderRoll": (0.0087, 1.5620),
    "LShoulderPitch": (-2.0857, 2.0857),
    "LElbowRoll": (-1.5620, -0.0087),
    "LElbowYaw": (-2.0857, 2.0857),
    "RShoulderRoll": (-1.5620, -0.0087),
    "RShoulderPitch": (-2.0857, 2.0857),
    "RElbowRoll": (0.0087, 1.5620),
    "RElbowYaw": (-2.0857, 2.0857),
    "HipRoll": (-0.5149, 0.5149),
}


def test_when_loading_default_expect_seed_order_and_table_3_1_limits(robot):
    assert robot.names == tuple(SEED_TABLE_3_1)
    np.testing.assert_allclose(robot.lower_rad, [v[0] for v in SEED_TABLE_3_1.values()])
    np.testing.assert_allclose(robot.upper_rad, [v[1] for v in SEED_TABLE_3_1.values()])


def test_when_loading_default_expect_urdf_velocities_and_neutral_inside_limits(robot):
    assert robot.max_velocity_rad_s[robot.names.index("HipRoll")] == pytest.approx(2.27032)
    assert robot.max_velocity_rad_s[robot.names.index("HeadYaw")] == pytest.approx(7.33998)
    assert np.all(robot.neutral_rad >= robot.lower_rad)
    assert np.all(robot.neutral_rad <= robot.upper_rad)
    # Arms hang down in the neutral pose: shoulder pitch pi/2 (DESIGN.md section 2).
    assert robot.neutral_rad[robot.names.index("LShoulderPitch")] == pytest.approx(
        np.pi / 2, abs=1e-3
    )


def test_when_normalizing_expect_eq_3_14_and_exact_inverse(robot):
    unit = robot.normalize(robot.lower_rad)
    np.testing.assert_allclose(unit, 0.0)
    np.testing.assert_allclose(robot.normalize(robot.upper_rad), 1.0)
    angles = np.random.default_rng(0).uniform(robot.lower_rad, robot.upper_rad, (50, 11))
    np.testing.assert_allclose(robot.denormalize(robot.normalize(angles)), angles)


def test_when_groups_requested_expect_head_two_arms_eight_hip_one(robot):
    assert robot.group_mask("head").sum() == 2
    assert robot.group_mask("arms").sum() == 8
    assert robot.group_mask("hip").sum() == 1
    with pytest.raises(ValueError, match="unknown joint group"):
        robot.group_mask("legs")


def test_when_limits_inverted_expect_error_naming_joint(tmp_path: Path):
    bad = tmp_path / "robot.yaml"
    bad.write_text(
        "robot: r\njoints:\n  - {name: J1, group: head, min_rad: 1.0, max_rad: -1.0, "
        "max_velocity_rad_s: 1, max_acceleration_rad_s2: 1, neutral_rad: 0}\n"
    )
    with pytest.raises(RobotDescriptionError, match=r"joint J1: min_rad 1\.0 must be below"):
        load_robot(bad)


def test_when_field_missing_expect_error_naming_file(tmp_path: Path):
    bad = tmp_path / "robot.yaml"
    bad.write_text("robot: r\njoints:\n  - {name: J1, group: head}\n")
    with pytest.raises(
        RobotDescriptionError, match=r"robot\.yaml: joints\[0\] \(J1\): field min_rad is missing"
    ):
        load_robot(bad)


def test_when_comparing_changed_ranges_expect_differences_listed(robot, tmp_path):
    data = robot.to_dict()
    data["joints"][0]["max_rad"] = 0.637045  # pepper_description's HeadPitch upper limit
    robot_file = tmp_path / "r.yaml"
    robot_file.write_text(yaml.safe_dump(data))
    other = load_robot(robot_file)
    assert robot.differences(other) == ["HeadPitch range [-0.7068, 0.637045] != [-0.7068, 0.4451]"]
    assert robot.differences(robot) == []


JOINT = (
    "{name: J1, group: head, min_rad: -1.0, max_rad: 1.0, max_velocity_rad_s: 1.0, "
    "max_acceleration_rad_s2: 1.0, neutral_rad: 0.0}"
)


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (("min_rad: -1.0", "min_rad: -.inf"), r"joint J1: min_rad -inf is not finite"),
        (("max_rad: 1.0", "max_rad: .nan"), r"joint J1: max_rad nan is not finite"),
        (("neutral_rad: 0.0", "neutral_rad: 2.0"), r"neutral_rad 2\.0 is outside"),
        (("max_velocity_rad_s: 1.0", "max_velocity_rad_s: .inf"), "max_velocity_rad_s inf is not"),
        (("max_acceleration_rad_s2: 1.0", "max_acceleration_rad_s2: -1"), "must be positive"),
        (("max_rad: 1.0", "max_rad: '1.0'"), r"\(J1\): field max_rad must be a number, got '1\.0'"),
        (("max_rad: 1.0", "max_rad: [1.0]"), r"field max_rad must be a number, got \[1\.0\]"),
        (("group: head", "group: [head]"), r"field group must be a non-empty string"),
        (("max_rad: 1.0", "max_rad: true"), r"field max_rad must be a number, got True"),
    ],
)
def test_when_a_joint_field_is_unusable_expect_configuration_error_naming_file_and_field(
    tmp_path: Path, edit: tuple[str, str], problem: str
):
    bad = tmp_path / "robot.yaml"
    bad.write_text(f"robot: r\njoints:\n  - {JOINT.replace(*edit)}\n")
    with pytest.raises(ConfigurationError, match=r"robot\.yaml: .*" + problem):
        load_robot(bad)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("- 1\n- 2\n", "expected a mapping with 'robot' and 'joints', got list"),
        ("robot: r\njoints: {a: 1}\n", "field joints must be a list"),
        ("robot: r\njoints: [1, 2]\n", r"joints\[0\]: expected a mapping, got int"),
        (f"robot: r\njoints: [{JOINT}, {JOINT}]\n", r"robot r: duplicated joints \['J1'\]"),
        ("robot: [r]\njoints: []\n", "field robot must be a non-empty string"),
        ("robot: r\njoints: [\n", r"not valid YAML at line \d"),
        ("", "expected a mapping with 'robot' and 'joints', got NoneType"),
    ],
)
def test_when_the_yaml_is_malformed_expect_configuration_error_naming_the_file(
    tmp_path: Path, text: str, problem: str
):
    bad = tmp_path / "robot.yaml"
    bad.write_text(text)
    with pytest.raises(ConfigurationError, match=r"robot\.yaml: " + problem):
        load_robot(bad)


def test_when_the_file_is_huge_missing_or_a_directory_expect_one_line(tmp_path: Path):
    huge = tmp_path / "huge.yaml"
    huge.write_bytes(b"#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(
        ConfigurationError, match=rf"huge\.yaml: larger than {MAX_FILE_BYTES} bytes"
    ):
        load_robot(huge)
    with pytest.raises(
        ConfigurationError, match=r"missing\.yaml: robot description file not found"
    ):
        load_robot(tmp_path / "missing.yaml")
    with pytest.raises(ConfigurationError, match="is a directory"):
        load_robot(tmp_path)


def test_when_the_robot_file_is_a_device_expect_refused_without_reading():
    with pytest.raises(ConfigurationError, match="/dev/zero: not a regular file"):
        load_robot("/dev/zero")


def test_when_unit_positions_are_0_and_1_expect_the_limits_exactly():
    robot = load_robot()
    assert np.array_equal(robot.denormalize(np.zeros(robot.n_joints)), robot.lower_rad)
    assert np.array_equal(robot.denormalize(np.ones(robot.n_joints)), robot.upper_rad)
