"""The bare rclpy floor of the graph benchmark: the graph's topology with no work in it.

``audio2pose bench --graph`` compares the three node processes with three relay processes that
a plain rclpy program would need for the same data path, run in the same benchmark run on the
same chunks, so a loaded machine raises both figures together and their ratio says what our
nodes add to rclpy's own cost:

- ``audio_features_node``: takes ``audio/audio`` (AudioData, :data:`AUDIO_QOS`) and
  ``audio/audio_info`` (latched) and publishes one ``features`` message (Float32MultiArray of
  ``--features`` zeros) per audio message;
- ``inference_node``: takes ``features`` and publishes one ``raw_trajectory`` (JointTrajectory,
  one point of ``--joints`` positions) per features message;
- ``motion_filter_node``: keeps the last raw pose and, on a timer of ``--rate-hz``, publishes
  ``joint_angles``, ``commanded_joint_states`` and the controller's ``joint_trajectory`` at
  ``--output-hz`` each, as the filter does with its default output rates.

Each relay also publishes a heartbeat on ``/diagnostics`` every
:data:`~audio2pose_ros.ros.diagnosed_node.HEARTBEAT_PERIOD_S`, with the nodes' QoS (a relay must
match its publishers). It loads what every node loads (rclpy, the message types, numpy) and
nothing else: no features, no model, no body.

Which executor a relay spins in (``--executor``):

- ``plain`` (the default, the floor ``audio2pose bench --graph`` reports against): rclpy's
  default, the SingleThreadedExecutor that ``rclpy.spin`` uses, as a plain rclpy program of
  the ros2/examples would;
- ``node``: the executor its node spins in (:func:`~audio2pose_ros.ros.executor.create_executor`),
  which measures what the nodes' work adds over the same transport.

Run one relay with
``python -m audio2pose_ros.ros.tools.relay_floor ROLE [--features N] [--joints J] [--executor E]``;
with several roles, one process runs their relays in one executor (the floor of the graph in
one process, ``audio2pose run --single-process``: a plain rclpy program composing three nodes).
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence

import rclpy
from audio_common_msgs.msg import AudioData, AudioInfo
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from naoqi_bridge_msgs.msg import JointAnglesWithSpeed
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float32MultiArray, Header, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from audio2pose_ros import topics
from audio2pose_ros.ros.diagnosed_node import HEARTBEAT_PERIOD_S
from audio2pose_ros.ros.executor import create_executor, shutdown
from audio2pose_ros.ros.launch_support import CONTROLLER_TOPIC
from audio2pose_ros.ros.nodes.process import STOP_SIGNALS, prepare_node_process
from audio2pose_ros.ros.qos import AUDIO_QOS, LATCHED_QOS, STREAM_QOS
from audio2pose_ros.ros.spin import spin_executor

ROLES = ("audio_features_node", "inference_node", "motion_filter_node")
EXECUTORS = ("plain", "node")  # rclpy.spin's default executor, or the one the node spins in
FILTER_RATE_HZ = 100.0  # the filter's tick (config/pepper.yaml rate_hz)
OUTPUT_RATE_HZ = 50.0  # joint_angles, joint_trajectory and commanded_joint_states


class _Relay(Node):
    """One relay: its heartbeat, and the role's subscriptions and publishers."""

    def __init__(self, role: str, n_features: int, n_joints: int) -> None:
        super().__init__(role)
        self.names = [f"joint_{i}" for i in range(n_joints)]
        self.pose = [0.0] * n_joints
        self.diagnostics = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, 10)
        self.create_timer(HEARTBEAT_PERIOD_S, self.heartbeat)
        if role == "audio_features_node":
            self.zeros = [0.0] * n_features
            self.features = self.create_publisher(Float32MultiArray, topics.FEATURES, STREAM_QOS)
            self.create_subscription(AudioInfo, topics.AUDIO_INFO, lambda _: None, LATCHED_QOS)
            self.create_subscription(AudioData, topics.AUDIO, self.on_audio, AUDIO_QOS)
        elif role == "inference_node":
            self.raw = self.create_publisher(JointTrajectory, topics.RAW_TRAJECTORY, STREAM_QOS)
            self.create_subscription(
                Float32MultiArray, topics.FEATURES, self.on_features, STREAM_QOS
            )
        else:
            self.create_subscription(
                JointTrajectory, topics.RAW_TRAJECTORY, self.on_raw, STREAM_QOS
            )
            self.angles = self.create_publisher(JointAnglesWithSpeed, topics.JOINT_ANGLES, 10)
            self.states = self.create_publisher(JointState, topics.COMMANDED_JOINT_STATES, 10)
            self.trajectory = self.create_publisher(JointTrajectory, CONTROLLER_TOPIC, 10)
            self.ticks = 0
            self.every = max(round(FILTER_RATE_HZ / OUTPUT_RATE_HZ), 1)
            self.create_timer(1.0 / FILTER_RATE_HZ, self.on_tick)

    def heartbeat(self) -> None:
        """What every node sends on /diagnostics, busy or idle."""
        status = DiagnosticStatus(level=DiagnosticStatus.OK, name=self.get_name(), message="ok")
        header = Header(stamp=self.get_clock().now().to_msg())
        self.diagnostics.publish(DiagnosticArray(header=header, status=[status]))

    def on_audio(self, _msg: AudioData) -> None:
        """One feature frame per audio chunk (the bench sends one frame step per chunk)."""
        msg = Float32MultiArray(data=self.zeros)
        msg.layout.dim = [
            MultiArrayDimension(label="frames", size=1, stride=len(self.zeros)),
            MultiArrayDimension(label="features", size=len(self.zeros), stride=len(self.zeros)),
        ]
        self.features.publish(msg)

    def on_features(self, _msg: Float32MultiArray) -> None:
        """One raw pose per feature frame."""
        point = JointTrajectoryPoint(positions=self.pose, time_from_start=Duration())
        self.raw.publish(JointTrajectory(joint_names=self.names, points=[point]))

    def on_raw(self, msg: JointTrajectory) -> None:
        """Keep the newest pose."""
        if msg.points:
            self.pose = list(msg.points[-1].positions)

    def on_tick(self) -> None:
        """The filter's tick; every other one sends the three outputs."""
        self.ticks += 1
        if self.ticks % self.every:
            return
        self.angles.publish(
            JointAnglesWithSpeed(joint_names=self.names, joint_angles=self.pose, speed=0.5)
        )
        self.states.publish(JointState(name=self.names, position=self.pose))
        point = JointTrajectoryPoint(
            positions=self.pose, time_from_start=Duration(nanosec=20_000_000)
        )
        self.trajectory.publish(JointTrajectory(joint_names=self.names, points=[point]))


