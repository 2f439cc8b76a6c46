"""What the three nodes share: QoS profiles, message <-> numpy conversions, diagnostics, main()."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import rclpy
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from std_msgs.msg import Float32MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

# Audio: best effort matches both reliable and best-effort publishers (audio_capture is reliable);
# a deep queue absorbs bursts from GStreamer without dropping chunks.
AUDIO_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.BEST_EFFORT
)
# AudioInfo is latched (transient local) by audio_capture and republished every 5 s.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
# Between our own nodes: reliable, so no feature frame or pose is lost silently.
STREAM_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE
)
DIAGNOSTICS_PERIOD_S = 1.0


def features_to_msg(frames: np.ndarray, label: str) -> Float32MultiArray:
    """Pack (n_frames, n_features) features; dim[1].label names the feature set."""
    n_frames, n_features = frames.shape
    msg = Float32MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label="frames", size=n_frames, stride=n_frames * n_features),
        MultiArrayDimension(label=label, size=n_features, stride=n_features),
    ]
    msg.data = np.ascontiguousarray(frames, dtype=np.float32).ravel().tolist()
    return msg


def msg_to_features(msg: Float32MultiArray) -> tuple[np.ndarray, str]:
    """Unpack a features message; raises ValueError when the layout does not fit the data."""
    dims = msg.layout.dim
    if len(dims) != 2:
        raise ValueError(f"features message needs 2 layout dims, got {len(dims)}")
    n_frames, n_features = dims[0].size, dims[1].size
    data = np.asarray(msg.data, dtype=np.float32)
    if data.size != n_frames * n_features:
        raise ValueError(
            f"features message holds {data.size} values, layout says {n_frames}x{n_features}"
        )
    return data.reshape(n_frames, n_features), dims[1].label


def duration_msg(seconds: float) -> Duration:
    """A builtin_interfaces/Duration of ``seconds``."""
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def trajectory_msg(
    joint_names: Sequence[str],
    positions_rad: np.ndarray,
    period_s: float,
    velocities_rad_s: np.ndarray | None = None,
) -> JointTrajectory:
    """A JointTrajectory with one point per row of ``positions_rad``, ``period_s`` apart.

    The first point is due one period after the header stamp.
    """
    msg = JointTrajectory()
    msg.joint_names = list(joint_names)
    for i, row in enumerate(np.atleast_2d(positions_rad)):
        point = JointTrajectoryPoint()
        point.positions = [float(v) for v in row]
        if velocities_rad_s is not None:
            point.velocities = [float(v) for v in np.atleast_2d(velocities_rad_s)[i]]
        point.time_from_start = duration_msg((i + 1) * period_s)
        msg.points.append(point)
    return msg


def trajectory_positions(msg: JointTrajectory, joint_names: Sequence[str]) -> np.ndarray:
    """(n_points, n_joints) positions reordered to ``joint_names``.

    Raises:
        ValueError: a joint is missing, or a point has the wrong number of positions.

    """
    index = {name: i for i, name in enumerate(msg.joint_names)}
    missing = [n for n in joint_names if n not in index]
    if missing:
        raise ValueError(f"trajectory lacks joints {missing}")
    order = [index[n] for n in joint_names]
    rows = []
    for k, point in enumerate(msg.points):
        if len(point.positions) != len(msg.joint_names):
            raise ValueError(
                f"point {k} has {len(point.positions)} positions for {len(msg.joint_names)} joints"
            )
        rows.append(np.asarray(point.positions, dtype=np.float64)[order])
    return np.array(rows).reshape(-1, len(joint_names))


def diagnostic_array(
    node: Node, level: bytes, message: str, values: dict[str, object]
) -> DiagnosticArray:
    """A DiagnosticArray with one status named after the node."""
    status = DiagnosticStatus(
        level=level,
        name=f"audio2pose_ros: {node.get_name()}",
        message=message,
        hardware_id="pepper",
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )
    array = DiagnosticArray()
    array.header.stamp = node.get_clock().now().to_msg()
    array.status = [status]
    return array


class StartupError(RuntimeError):
    """A node cannot start with its parameters (bad model, robot file, settings)."""


class ConfigurationErrorNode(Node):
    """Stands in for a node whose configuration is unusable: safe, visible, never restarting.

    It publishes nothing but an ERROR status on /diagnostics every second, so the robot gets no
    commands from it, operators see why, and a supervisor that respawns crashed processes
    (``respawn=True`` in a launch file) is not sent into a restart loop.
    """

    def __init__(self, node_name: str, reason: str) -> None:
        """Log the reason and start the diagnostics timer."""
        super().__init__(node_name)
        self.reason = reason
        self.get_logger().fatal(f"cannot start: {reason}; idle until restarted with a fix")
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics)

    def publish_diagnostics(self) -> None:
        """ERROR status with the reason."""
        self.diagnostics_pub.publish(
            diagnostic_array(
                self,
                DiagnosticStatus.ERROR,
                f"configuration error: {self.reason}",
                {"state": "idle, publishing nothing"},
            )
        )


def run_node(factory: Callable[[], Node], node_name: str, args: list[str] | None = None) -> None:
    """The ros2/examples main: init, spin until Ctrl-C or shutdown, clean up.

    A :class:`StartupError` (bad model, robot file or settings) does not end the process: the
    node is replaced by a :class:`ConfigurationErrorNode` that says why on the log and on
    /diagnostics and publishes nothing else.
    """
    try:
        with rclpy.init(args=args):
            try:
                node = factory()
            except StartupError as exc:
                node = ConfigurationErrorNode(node_name, str(exc))
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
