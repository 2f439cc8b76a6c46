"""The graph's topic and service names as integrators see them: naoqi_driver, audio_capture,
ros2_control and diagnostic_aggregator expect exactly these in the root namespace."""

import ast
from pathlib import Path

from audio2pose_ros import topics

TOPIC_CALLS = (
    "create_publisher",
    "create_subscription",
    "create_bounded_subscription",
    "create_service",
    "create_client",
)


def test_topic_names_in_the_root_namespace_are_the_documented_interface():
    assert {
        name: topics.absolute(value)
        for name, value in vars(topics).items()
        if name.isupper() and isinstance(value, str)
    } == {
        "AUDIO": "/audio/audio",
        "AUDIO_INFO": "/audio/audio_info",
        "FEATURES": "/features",
        "VOICE_ACTIVITY": "/voice_activity",
        "RAW_TRAJECTORY": "/raw_trajectory",
        "JOINT_ANGLES": "/joint_angles",
        "JOINT_TRAJECTORY": "/joint_trajectory_controller/joint_trajectory",
        "COMMANDED_JOINT_STATES": "/commanded_joint_states",
        "JOINT_STATES": "/joint_states",
        "HEAD_TARGET": "/head_target",
        "HEAD_OFFSET": "/head_offset",
        "ENABLE": "/enable",
        "STOP": "/stop",
        "EMERGENCY_STOP": "/emergency_stop",
        "DISABLE_MOTION": "/disable_motion",
        "AUDIO_OUT": "/audio_out",
        "AUDIO_OUT_INFO": "/audio_out_info",
        "ROBOT_MICROPHONES": "/audio",
        "DIAGNOSTICS": "/diagnostics",
        "ROBOT_DESCRIPTION": "/robot_description",
        "TF": "/tf",
        "CAMERA_IMAGE": "/camera/front/image_raw",
        "CAMERA_INFO": "/camera/front/camera_info",
    }


def test_graph_topics_are_relative_so_namespaces_and_remaps_move_them():
    graph = [v for k, v in vars(topics).items() if k.isupper() and k != "DIAGNOSTICS"]
    assert all(not name.startswith("/") for name in graph)
    assert topics.absolute("/diagnostics") == "/diagnostics"


def literal_topics(source: str) -> list[str]:
    """String literals passed as the topic (service) name of the calls that create its ends."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in TOPIC_CALLS
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Constant)
            and isinstance(node.args[1].value, str)
        ):
            found.append(f"line {node.lineno}: {node.args[1].value!r}")
    return found


def test_no_module_names_a_topic_or_service_with_a_string_literal():
    package = Path(topics.__file__).parent
    found = {
        str(path.relative_to(package)): hits
        for path in sorted(package.rglob("*.py"))
        if (hits := literal_topics(path.read_text()))
    }
    assert found == {}


def test_literal_topic_check_finds_a_literal():
    source = 'node.create_publisher(Bool, "stop", 10)\nnode.create_subscription(Bool, STOP, f, 1)\n'
    assert literal_topics(source) == ["line 1: 'stop'"]