def relay_executor(executor: str) -> Executor:
    """The executor a relay spins in: ``plain`` (rclpy's default) or ``node`` (its node's)."""
    if executor not in EXECUTORS:
        raise ValueError(f"executor must be one of {EXECUTORS}, got {executor!r}")
    if executor == "plain":
        return SingleThreadedExecutor()
    return create_executor()


def main(argv: Sequence[str] | None = None) -> None:
    """Run one relay until SIGTERM or Ctrl-C; it dies with the process that started it."""
    prepare_node_process()
    parser = argparse.ArgumentParser(prog="python -m audio2pose_ros.ros.tools.relay_floor")
    parser.add_argument("roles", nargs="+", choices=ROLES, metavar="ROLE")
    parser.add_argument("--features", type=int, default=26, help="floats per feature frame")
    parser.add_argument("--joints", type=int, default=11, help="joints per pose")
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="plain",
        help="rclpy.spin's SingleThreadedExecutor (plain, default) or the node's own (node)",
    )
    args, ros_args = parser.parse_known_args(argv)
    rclpy.init(args=[sys.argv[0], *ros_args])
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    try:
        executor = relay_executor(args.executor)
        for role in dict.fromkeys(args.roles):
            executor.add_node(_Relay(role, args.features, args.joints))
        spin_executor(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        shutdown()


if __name__ == "__main__":
    main()
