"""The fault campaign's harness: the probe that plays the world, and what each case measures.

:class:`CampaignProbe` streams the benign pose, echoes the commands as the measured joint states
and records what the robot receives; :class:`Campaign` settles the graph, runs one fault and
reads the :class:`Outcome` (worst deviation, limits, steps, gaps) from the commands. The cases
are in :mod:`~audio2pose_ros.ros.tools.fault_campaign`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.client import Client
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float32MultiArray
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from audio2pose_ros import topics
from audio2pose_ros.offline.parameters_file import FILTER_NODE
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.ros.messages import stamp_s
from audio2pose_ros.ros.qos import LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.supervisor import NodeSupervisor

MAX_DEVIATION_RAD = 0.1  # one bad input moves no joint more than about this


SETTLE_TOLERANCE_RAD = 0.005


STREAM_PERIOD_S = 0.02  # the benign stream: 2 points of 10 ms every 20 ms


MEASURED_PERIOD_S = 0.02  # naoqi_driver publishes the measured joint states at 50 Hz


OBSERVE_S = 2.0  # how long each case watches the robot after its fault


STEP_TOLERANCE = 1.05  # a step may exceed v_max * dt by this factor (timing jitter of dt)


# Commands must keep flowing: no gap longer than this. Decoding a 100,000-point message stops a
# node for about 1 s; the probe's own scheduling on a busy 2-core machine adds up to ~0.1 s.
MAX_COMMAND_GAP_S = 0.3


STALE_LEVEL = 3  # diagnostic_msgs/DiagnosticStatus.STALE


@dataclass
class Outcome:
    """What the robot did in one case."""

    did: str
    passed: bool
    worst_deviation_rad: float = math.nan


@dataclass
class Case:
    """One attack: a name, what the robot must do, and the function that runs it."""

    name: str
    must: str
    run: Callable[[Campaign], Outcome]


@dataclass
class Commands:
    """The commands the robot received during an observation window."""

    # (n,) the time each command was computed for (its header stamp, set by the filter at its
    # tick): gaps and steps are the graph's, not delays of this probe, which blocks while it
    # publishes a fault (an 11 MB message takes it a few hundred ms under load)
    times_s: np.ndarray
    positions_rad: np.ndarray  # (n, n_joints)

    def worst_deviation(self, pose: np.ndarray, mask: np.ndarray | None = None) -> float:
        """Largest |command - pose| over the window (rad), inf if any command is not finite."""
        if len(self.positions_rad) == 0:
            return math.nan
        error = np.abs(self.positions_rad - pose[None, :])
        if mask is not None:
            error = error[:, mask]
        return float(np.max(error)) if np.isfinite(error).all() else math.inf

    def longest_gap_s(self) -> float:
        """Longest time without a command (s)."""
        return float(np.max(np.diff(self.times_s))) if len(self.times_s) > 1 else math.inf


class CampaignProbe(Node):
    """The world around the graph: raw poses, voice, stop/enable, head targets, audio, robot."""

    def __init__(self, robot: RobotDescription) -> None:
        """Publishers for every input of the graph; recorders for what the robot receives."""
        super().__init__("audio2pose_fault_campaign")
        self.robot = robot
        self.raw = self.create_publisher(JointTrajectory, topics.RAW_TRAJECTORY, STREAM_QOS)
        self.voice = self.create_publisher(Bool, topics.VOICE_ACTIVITY, STREAM_QOS)
        self.stop = self.create_publisher(Bool, topics.STOP, LATCHED_QOS)
        self.enable = self.create_publisher(Bool, topics.ENABLE, LATCHED_QOS)
        self.head_target = self.create_publisher(JointState, topics.HEAD_TARGET, 10)
        self.head_offset = self.create_publisher(JointState, topics.HEAD_OFFSET, 10)
        self.measured = self.create_publisher(JointState, topics.JOINT_STATES, 10)
        self.audio = self.create_publisher(AudioData, topics.AUDIO, 100)
        self.audio_info = self.create_publisher(AudioInfo, topics.AUDIO_INFO, LATCHED_QOS)
        self.set_filter_parameters: Client[SetParameters.Request, SetParameters.Response]
        self.set_filter_parameters = self.create_client(
            SetParameters, f"{FILTER_NODE}/set_parameters"
        )
        self.commands: list[tuple[float, np.ndarray]] = []
        self.features = 0
        self.diagnostics: dict[str, tuple[int, str, dict[str, str]]] = {}
        self.stale_reports: dict[str, int] = {}
        self.create_subscription(JointAnglesWithSpeed, topics.JOINT_ANGLES, self._on_command, 1000)
        self.create_subscription(Float32MultiArray, topics.FEATURES, self._on_features, 100)
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 100)
        self.pose = robot.neutral_rad.copy()
        self.robot_pose = robot.neutral_rad.copy()
        self.streaming = True
        self.robot_reports = True  # publish the measured joint states, as naoqi_driver does
        self._next_send_s = 0.0
        self._next_measured_s = 0.0

    def _on_command(self, msg: JointAnglesWithSpeed) -> None:
        index = {name: i for i, name in enumerate(msg.joint_names)}
        values = np.array(
            [msg.joint_angles[index[n]] if n in index else math.nan for n in self.robot.names]
        )
        stamp = msg.header.stamp
        self.commands.append((stamp_s(stamp), values))
        if np.isfinite(values).all():
            self.robot_pose = values  # a perfect robot: it is where it was last commanded

    def _on_features(self, msg: Float32MultiArray) -> None:
        self.features += len(msg.layout.dim) and msg.layout.dim[0].size

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            name = status.name.rpartition(": ")[2].lstrip("/")  # the graph's namespace is /
            values = {kv.key: kv.value for kv in status.values}
            level = int.from_bytes(status.level, "little")
            self.diagnostics[name] = (level, status.message, values)
            if level == STALE_LEVEL:
                self.stale_reports[name] = self.stale_reports.get(name, 0) + 1

    def joint_state_msg(
        self, values: np.ndarray, names: tuple[str, ...] | None = None
    ) -> JointState:
        """A JointState stamped now: ``values`` for ``names`` (default: every joint)."""
        msg = JointState()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.name = list(names or self.robot.names)
        msg.position = [float(v) for v in values]
        return msg

    def trajectory(self, rows: np.ndarray, stamp: Time | None = None) -> JointTrajectory:
        """A raw_trajectory message like inference_node's: 10 ms points."""
        msg = JointTrajectory()
        msg.header.stamp = stamp or self.get_clock().now().to_msg()
        msg.joint_names = list(self.robot.names)
        for i, row in enumerate(np.atleast_2d(rows)):
            point = JointTrajectoryPoint()
            point.positions = [float(v) for v in row]
            point.time_from_start.nanosec = 10_000_000 * (i + 1)
            msg.points.append(point)
        return msg

    def spin_for(self, seconds: float) -> None:
        """Serve callbacks and keep the benign stream going for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            now = time.monotonic()
            if self.streaming and now >= self._next_send_s:
                self._next_send_s = now + STREAM_PERIOD_S
                self.raw.publish(self.trajectory(np.stack([self.pose, self.pose])))
                self.voice.publish(Bool(data=True))
            if self.robot_reports and now >= self._next_measured_s:
                self._next_measured_s = now + MEASURED_PERIOD_S
                self.measured.publish(self.joint_state_msg(self.robot_pose))
            rclpy.spin_once(self, timeout_sec=0.002)

    def observe(self, seconds: float) -> Commands:
        """Commands received during the next ``seconds``."""
        start = len(self.commands)
        self.spin_for(seconds)
        window = self.commands[start:]
        n = self.robot.n_joints
        return Commands(
            np.array([t for t, _ in window]),
            np.array([p for _, p in window]).reshape(-1, n),
        )

    def observe_restart(self, killed_s: float, timeout_s: float, seconds: float) -> Commands:
        """Commands stamped after ``killed_s``: from the first (awaited up to ``timeout_s``) on.

        A restarted filter commands nothing until it knows where to start, which takes longer
        when a publisher of joint_states is awaited; how long is not the verdict: what it
        commands, for ``seconds`` from its first command, is.
        """
        start = len(self.commands)
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not any(t > killed_s for t, _ in self.commands[start:]):
            self.spin_for(0.02)
        self.spin_for(seconds)
        window = [(t, p) for t, p in self.commands[start:] if t > killed_s]
        return Commands(
            np.array([t for t, _ in window]),
            np.array([p for _, p in window]).reshape(-1, self.robot.n_joints),
        )

    def settle(self, pose: np.ndarray, timeout_s: float = 15.0) -> bool:
        """Stream ``pose`` until the commands sit on it."""
        self.pose = pose.copy()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            window = self.observe(0.3)
            if len(window.times_s) and window.worst_deviation(pose) < SETTLE_TOLERANCE_RAD:
                return True
        return False

    def set_parameter(self, name: str, value: object) -> tuple[bool, str]:
        """Set one parameter of motion_filter_node at run time: (successful, reason)."""
        parameter_value = ParameterValue()
        if isinstance(value, bool):
            parameter_value.type, parameter_value.bool_value = ParameterType.PARAMETER_BOOL, value
        elif isinstance(value, int):
            parameter_value.type = ParameterType.PARAMETER_INTEGER
            parameter_value.integer_value = value
        elif isinstance(value, float):
            parameter_value.type = ParameterType.PARAMETER_DOUBLE
            parameter_value.double_value = value
        else:
            parameter_value.type = ParameterType.PARAMETER_STRING
            parameter_value.string_value = str(value)
        request = SetParameters.Request(parameters=[Parameter(name=name, value=parameter_value)])
        if not self.set_filter_parameters.wait_for_service(timeout_sec=10.0):
            return False, "no set_parameters service"
        future = self.set_filter_parameters.call_async(request)
        deadline = time.monotonic() + 5.0
        while not future.done() and time.monotonic() < deadline:
            self.spin_for(0.01)
        if not future.done():
            return False, "no answer"
        response = future.result()
        if response is None:
            return False, "no answer"
        result = response.results[0]
        return bool(result.successful), result.reason


@dataclass
class Campaign:
    """The running graph, the probe and what the cases share."""

    supervisor: NodeSupervisor
    probe: CampaignProbe
    robot: RobotDescription
    rows: list[tuple[Case, Outcome]] = field(default_factory=list)
    state_file: Path = Path()  # the filter's state file (alone in its directory)

    @property
    def pose_a(self) -> np.ndarray:
        """The benign pose the cases start from: neutral with the arms and head moved."""
        pose = self.robot.neutral_rad.copy()
        moves = (
            ("LShoulderPitch", -0.4),
            ("LShoulderRoll", 0.28),
            ("RElbowRoll", 0.3),
            ("HeadYaw", 0.2),
        )
        for name, delta in moves:  # the left arm forward and out: clear of the body
            pose[self.robot.names.index(name)] += delta
        return np.clip(pose, self.robot.lower_rad + 0.05, self.robot.upper_rad - 0.05)

    @property
    def pose_b(self) -> np.ndarray:
        """A second benign pose, to show that tracking goes on after a fault."""
        pose = self.pose_a.copy()
        pose[self.robot.names.index("LShoulderPitch")] += 0.2
        return pose

    def max_step_ratio(self, commands: Commands) -> float:
        """Largest step between commands over what the velocity limit allows for its time."""
        if len(commands.times_s) < 2:
            return math.nan
        steps = np.abs(np.diff(commands.positions_rad, axis=0))
        # dt of the arrivals, but at least the output period: DDS may deliver two at once
        dt = np.maximum(np.diff(commands.times_s), 0.02)[:, None]
        return float(np.max(steps / (self.robot.max_velocity_rad_s[None, :] * dt)))

    def inside_limits(self, commands: Commands) -> bool:
        """Every command finite and inside the position limits."""
        p = commands.positions_rad
        return bool(
            np.isfinite(p).all()
            and (p >= self.robot.lower_rad - 1e-9).all()
            and (p <= self.robot.upper_rad + 1e-9).all()
        )

    def pid(self, node: str) -> int:
        """PID of a node's current process."""
        return self.supervisor.processes[node].pid
