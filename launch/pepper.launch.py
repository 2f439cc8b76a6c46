"""Start the audio2pose_ros graph: audio features -> inference -> motion filter.

Usage:
    ros2 launch audio2pose_ros pepper.launch.py
    ros2 launch audio2pose_ros pepper.launch.py params_file:=/path/to/my.yaml \
        model_path:=/path/to/model.safetensors audio_ns:=/audio
    ros2 launch audio2pose_ros pepper.launch.py style:=calm_reader      # a speaking style
    ros2 launch audio2pose_ros pepper.launch.py model_path:=/path/to/me  # a personal model

    ros2 launch audio2pose_ros pepper.launch.py rviz:=true     # + robot_state_publisher, RViz
    ros2 launch audio2pose_ros pepper.launch.py sim:=gz rviz:=true  # + gz sim with ros2_control

The nodes read config/pepper.yaml (or ``params_file``). Audio is expected on
``<audio_ns>/audio`` and ``<audio_ns>/audio_info`` as audio_capture publishes them; commands go to
/joint_angles (naoqi_driver) and ``controller_topic`` (ros2_control's
pepper_joint_trajectory_controller); the commanded pose goes to /commanded_joint_states, never to
/joint_states, which belongs to the robot (naoqi_driver or the simulator). Without a ROS distro,
``audio2pose run`` starts the same executables with the same parameter file.

Arguments (see ``ros2 launch audio2pose_ros pepper.launch.py --show-args``) are checked before
any node starts, by :func:`audio2pose_ros.ros.launch_support.plan_launch`; an unusable one stops the
launch with one line and exit status 1. Booleans accept what launch's IfCondition accepts
(true/false/1/0, any letter case). ``model_path`` precedence: the launch argument when not empty,
else the parameters file, else the package default.

Crashed nodes are restarted at once, then after 2, 4, 8, 8 s, at most 5 times in a row (a
process that ran 30 s starts a new row;
:class:`~audio2pose_ros.ros.launch_support.RespawnBudget`); a node that exits
with status 78 (it cannot start with its configuration) or one that crashes a 6th time in a row
stops the launch with one line and exit status 1. This replaces ``respawn=True``, which
restarts forever on Humble (it has no ``respawn_max_retries``).

Visualisation and simulation (urdf/pepper.urdf, primitive shapes):
- ``robot_state_publisher:=true`` (default: the value of ``rviz``) publishes /robot_description
  and /tf from /commanded_joint_states, for a graph without a robot. On a real robot naoqi_driver
  publishes them from the measured /joint_states: use ``rviz:=true robot_state_publisher:=false``.
- ``sim:=gz`` starts gz sim (ros_gz_sim, empty world), spawns the URDF, whose ros2_control block
  loads gz_ros2_control with config/ros2_controllers.yaml, and spawns joint_state_broadcaster and
  pepper_joint_trajectory_controller, which executes the motion filter's trajectories. The
  simulated robot publishes /joint_states like a real one; robot_state_publisher shows it.
- ``sim:=pybullet`` starts ``pepper_sim_node`` (this package, headless, 2 CPU cores are plenty):
  a simulated Pepper that follows /joint_angles as ALMotion's setAngles does and publishes the
  measured /joint_states at 50 Hz, with robot_state_publisher for RViz.

``single_process:=true`` runs the three nodes in one process and one executor
(``python -m audio2pose_ros.ros.nodes.single_process``, the same parameters and remappings): the
smallest footprint. The default stays three processes.

``console:=true`` starts console_node, the operator's web console (doc/console.md):
it prints the address to open; its settings (host, port, token, certificate) come from the
parameters file's ``console_node`` section.

``diagnostic_aggregator:=true`` starts diagnostic_aggregator with config/diagnostic_analyzers.yaml:
/diagnostics_agg (and rqt_robot_monitor) shows each node's status, missing or stale ones as such.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import Action, LaunchContext, LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    ExecuteProcess,
    IncludeLaunchDescription,
    OpaqueFunction,
    RegisterEventHandler,
    TimerAction,
)
from launch.event_handlers import OnProcessExit
from launch.events.process import ProcessExited
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.logging import get_logger
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from audio2pose_ros import topics
from audio2pose_ros.ros.launch_support import (
    ARGUMENTS,
    CONSOLE_EXECUTABLE,
    CONTROLLER_NAME,
    CONTROLLER_TOPIC,
    SINGLE_PROCESS_MODULE,
    LaunchPlan,
    RespawnBudget,
    plan_launch,
    single_process_arguments,
)

PACKAGE = "audio2pose_ros"
SINGLE_PROCESS = "audio2pose_nodes"  # the process of single_process:=true
VOICE_EXECUTABLE = "voice_out_node"  # voice_out:=... (the operator's voice out of the robot)


def declare_arguments() -> list[DeclareLaunchArgument]:
    """The launch arguments; their values are checked by ``plan_launch`` before anything runs."""
    share = Path(get_package_share_directory(PACKAGE))
    return [
        DeclareLaunchArgument(
            "params_file",
            default_value=str(share / "config" / "pepper.yaml"),
            description="Parameter file of the three nodes (must exist and parse as YAML)",
        ),
        DeclareLaunchArgument(
            "model_path",
            default_value="",
            description="Checkpoint; '' = the params_file's model_path, else the packaged model",
        ),
        DeclareLaunchArgument(
            "style",
            default_value="",
            description="Speaking style: a preset (config/styles: calm_reader, "
            "addressing_camera, lecturer), a style file or a personal model folder "
            "(audio2pose enroll); '' = the parameters file's style parameters",
        ),
        DeclareLaunchArgument(
            "audio_ns",
            default_value="/audio",
            description="Namespace of the audio topics <audio_ns>/audio and <audio_ns>/audio_info",
        ),
        DeclareLaunchArgument(
            "controller_topic",
            default_value=CONTROLLER_TOPIC,
            description="JointTrajectory topic of the ros2_control trajectory controller "
            f"(Pepper's ros2_control names it {CONTROLLER_NAME}, 50 Hz)",
        ),
        DeclareLaunchArgument(
            "rviz",
            default_value="false",
            description="Open RViz with config/pepper.rviz (true/false/1/0)",
        ),
        DeclareLaunchArgument(
            "robot_state_publisher",
            default_value=LaunchConfiguration("rviz"),
            description="Publish /robot_description and /tf from /commanded_joint_states when "
            "there is no robot or simulator (true/false/1/0; default: the value of rviz)",
        ),
        DeclareLaunchArgument(
            "sim",
            default_value="none",
            choices=["none", "gz", "pybullet"],
            description="'gz': simulate the robot in gz sim, driven through ros2_control; "
            "'pybullet': pepper_sim_node, a headless simulated Pepper that takes joint_angles "
            "and publishes joint_states as naoqi_driver does",
        ),
        DeclareLaunchArgument(
            "diagnostic_aggregator",
            default_value="false",
            description="Aggregate /diagnostics with config/diagnostic_analyzers.yaml into "
            "/diagnostics_agg (rqt_robot_monitor) (true/false/1/0)",
        ),
        DeclareLaunchArgument(
            "console",
            default_value="false",
            description="Start the operator's web console (console_node: talk from a browser, "
            "3D view, stop); it prints the address to open (true/false/1/0)",
        ),
        DeclareLaunchArgument(
            "single_process",
            default_value="false",
            description="Run the three nodes in one process and one executor, the smallest "
            "footprint; same topics and outputs (true/false/1/0)",
        ),
        DeclareLaunchArgument(
            "voice_out",
            default_value="off",
            description="The operator's voice out of the robot, held back to be heard with the "
            "motion: 'naoqi:tcp://HOST:9559' (Pepper's loudspeakers through NAOqi; with "
            "sim:=pybullet and 127.0.0.1 the simulated Pepper serves it), 'topic' (audio_out, "
            "for audio_common's audio_play) or 'off'",
        ),
    ]


class NodeSupervisor:
    """Starts the package's nodes and restarts a crashed one as a :class:`RespawnBudget` says.

    A node that exits while the launch is not shutting down is restarted after the budget's
    back-off; when the budget refuses (exit status 78, or too many restarts), the exception
    raised here ends the launch: launch logs it as one line and exits with status 1.
    """

    def __init__(self, plan: LaunchPlan) -> None:
        """Remember the plan; nothing starts before :meth:`start`."""
        self.plan = plan
        self.budget = RespawnBudget()
        self.started_s: dict[str, float] = {}

    def node(self, executable: str) -> ExecuteProcess:
        """A fresh action for one of the package's executables, or the single-process one."""
        if executable == SINGLE_PROCESS:
            arguments = single_process_arguments(self.plan, Path(tempfile.mkdtemp(PACKAGE)))
            return ExecuteProcess(
                cmd=[sys.executable, "-m", SINGLE_PROCESS_MODULE, *arguments],
                name=SINGLE_PROCESS,
                output="screen",
            )
        parameters: list[object] = [str(self.plan.params_file)]
        remappings: list[tuple[str, str]] = []
        if executable in ("audio_features_node", "inference_node"):
            # value_type=str: launch_ros would otherwise read the text as YAML ('1' -> int).
            parameters += [
                {name: ParameterValue(value, value_type=str)}
                for name, value in self.plan.model_path.items()
            ]
        if executable in ("audio_features_node", VOICE_EXECUTABLE):
            remappings = list(self.plan.audio_topics.items())
        if executable == VOICE_EXECUTABLE:
            parameters.append({"voice_out": ParameterValue(self.plan.voice_out, value_type=str)})
        if executable == "motion_filter_node":
            remappings = [(topics.JOINT_TRAJECTORY, self.plan.controller_topic)]
            parameters += [dict(self.plan.style)] if self.plan.style else []
        return Node(
            package=PACKAGE,
            executable=executable,
            name=executable,
            parameters=parameters,
            remappings=remappings,
            output="screen",
        )

    def start(self, executable: str, delay_s: float = 0.0) -> list[Action]:
        """The node and the handler that watches its exit; the node starts in ``delay_s``."""
        self.started_s[executable] = time.monotonic() + delay_s
        node = self.node(executable)
        on_exit = OnProcessExit(
            target_action=node,
            on_exit=lambda event, context: self.exited(executable, event, context),
        )
        return [RegisterEventHandler(on_exit), node]

    def exited(
        self, executable: str, event: ProcessExited, context: LaunchContext
    ) -> list[Action] | None:
        """Restart ``executable`` after its back-off, or end the launch with one line."""
        if context.is_shutdown:
            return None
        ran_s = time.monotonic() - self.started_s[executable]
        decision = self.budget.on_exit(executable, event.returncode, ran_s)
        if not decision.restart:
            raise decision.error()
        get_logger(PACKAGE).warning(decision.message)
        return [
            TimerAction(period=decision.delay_s, actions=self.start(executable, decision.delay_s))
        ]


