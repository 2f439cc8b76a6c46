"""pepper_sim_node: a simulated Pepper that takes what naoqi_driver takes and reports like it.

Subscriptions:
    joint_angles (naoqi_bridge_msgs/JointAnglesWithSpeed): ALMotion ``setAngles`` commands
        (``command_input: joint_angles``, the default, as naoqi_driver).
    joint_trajectory_controller/joint_trajectory (trajectory_msgs/JointTrajectory): a ros2_control
        controller's input (``command_input: joint_trajectory``).
Publications:
    joint_states (sensor_msgs/JointState): the measured positions and velocities, at
        naoqi_driver's 50 Hz.
    /diagnostics (diagnostic_msgs/DiagnosticArray): heartbeat every 0.5 s with the commands
        taken and refused and the self-collisions executed (steps with an arm inside the body).
    camera/front/image_raw, camera/front/camera_info (sensor_msgs/Image rgb8, CameraInfo): the
        head camera's view of a small room, while someone subscribes
        (:class:`~audio2pose_ros.ros.nodes.sim_camera.SimCamera`).
    audio (naoqi_bridge_msgs/AudioBuffer): the robot's microphones, hearing the room and the
        voice its loudspeakers play (:mod:`~audio2pose_ros.ros.nodes.sim_voice`).

The robot's voice side (a fake ALAudioDevice over real libqi, loudspeakers, microphones) and the
emulated execution and loudspeaker latencies are
:class:`~audio2pose_ros.ros.nodes.sim_voice.SimVoice` and its parameters; a ``joint_angles``
command is taken ``execution_latency_s`` after it arrived.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from diagnostic_msgs.msg import DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros import topics
from audio2pose_ros.errors import InputError
from audio2pose_ros.parameters import param, settings_from, specs_of, validate_settings
from audio2pose_ros.robot.simulated_pepper import SimulatedPepper
from audio2pose_ros.ros.diagnosed_node import DiagnosedNode
from audio2pose_ros.ros.node_parameters import NodeParameters
from audio2pose_ros.ros.nodes.sim_camera import SimCamera
from audio2pose_ros.ros.nodes.sim_voice import SimVoice, SimVoiceSettings
from audio2pose_ros.ros.spin import run_node
from audio2pose_ros.voice.delay import DelayedCommands

COMMAND_INPUTS = ("joint_angles", "joint_trajectory")
STEP_PERIOD_S = 0.01  # the simulation follows the wall clock in steps of about this (s)
MAX_CATCH_UP_S = 0.1  # after a stall, at most this much simulated time is made up (s)
STATE_PERIOD_S = 0.02  # joint_states at 50 Hz, as naoqi_driver publishes them
MAX_COMMAND_BYTES = 64 * 1024  # a command for a few dozen joints; larger ones are dropped
MAX_TRAJECTORY_POINTS = 1000


@dataclass(frozen=True)
class PepperSimSettings:
    """The simulated robot's parameters."""

    command_input: str = field(
        default="joint_angles",
        metadata=param(
            "which command the robot follows: 'joint_angles' (naoqi_driver's JointAnglesWithSpeed)"
            " or 'joint_trajectory' (a ros2_control trajectory controller)",
            choices=COMMAND_INPUTS,
            read_only=True,
        ),
    )
    camera_fps: float = field(
        default=10.0,
        metadata=param(
            "frames a second the head camera renders at most, while someone subscribes to it "
            "(0: no camera)",
            minimum=0.0,
            maximum=30.0,
            unit="Hz",
            read_only=True,
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration."""
        validate_settings(self)


PARAMETERS = (*specs_of(PepperSimSettings), *specs_of(SimVoiceSettings))


class PepperSimNode(DiagnosedNode):
    """A simulated Pepper behind naoqi_driver's topics."""

    def __init__(self) -> None:
        """Declare the parameters, load the simulated robot and wire the topics."""
        super().__init__("pepper_sim_node")
        self.parameters = NodeParameters(self, PARAMETERS)
        self.settings = settings_from(PepperSimSettings, self.parameters.values)
        voice_settings = settings_from(SimVoiceSettings, self.parameters.values)
        self.sim = SimulatedPepper()
        # (names, angles, speed) of joint_angles commands, taken after the execution latency
        self.delayed: DelayedCommands[tuple[list[str], list[float], float]] = DelayedCommands(
            voice_settings.execution_latency_s
        )
        self.voice = SimVoice(self, voice_settings)
        # Commands coalesce: the newest one received before a step is followed, those it
        # replaced are counted (messages_superseded); a flood costs the node nothing per message.
        if self.settings.command_input == "joint_angles":
            self.commands = self.create_latest_subscription(
                JointAnglesWithSpeed, topics.JOINT_ANGLES, self.on_joint_angles, 10,
                MAX_COMMAND_BYTES,
            )  # fmt: skip
        else:
            self.commands = self.create_latest_subscription(
                JointTrajectory, topics.JOINT_TRAJECTORY, self.on_trajectory, 10,
                MAX_COMMAND_BYTES,
            )  # fmt: skip
        self.state_pub = self.create_publisher(JointState, topics.JOINT_STATES, 10)
        self.last_step_s = time.monotonic()
        # paced: no backlog of commands delays the simulation or its joint_states
        self.create_paced_timer(STEP_PERIOD_S, self.on_step)
        self.create_paced_timer(STATE_PERIOD_S, self.publish_state)
        self.camera = SimCamera(self, self.settings.camera_fps, self.measured_pose)

    def measured_pose(self) -> dict[str, float]:
        """The measured joint angles by name (the camera's pose)."""
        positions, _ = self.sim.measured()
        return {n: float(a) for n, a in zip(self.sim.robot.names, positions, strict=True)}

    def refuse(self, kind: str, exc: InputError) -> None:
        """WARN about a refused command; the robot keeps its previous targets."""
        self.report_problem("command_refused", DiagnosticStatus.WARN, f"{kind} refused: {exc}")

    def on_joint_angles(self, msg: JointAnglesWithSpeed) -> None:
        """ALMotion setAngles: absolute angles only, as naoqi_driver passes them on."""
        try:
            if msg.relative:
                raise InputError("relative angles are not supported; send absolute ones")
            command = (list(msg.joint_names), list(msg.joint_angles), float(msg.speed))
            if self.delayed.latency_s > 0.0:
                self.delayed.push(time.time(), command)
            else:
                self.sim.set_angles(*command)
        except InputError as exc:
            self.refuse("joint_angles", exc)

    def take_delayed(self) -> None:
        """Take the joint_angles commands whose execution latency is over."""
        for command in self.delayed.due(time.time()):
            try:
                self.sim.set_angles(*command)
            except InputError as exc:
                self.refuse("joint_angles", exc)

    def on_trajectory(self, msg: JointTrajectory) -> None:
        """Follow a trajectory's points at their times from now."""
        try:
            if not msg.points or len(msg.points) > MAX_TRAJECTORY_POINTS:
                raise InputError(
                    f"{len(msg.points)} points (1 to {MAX_TRAJECTORY_POINTS} are followed)"
                )
            times = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points]
            positions = [list(p.positions) for p in msg.points]
            if any(len(row) != len(msg.joint_names) for row in positions):
                raise InputError("every point needs one position per joint")
            self.sim.follow(list(msg.joint_names), times, positions)  # type: ignore[arg-type]
        except InputError as exc:
            self.refuse("joint_trajectory", exc)

    def on_step(self) -> None:
        """Take the newest command; advance the simulation to the wall clock.

        At most MAX_CATCH_UP_S is made up at once.
        """
        self.commands.serve()
        self.take_delayed()
        now = time.monotonic()
        elapsed = min(now - self.last_step_s, MAX_CATCH_UP_S)
        self.last_step_s = now
        self.sim.step(elapsed)

    def publish_state(self) -> None:
        """The measured joint states, as naoqi_driver publishes them."""
        positions, velocities = self.sim.measured()
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(self.sim.robot.names)
        msg.position = [float(v) for v in positions]
        msg.velocity = [float(v) for v in velocities]
        self.state_pub.publish(msg)

    def diagnostic_summary(self) -> tuple[bytes, str]:
        """ERROR while an arm has been inside the body; OK otherwise."""
        counts = self.sim.counts
        if counts.self_collision_steps:
            return DiagnosticStatus.ERROR, (
                f"simulated robot: an arm went inside the body in {counts.self_collision_steps} "
                f"steps (deepest {counts.deepest_m * 100:.1f} cm)"
            )
        return DiagnosticStatus.OK, f"simulated robot following {self.settings.command_input}"

    def diagnostic_values(self) -> dict[str, object]:
        """Commands, refusals, steps and executed self-collisions."""
        counts = self.sim.counts
        return {
            "commands": counts.commands,
            "commands_refused": counts.refused,
            "simulated_s": f"{self.sim.time_s:.2f}",
            "self_collision_steps": counts.self_collision_steps,
            "deepest_self_collision_cm": f"{counts.deepest_m * 100:.2f}",
            **self.camera.diagnostic_values(),
            **self.voice.diagnostic_values(),
        }

    def destroy_node(self) -> None:
        """Disconnect the simulation, end the camera and stop serving ALAudioDevice."""
        for part in ("camera", "voice", "sim"):  # those made before a failed construction
            if hasattr(self, part):
                getattr(self, part).close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run the node until shutdown."""
    run_node(PepperSimNode, "pepper_sim_node", args)


if __name__ == "__main__":
    main()
