"""Package structure: executables, launch file, parameter files and package.xml agree.

`ros2 launch` is not available here, so the launch file is checked for structure: the
executables it starts exist, node names match them, the arguments it declares are the ones
audio2pose_ros.ros.launch_support checks, and the configuration files it installs name the same
controllers, topics and diagnostics as the code. test/test_launch_pepper.py runs it for real where
launch_testing is installed.
"""

import ast
import configparser
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.ros.console_runner import CONSOLE_NODE
from audio2pose_ros.ros.launch_support import ARGUMENTS, CONTROLLER_NAME, CONTROLLER_TOPIC
from audio2pose_ros.ros.supervisor import NODE_EXECUTABLES, SIM_NODE
from audio2pose_ros.ros.voice_graph import VOICE_NODE

ROOT = Path(__file__).resolve().parent.parent
LAUNCH_FILE = ROOT / "launch" / "pepper.launch.py"


def console_scripts() -> dict[str, str]:
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "setup.cfg")
    lines = cfg["options.entry_points"]["console_scripts"].strip().splitlines()
    return dict(line.split(" = ") for line in lines)


def launch_calls(function: str) -> list[ast.Call]:
    """Every call of ``function`` (a plain name) in the launch file."""
    tree = ast.parse(LAUNCH_FILE.read_text())
    return [
        call
        for call in ast.walk(tree)
        if isinstance(call, ast.Call) and getattr(call.func, "id", "") == function
    ]


def constant_keywords(call: ast.Call) -> dict[str, object]:
    """The keyword arguments of ``call`` that are literals."""
    return {kw.arg: kw.value.value for kw in call.keywords if isinstance(kw.value, ast.Constant)}


def test_when_reading_setup_cfg_expect_one_executable_per_node_plus_cli():
    scripts = console_scripts()
    assert set(scripts) == {*NODE_EXECUTABLES, SIM_NODE, CONSOLE_NODE, VOICE_NODE, "audio2pose"}
    for name in (*NODE_EXECUTABLES, SIM_NODE, CONSOLE_NODE, VOICE_NODE):
        # nodes/process.py makes the process safe to stop before the heavy imports
        assert scripts[name] == f"audio2pose_ros.ros.nodes.process:{name}"


def test_when_parsing_launch_file_expect_the_three_nodes_named_as_their_executables():
    tree = ast.parse(LAUNCH_FILE.read_text())
    started = [
        node.iter.elts
        for node in ast.walk(tree)
        if isinstance(node, ast.For) and isinstance(node.iter, ast.Tuple)
    ]
    assert [tuple(e.value for e in elts) for elts in started] == [NODE_EXECUTABLES]
    ours = [call for call in launch_calls("Node") if "PACKAGE" in ast.unparse(call)]
    keywords = [{kw.arg: ast.unparse(kw.value) for kw in call.keywords} for call in ours]
    assert [k["executable"] for k in keywords] == ["executable", f"{SIM_NODE!r}"]
    assert all(k["executable"] == k["name"] for k in keywords)


def test_when_parsing_launch_file_expect_no_respawn_flag_and_no_string_comparisons():
    # respawn=True restarts forever on Humble; NodeSupervisor bounds it. PythonExpression string
    # comparisons treated rviz:=True or rviz:=1 differently from IfCondition.
    source = LAUNCH_FILE.read_text()
    assert "respawn" not in {kw.arg for call in launch_calls("Node") for kw in call.keywords}
    assert "PythonExpression" not in source
    assert "condition=" not in source  # booleans are read by launch_support.parse_bool


def test_when_parsing_launch_file_expect_it_declares_exactly_the_checked_arguments():
    declared = [call.args[0].value for call in launch_calls("DeclareLaunchArgument")]
    assert sorted(declared) == sorted(ARGUMENTS)
    assert "for name in ARGUMENTS" in LAUNCH_FILE.read_text()


def test_when_parsing_launch_file_expect_other_packages_started_only_by_the_plan():
    started = {
        (kw["package"], kw["executable"])
        for kw in map(constant_keywords, launch_calls("Node"))
        if "package" in kw
    }
    assert started == {
        ("robot_state_publisher", "robot_state_publisher"),
        ("rviz2", "rviz2"),
        ("ros_gz_bridge", "parameter_bridge"),
        ("ros_gz_sim", "create"),
        ("controller_manager", "spawner"),
        ("diagnostic_aggregator", "aggregator_node"),
    }
    tree = ast.parse(LAUNCH_FILE.read_text())
    (visualisation,) = [
        f
        for f in ast.walk(tree)
        if isinstance(f, ast.FunctionDef) and f.name == "visualisation_and_simulation"
    ]
    branches = [
        ast.unparse(node.test) for node in ast.walk(visualisation) if isinstance(node, ast.If)
    ]
    assert branches == [
        "plan.commanded_state_publisher",
        "plan.rviz",
        "plan.sim == 'pybullet'",
        "plan.sim == 'gz'",
    ]
    # The commanded pose only feeds robot_state_publisher in the branch without a robot.
    assert ast.unparse(visualisation).count("COMMANDED_JOINT_STATES") == 1


