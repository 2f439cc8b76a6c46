"""Start the audio2pose_ros graph: audio features -> inference -> motion filter.

Usage:
    ros2 launch audio2pose_ros pepper.launch.py
    ros2 launch audio2pose_ros pepper.launch.py params_file:=/path/to/my.yaml \
        model_path:=/path/to/model.safetensors audio_ns:=/audio

    ros2 launch audio2pose_ros pepper.launch.py rviz:=true        # + robot_state_publisher, RViz
    ros2 launch audio2pose_ros pepper.launch.py sim:=gz rviz:=true  # + gz sim with ros2_control

The nodes read config/pepper.yaml (or ``params_file``). Audio is expected on
``<audio_ns>/audio`` and ``<audio_ns>/audio_info`` as audio_capture publishes them; commands go to
/joint_angles (naoqi_driver), /joint_trajectory_controller/joint_trajectory (ros2_control) and
/joint_states. Without a ROS distro, ``audio2pose run`` starts the same executables with the same
parameter file.

Visualisation and simulation (urdf/pepper.urdf, primitive shapes):
- ``robot_state_publisher:=true`` publishes /robot_description and /tf from the commanded
  /joint_states; ``rviz:=true`` does too and opens RViz with config/pepper.rviz.
- ``sim:=gz`` starts gz sim (ros_gz_sim, empty world), spawns the URDF, whose ros2_control block
  loads gz_ros2_control with config/ros2_controllers.yaml, and spawns joint_state_broadcaster and
  joint_trajectory_controller, which executes the motion filter's trajectories. The simulated
  joint states go to /sim/joint_states, so robot_state_publisher shows the simulated robot, not the
  commands.
"""

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import Action, LaunchDescription
from launch.actions import DeclareLaunchArgument, IncludeLaunchDescription
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

SIM_JOINT_STATES = "/sim/joint_states"
# The nodes are respawned when they crash; a configuration error does not crash them (they idle
# and report it on /diagnostics), so respawning cannot loop.
RESPAWN_DELAY_S = 2.0


def robot_description() -> ParameterValue:
    """The URDF text, with the installed share directory where it says $(find audio2pose_ros)."""
    share = get_package_share_directory("audio2pose_ros")
    urdf = Path(share, "urdf", "pepper.urdf").read_text(encoding="utf-8")
    return ParameterValue(urdf.replace("$(find audio2pose_ros)", share), value_type=str)


def visualisation_and_simulation() -> list[Action]:
    """robot_state_publisher, RViz and gz sim + ros2_control, each behind its launch argument."""
    rsp = LaunchConfiguration("robot_state_publisher")
    rviz = LaunchConfiguration("rviz")
    sim = LaunchConfiguration("sim")
    gz = IfCondition(PythonExpression(["'", sim, "' == 'gz'"]))
    commanded = IfCondition(
        PythonExpression(
            ["('", rsp, "' == 'true' or '", rviz, "' == 'true') and '", sim, "' != 'gz'"]
        )
    )
    description = {"robot_description": robot_description()}
    return [
        DeclareLaunchArgument(
            "robot_state_publisher",
            default_value="false",
            description="Publish /robot_description and /tf from /joint_states (true/false)",
        ),
        DeclareLaunchArgument(
            "rviz", default_value="false", description="Open RViz with config/pepper.rviz"
        ),
        DeclareLaunchArgument(
            "sim",
            default_value="none",
            choices=["none", "gz"],
            description="'gz': simulate the robot in gz sim, driven through ros2_control",
        ),
        Node(
            package="robot_state_publisher",
            executable="robot_state_publisher",
            name="robot_state_publisher",
            parameters=[description],
            condition=commanded,
        ),
        Node(
            package="robot_state_publisher",
            executable="robot_state_publisher",
            name="robot_state_publisher",
            parameters=[description, {"use_sim_time": True}],
            remappings=[("joint_states", SIM_JOINT_STATES)],
            condition=gz,
        ),
        Node(
            package="rviz2",
            executable="rviz2",
            name="rviz2",
            arguments=[
                "-d",
                PathJoinSubstitution([FindPackageShare("audio2pose_ros"), "config", "pepper.rviz"]),
            ],
            condition=IfCondition(rviz),
        ),
        IncludeLaunchDescription(
            PathJoinSubstitution([FindPackageShare("ros_gz_sim"), "launch", "gz_sim.launch.py"]),
            launch_arguments={"gz_args": "-r empty.sdf"}.items(),
            condition=gz,
        ),
        Node(
            package="ros_gz_bridge",
            executable="parameter_bridge",
            name="clock_bridge",
            arguments=["/clock@rosgraph_msgs/msg/Clock[gz.msgs.Clock"],
            condition=gz,
        ),
        Node(
            package="ros_gz_sim",
            executable="create",
            name="spawn_pepper",
            arguments=["-topic", "robot_description", "-name", "pepper", "-z", "0.82"],
            condition=gz,
        ),
        Node(
            package="controller_manager",
            executable="spawner",
            name="spawn_joint_state_broadcaster",
            arguments=[
                "joint_state_broadcaster",
                "--controller-ros-args",
                f"-r /joint_states:={SIM_JOINT_STATES}",
            ],
            condition=gz,
        ),
        Node(
            package="controller_manager",
            executable="spawner",
            name="spawn_joint_trajectory_controller",
            arguments=["joint_trajectory_controller"],
            condition=gz,
        ),
    ]


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
            *visualisation_and_simulation(),
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
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            ),
            Node(
                package="audio2pose_ros",
                executable="inference_node",
                name="inference_node",
                parameters=shared,
                output="screen",
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            ),
            Node(
                package="audio2pose_ros",
                executable="motion_filter_node",
                name="motion_filter_node",
                parameters=[params_file],
                output="screen",
                respawn=True,
                respawn_delay=RESPAWN_DELAY_S,
            ),
        ]
    )
