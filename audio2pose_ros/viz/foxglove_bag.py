"""A rosbag2 (MCAP) of a trajectory that Foxglove and RViz show as a moving robot.

Topics: /robot_description (std_msgs/String, once, offered as transient local like
robot_state_publisher's), /joint_states (sensor_msgs/JointState, every URDF joint with a position)
and /tf (tf2_msgs/TFMessage, one transform per URDF joint, from
:mod:`audio2pose_ros.robot.kinematics`),
one message each per trajectory sample.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from scipy.spatial.transform import Rotation

from audio2pose_ros.data.bag import typestore
from audio2pose_ros.offline.trajectory import Trajectory
from audio2pose_ros.robot.kinematics import RobotKinematics, UrdfJoint
from audio2pose_ros.topics import JOINT_STATES, ROBOT_DESCRIPTION, TF, absolute

_NO_TIME = QosTime(sec=0, nsec=0)


def _qos(durability: QosDurability) -> Qos:
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=1 if durability == QosDurability.TRANSIENT_LOCAL else 10,
        reliability=QosReliability.RELIABLE,
        durability=durability,
        deadline=_NO_TIME,
        lifespan=_NO_TIME,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_NO_TIME,
        avoid_ros_namespace_conventions=False,
    )


def write_foxglove_bag(
    path: str | Path,
    trajectory: Trajectory,
    kinematics: RobotKinematics,
    start_ns: int | None = None,
) -> Path:
    """Write ``trajectory`` as a new rosbag2 directory in MCAP storage.

    Args:
        path: the bag directory to create (must not exist); the .mcap file lies inside it.
        trajectory: angles of some of the URDF's movable joints; the others stay at default.
        kinematics: the robot's URDF (its text becomes /robot_description).
        start_ns: stamp of the trajectory's time 0 (ns since the epoch; default: now).

    Returns:
        The bag directory.

    Raises:
        FileExistsError: ``path`` exists already.

    """
    out = Path(path)
    if out.exists():
        raise FileExistsError(f"{out} exists already; a rosbag2 output must be a new directory")
    store = typestore()
    msgs = store.types
    base_ns = time.time_ns() if start_ns is None else start_ns
    joint_names = kinematics.movable_joint_names
    with Writer(out, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        description = writer.add_connection(
            absolute(ROBOT_DESCRIPTION),
            "std_msgs/msg/String",
            typestore=store,
            offered_qos_profiles=[_qos(QosDurability.TRANSIENT_LOCAL)],
        )
        states = writer.add_connection(
            absolute(JOINT_STATES),
            "sensor_msgs/msg/JointState",
            typestore=store,
            offered_qos_profiles=[_qos(QosDurability.VOLATILE)],
        )
        tf = writer.add_connection(
            absolute(TF),
            "tf2_msgs/msg/TFMessage",
            typestore=store,
            offered_qos_profiles=[_qos(QosDurability.VOLATILE)],
        )
        text = msgs["std_msgs/msg/String"](data=kinematics.urdf_xml)
        writer.write(description, base_ns, store.serialize_cdr(text, "std_msgs/msg/String"))
        for t_s, row in zip(trajectory.times_s, trajectory.angles_rad, strict=True):
            stamp_ns = base_ns + round(float(t_s) * 1e9)
            positions = kinematics.resolve(dict(zip(trajectory.joint_names, row, strict=True)))
            header = msgs["std_msgs/msg/Header"](stamp=_stamp(stamp_ns, msgs), frame_id="")
            state = msgs["sensor_msgs/msg/JointState"](
                header=header,
                name=list(joint_names),
                position=np.array([positions[n] for n in joint_names], dtype=np.float64),
                velocity=np.zeros(0, dtype=np.float64),
                effort=np.zeros(0, dtype=np.float64),
            )
            writer.write(states, stamp_ns, store.serialize_cdr(state, "sensor_msgs/msg/JointState"))
            transforms = [
                _transform_stamped(kinematics.joint(name), matrix, stamp_ns, msgs)
                for name, matrix in kinematics.joint_transforms(positions).items()
            ]
            message = msgs["tf2_msgs/msg/TFMessage"](transforms=transforms)
            writer.write(tf, stamp_ns, store.serialize_cdr(message, "tf2_msgs/msg/TFMessage"))
    return out


def _stamp(stamp_ns: int, msgs: dict[str, Any]) -> Any:
    return msgs["builtin_interfaces/msg/Time"](
        sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000
    )


def _transform_stamped(
    joint: UrdfJoint, matrix: np.ndarray, stamp_ns: int, msgs: dict[str, Any]
) -> Any:
    qx, qy, qz, qw = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    x, y, z = (float(v) for v in matrix[:3, 3])
    return msgs["geometry_msgs/msg/TransformStamped"](
        header=msgs["std_msgs/msg/Header"](stamp=_stamp(stamp_ns, msgs), frame_id=joint.parent),
        child_frame_id=joint.child,
        transform=msgs["geometry_msgs/msg/Transform"](
            translation=msgs["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
            rotation=msgs["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        ),
    )