def test_when_reading_controller_config_expect_pepper_controller_at_50_hz_on_the_launch_topic():
    config = yaml.safe_load((ROOT / "config" / "ros2_controllers.yaml").read_text())
    manager = config["controller_manager"]["ros__parameters"]
    assert manager["update_rate"] == 50
    assert (
        manager[CONTROLLER_NAME]["type"] == "joint_trajectory_controller/JointTrajectoryController"
    )
    assert tuple(config[CONTROLLER_NAME]["ros__parameters"]["joints"]) == load_robot().names
    assert f"/{CONTROLLER_NAME}/joint_trajectory" == CONTROLLER_TOPIC
    spawned = [
        ast.unparse(call)
        for call in launch_calls("Node")
        if constant_keywords(call).get("executable") == "spawner"
    ]
    assert any("arguments=[CONTROLLER_NAME]" in call for call in spawned)


def test_when_reading_diagnostic_analyzers_expect_one_analyzer_per_node_status_name():
    from types import SimpleNamespace

    from audio2pose_ros.ros.diagnosed_node import diagnostic_array

    config = yaml.safe_load((ROOT / "config" / "diagnostic_analyzers.yaml").read_text())
    group = config["analyzers"]["ros__parameters"]["audio2pose_ros"]
    assert group["type"] == "diagnostic_aggregator/AnalyzerGroup"
    analyzers = group["analyzers"].values()
    assert {a["type"] for a in analyzers} == {"diagnostic_aggregator/GenericAnalyzer"}
    expected = sorted(name for a in analyzers for name in a["expected"])
    clock = SimpleNamespace(now=lambda: SimpleNamespace(to_msg=lambda: None))
    names = []
    for node in NODE_EXECUTABLES:
        fake = SimpleNamespace(
            get_fully_qualified_name=lambda node=node: f"/{node}", get_clock=lambda: clock
        )
        names += [s.name for s in diagnostic_array(fake, b"\x00", "ok", {}).status]
    assert expected == sorted(names)
    assert 'glob("config/*.yaml")' in (ROOT / "setup.py").read_text()  # installed with the rest


def test_when_reading_parameter_file_expect_sections_for_the_launched_nodes_and_shared_ones():
    # Every value is checked against the nodes' declarations in test_parameter_docs.py; here:
    # the sections match the node names the launch file gives, and model_path is shared, so the
    # launch argument's override reaches both nodes that read it.
    params = yaml.safe_load((ROOT / "config" / "pepper.yaml").read_text())
    assert set(params) == {"/**", *NODE_EXECUTABLES, CONSOLE_NODE, VOICE_NODE}  # console, voice
    assert "model_path" in params["/**"]["ros__parameters"]


def test_when_reading_package_xml_expect_format_3_with_message_dependencies():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "audio2pose_ros"
    exec_deps = {e.text for e in root.findall("exec_depend")}
    imported = {
        "rclpy",
        "builtin_interfaces",
        "std_msgs",
        "std_srvs",
        "sensor_msgs",
        "trajectory_msgs",
        "diagnostic_msgs",
        "audio_common_msgs",
        "naoqi_bridge_msgs",
    }
    assert imported <= exec_deps
    assert {"launch_testing", "launch_ros"} <= {e.text for e in root.findall("test_depend")}
    assert root.find("export/build_type").text == "ament_python"


def test_when_reading_the_message_copies_expect_upstream_licence_and_source():
    naoqi = ET.parse(ROOT / "support" / "ros_msgs" / "naoqi_bridge_msgs" / "package.xml")
    assert naoqi.getroot().findtext("license") == "Apache-2.0"
    assert naoqi.getroot().findtext("url") == "https://github.com/ros-naoqi/naoqi_bridge_msgs2"
    audio = ET.parse(ROOT / "support" / "ros_msgs" / "audio_common_msgs" / "package.xml")
    assert audio.getroot().findtext("license") == "BSD"
    assert audio.getroot().findtext("url") == "https://github.com/ros-drivers/audio_common"
