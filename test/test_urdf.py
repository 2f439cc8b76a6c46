"""urdf/pepper.urdf: a valid URDF that agrees with the robot description the nodes use."""

import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.robot.kinematics import RobotKinematics, default_urdf_path

ROOT = Path(__file__).resolve().parent.parent
URDF = ROOT / "urdf" / "pepper.urdf"


@pytest.fixture(scope="module")
def kinematics():
    return RobotKinematics(URDF)


def test_when_running_check_urdf_expect_it_parses_one_tree_from_base_link():
    # urdfdom's tool: Debian's liburdfdom-tools, or the pip wheel beside this interpreter (pin's
    # dependencies bring it into .venv/bin, which is not on PATH when the venv is not activated).
    check_urdf = shutil.which("check_urdf") or shutil.which(
        "check_urdf", path=str(Path(sys.executable).parent)
    )
    if check_urdf is None:
        pytest.skip("check_urdf not installed (Debian: apt-get install liburdfdom-tools)")
    result = subprocess.run([check_urdf, str(URDF)], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Successfully Parsed XML" in result.stdout
    assert "root Link: base_link" in result.stdout


def test_when_loading_the_packaged_urdf_expect_the_repository_file():
    assert default_urdf_path().resolve() == URDF.resolve()


def test_when_parsing_expect_base_link_torso_fixed_and_every_movable_joint_limited(kinematics):
    base = kinematics.joint("base_link_fixedjoint")
    assert (base.parent, base.child, base.joint_type) == ("base_link", "torso", "fixed")
    expected = {
        *load_robot().names,
        *("HipPitch", "KneePitch", "LWristYaw", "RWristYaw", "LHand", "RHand"),
    }
    assert set(kinematics.movable_joint_names) == expected
    for name in kinematics.movable_joint_names:
        joint = kinematics.joint(name)
        assert joint.lower_rad < joint.upper_rad, name
        assert joint.max_velocity_rad_s > 0, name


def test_when_reading_links_expect_positive_mass_and_inertia_except_the_root():
    root = ET.parse(URDF).getroot()
    links = root.findall("link")
    assert len(links) == 19
    for link in links:
        inertial = link.find("inertial")
        if link.get("name") == "base_link":
            assert inertial is None  # KDL rejects a root link with inertia
            continue
        assert float(inertial.find("mass").get("value")) > 0, link.get("name")
        inertia = inertial.find("inertia")
        assert all(float(inertia.get(k)) > 0 for k in ("ixx", "iyy", "izz")), link.get("name")
        assert link.find("visual/geometry") is not None, link.get("name")


def test_when_comparing_with_robot_description_expect_equal_position_and_velocity_limits(
    kinematics,
):
    for limits in load_robot().joints:
        joint = kinematics.joint(limits.name)
        assert joint.lower_rad == pytest.approx(limits.min_rad, abs=1e-9), limits.name
        assert joint.upper_rad == pytest.approx(limits.max_rad, abs=1e-9), limits.name
        assert joint.max_velocity_rad_s == pytest.approx(limits.max_velocity_rad_s, abs=1e-9)


def test_when_reading_ros2_control_block_expect_the_driven_joints_in_robot_order():
    robot = load_robot()
    block = ET.parse(URDF).getroot().find("ros2_control")
    joints = block.findall("joint")
    assert tuple(j.get("name") for j in joints) == robot.names
    for joint, limits in zip(joints, robot.joints, strict=True):
        command = joint.find("command_interface[@name='position']")
        params = {p.get("name"): float(p.text) for p in command.findall("param")}
        assert params == pytest.approx({"min": limits.min_rad, "max": limits.max_rad})
        initial = joint.find("state_interface[@name='position']/param[@name='initial_value']")
        assert float(initial.text) == pytest.approx(limits.neutral_rad)


def test_when_reading_controller_config_expect_the_robot_joints_in_order():
    config = yaml.safe_load((ROOT / "config" / "ros2_controllers.yaml").read_text())
    params = config["pepper_joint_trajectory_controller"]["ros__parameters"]
    assert tuple(params["joints"]) == load_robot().names
    assert params["command_interfaces"] == ["position"]


def test_when_reading_rviz_config_expect_the_robot_model_from_robot_description():
    config = yaml.safe_load((ROOT / "config" / "pepper.rviz").read_text())
    displays = {d["Class"]: d for d in config["Visualization Manager"]["Displays"]}
    model = displays["rviz_default_plugins/RobotModel"]
    assert model["Description Topic"]["Value"] == "/robot_description"
    assert model["Description Topic"]["Durability Policy"] == "Transient Local"
    assert config["Visualization Manager"]["Global Options"]["Fixed Frame"] == "base_link"
