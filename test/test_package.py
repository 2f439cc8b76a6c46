"""Package structure: executables, launch file, parameter file and package.xml agree.

`ros2 launch` is not available here, so the launch file is checked for structure: the
executables it starts exist, node names match them, and the parameters it passes are the ones
the nodes declare.
"""

import ast
import configparser
import xml.etree.ElementTree as ET
from dataclasses import fields
from pathlib import Path

import yaml

from audio2pose_ros.cli.graph import NODE_EXECUTABLES
from audio2pose_ros.motion.filter import MotionFilterSettings
from audio2pose_ros.motion.limits import LimitSettings

ROOT = Path(__file__).resolve().parent.parent


def console_scripts() -> dict[str, str]:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    lines = cfg["options.entry_points"]["console_scripts"].strip().splitlines()
    return dict(line.split(" = ") for line in lines)


def launch_nodes() -> list[dict[str, str]]:
    tree = ast.parse((ROOT / "launch" / "pepper.launch.py").read_text())
    nodes = []
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "Node":
            nodes.append(
                {
                    kw.arg: kw.value.value
                    for kw in call.keywords
                    if isinstance(kw.value, ast.Constant)
                }
            )
    # robot_state_publisher, RViz and the gz sim helpers are other packages' nodes
    return [n for n in nodes if n.get("package") == "audio2pose_ros"]


def test_when_reading_setup_cfg_expect_one_executable_per_node_plus_cli():
    scripts = console_scripts()
    assert set(scripts) == {*NODE_EXECUTABLES, "audio2pose"}
    for name in NODE_EXECUTABLES:
        assert scripts[name] == f"audio2pose_ros.nodes.{name}:main"


def test_when_parsing_launch_file_expect_the_three_nodes_named_as_their_executables():
    nodes = launch_nodes()
    assert sorted(n["executable"] for n in nodes) == sorted(NODE_EXECUTABLES)
    for node in nodes:
        assert node["package"] == "audio2pose_ros"
        assert node["name"] == node["executable"]
        assert node["respawn"] is True  # safe: configuration errors idle instead of crashing


def test_when_reading_parameter_file_expect_only_parameters_the_nodes_declare():
    params = yaml.safe_load((ROOT / "config" / "pepper.yaml").read_text())
    assert set(params) == {"/**", *NODE_EXECUTABLES}
    assert set(params["/**"]["ros__parameters"]) == {"model_path", "robot_description"}
    declared = {f.name for f in fields(MotionFilterSettings)} | {
        f.name for f in fields(LimitSettings)
    }
    declared |= {
        "joint_angles_speed",
        "joint_angles_rate_hz",
        "joint_trajectory_rate_hz",
        "joint_states_rate_hz",
    }
    filter_params = params["motion_filter_node"]["ros__parameters"]
    assert set(filter_params) <= declared
    # Defaults in the YAML equal the dataclass defaults, so the code and the file cannot drift.
    for settings in (MotionFilterSettings(), LimitSettings()):
        for f in fields(settings):
            if f.name in filter_params:
                assert filter_params[f.name] == getattr(settings, f.name), f.name


def test_when_reading_package_xml_expect_format_3_with_message_dependencies():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "audio2pose_ros"
    exec_deps = {e.text for e in root.findall("exec_depend")}
    imported = {
        "rclpy",
        "builtin_interfaces",
        "std_msgs",
        "sensor_msgs",
        "trajectory_msgs",
        "diagnostic_msgs",
        "audio_common_msgs",
        "naoqi_bridge_msgs",
    }
    assert imported <= exec_deps
    assert root.find("export/build_type").text == "ament_python"