def robot_description() -> ParameterValue:
    """The URDF text, with the installed share directory where it says $(find audio2pose_ros)."""
    share = get_package_share_directory(PACKAGE)
    urdf = Path(share, "urdf", "pepper.urdf").read_text(encoding="utf-8")
    return ParameterValue(urdf.replace(f"$(find {PACKAGE})", share), value_type=str)


def visualisation_and_simulation(plan: LaunchPlan) -> list[Action]:
    """robot_state_publisher, RViz and gz sim + ros2_control, as the plan asks."""
    actions: list[Action] = []
    if plan.commanded_state_publisher:
        actions.append(
            Node(
                package="robot_state_publisher",
                executable="robot_state_publisher",
                name="robot_state_publisher",
                parameters=[{"robot_description": robot_description()}],
                remappings=[(topics.JOINT_STATES, topics.COMMANDED_JOINT_STATES)],
            )
        )
    if plan.rviz:
        share = get_package_share_directory(PACKAGE)
        actions.append(
            Node(
                package="rviz2",
                executable="rviz2",
                name="rviz2",
                arguments=["-d", str(Path(share, "config", "pepper.rviz"))],
            )
        )
    if plan.sim == "pybullet":
        served = plan.voice_out.removeprefix("naoqi:")
        actions += [
            Node(
                package=PACKAGE,
                executable="pepper_sim_node",
                name="pepper_sim_node",
                # the fake ALAudioDevice, when the voice goes to NAOqi on this machine
                parameters=[{"naoqi_url": served}] if served.startswith("tcp://127.0.0.1:") else [],
                output="screen",
            ),
            # The simulated robot's measured joint states, on /joint_states like a real robot's.
            Node(
                package="robot_state_publisher",
                executable="robot_state_publisher",
                name="robot_state_publisher",
                parameters=[{"robot_description": robot_description()}],
            ),
        ]
    if plan.sim == "gz":
        gz_launch = Path(get_package_share_directory("ros_gz_sim"), "launch", "gz_sim.launch.py")
        actions += [
            IncludeLaunchDescription(
                PythonLaunchDescriptionSource(str(gz_launch)),
                launch_arguments={"gz_args": "-r empty.sdf"}.items(),
            ),
            # The simulated robot's measured joint states, on /joint_states like a real robot's.
            Node(
                package="robot_state_publisher",
                executable="robot_state_publisher",
                name="robot_state_publisher",
                parameters=[{"robot_description": robot_description()}, {"use_sim_time": True}],
            ),
            Node(
                package="ros_gz_bridge",
                executable="parameter_bridge",
                name="clock_bridge",
                arguments=["/clock@rosgraph_msgs/msg/Clock[gz.msgs.Clock"],
            ),
            Node(
                package="ros_gz_sim",
                executable="create",
                name="spawn_pepper",
                arguments=["-topic", "robot_description", "-name", "pepper", "-z", "0.82"],
            ),
            Node(
                package="controller_manager",
                executable="spawner",
                name="spawn_joint_state_broadcaster",
                arguments=["joint_state_broadcaster"],
            ),
            Node(
                package="controller_manager",
                executable="spawner",
                name="spawn_trajectory_controller",
                arguments=[CONTROLLER_NAME],
            ),
        ]
    return actions


