"""The graph's topic names as integrators see them: naoqi_driver, audio_capture, ros2_control and
diagnostic_aggregator expect exactly these in the root namespace."""

from audio2pose_ros import topics


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
        "DIAGNOSTICS": "/diagnostics",
        "ROBOT_DESCRIPTION": "/robot_description",
        "TF": "/tf",
    }


def test_graph_topics_are_relative_so_namespaces_and_remaps_move_them():
    graph = [v for k, v in vars(topics).items() if k.isupper() and k != "DIAGNOSTICS"]
    assert all(not name.startswith("/") for name in graph)
    assert topics.absolute("/diagnostics") == "/diagnostics"
