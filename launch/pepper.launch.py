"""Start the audio2pose_ros graph: audio features -> inference -> motion filter.

Usage:
    ros2 launch audio2pose_ros pepper.launch.py
    ros2 launch audio2pose_ros pepper.launch.py params_file:=/path/to/my.yaml \
        model_path:=/path/to/model.safetensors audio_ns:=/audio

The nodes read config/pepper.yaml (or ``params_file``). Audio is expected on
``<audio_ns>/audio`` and ``<audio_ns>/audio_info`` as audio_capture publishes them; commands go to
/joint_angles (naoqi_driver), /joint_trajectory_controller/joint_trajectory (ros2_control) and
/joint_states. Without a ROS distro, ``audio2pose run`` starts the same executables with the same
parameter file.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    """Three nodes sharing one parameter file; audio topics remapped under ``audio_ns``."""
    params_file = LaunchConfiguration("params_file")
    model_path = LaunchConfiguration("model_path")
    audio_ns = LaunchConfiguration("audio_ns")
    # value_type=str: otherwise launch_ros reads the argument as YAML ('' -> None on older
    # distros, 'true' or '1' -> bool / int for a string parameter).
    shared = [params_file, {"model_path": ParameterValue(model_path, value_type=str)}]
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value=PathJoinSubstitution(
                    [FindPackageShare("audio2pose_ros"), "config", "pepper.yaml"]
                ),
                description="Parameter file for the three nodes",
            ),
            DeclareLaunchArgument(
                "model_path", default_value="", description="Checkpoint ('' = packaged default)"
            ),
            DeclareLaunchArgument(
                "audio_ns", default_value="/audio", description="Namespace of the audio topics"
            ),
            Node(
                package="audio2pose_ros",
                executable="audio_features_node",
                name="audio_features_node",
                parameters=shared,
                remappings=[
                    ("audio/audio", [audio_ns, "/audio"]),
                    ("audio/audio_info", [audio_ns, "/audio_info"]),
                ],
                output="screen",
            ),
            Node(
                package="audio2pose_ros",
                executable="inference_node",
                name="inference_node",
                parameters=shared,
                output="screen",
            ),
            Node(
                package="audio2pose_ros",
                executable="motion_filter_node",
                name="motion_filter_node",
                parameters=[params_file],
                output="screen",
            ),
        ]
    )