def diagnostics(plan: LaunchPlan) -> list[Action]:
    """diagnostic_aggregator with the package's analyzers, when the plan asks for it."""
    if not plan.diagnostic_aggregator:
        return []
    analyzers = Path(get_package_share_directory(PACKAGE), "config", "diagnostic_analyzers.yaml")
    # No name: the analyzers file is keyed by the aggregator's own node name, "analyzers".
    return [
        Node(
            package="diagnostic_aggregator",
            executable="aggregator_node",
            parameters=[str(analyzers)],
        )
    ]


def launch_setup(context: LaunchContext) -> list[Action]:
    """Check the arguments, then start the graph (and the visualisation the arguments ask for)."""
    plan = plan_launch({name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS})
    supervisor = NodeSupervisor(plan)
    actions = visualisation_and_simulation(plan) + diagnostics(plan)
    if plan.console:
        actions += supervisor.start(CONSOLE_EXECUTABLE)
    if plan.voice_out != "off":
        actions += supervisor.start(VOICE_EXECUTABLE)
    if plan.single_process:
        return actions + supervisor.start(SINGLE_PROCESS)
    for executable in ("audio_features_node", "inference_node", "motion_filter_node"):
        actions += supervisor.start(executable)
    return actions


def generate_launch_description() -> LaunchDescription:
    """Declared arguments, then the graph built from their checked values."""
    return LaunchDescription([*declare_arguments(), OpaqueFunction(function=launch_setup)])
