"""The graph's stream messages as rclpy objects and numpy arrays: features and trajectories.

A features message carries (n_frames, n_features) float32 values, its feature set named in
dim[1].label and, optionally, the index of its first frame in dim[0].label ("frames from N"), so
the receiver counts the frames lost between messages. A raw trajectory is a JointTrajectory of
one point per 10 ms frame, read by the motion filter as a :class:`RawTrajectory`. The nodes,
tools and tests send and read them as rclpy's message objects, whose serialization is rclpy's
own (``rclpy.serialization``). Also here: what the middleware tells about a message (its
publisher, when it was published; :mod:`audio2pose_ros.ros.subscriptions`) and the largest raw
trajectory worth decoding.
"""

from __future__ import annotations

import array
import time
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
from builtin_interfaces.msg import Duration, Time
from std_msgs.msg import Float32MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from audio2pose_ros.errors import InputError
from audio2pose_ros.ros.subscriptions import MessageInfo

FRAMES_LABEL = "frames"  # dim[0] of a features message; "frames from N" numbers its first frame


class FeatureBatch(NamedTuple):
    """An unpacked features message."""

    frames: np.ndarray  # (n_frames, n_features) float32
    label: str  # the feature set (dim[1].label)
    first_frame: int | None  # index of the first frame in its stream, if the sender numbers them


def features_to_msg(
    frames: np.ndarray, label: str, first_frame: int | None = None
) -> Float32MultiArray:
    """Pack (n_frames, n_features) features; dim[1].label names the feature set.

    With ``first_frame``, dim[0].label is ``"frames from <first_frame>"``: the receiver counts
    the frames lost between messages (:class:`~audio2pose_ros.timebase.FrameSequence`). A
    receiver that reads only the sizes is unaffected.
    """
    n_frames, n_features = frames.shape
    msg = Float32MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(
            label=frames_label(first_frame), size=n_frames, stride=n_frames * n_features
        ),
        MultiArrayDimension(label=label, size=n_features, stride=n_features),
    ]
    # An array.array of the right type code is stored as is; a list is checked value by value.
    msg.data = array.array("f", np.ascontiguousarray(frames, dtype=np.float32).tobytes())
    return msg


def frames_label(first_frame: int | None) -> str:
    """dim[0].label of a features message: ``"frames"``, or ``"frames from <first_frame>"``."""
    return FRAMES_LABEL if first_frame is None else f"{FRAMES_LABEL} from {first_frame}"


def msg_to_features(msg: Float32MultiArray) -> FeatureBatch:
    """Unpack a features message; a dim[0].label other than ``"frames from <n>"`` numbers nothing.

    Raises:
        InputError: the layout does not describe the data (see :func:`feature_batch`).
    """
    data = np.frombuffer(msg.data, dtype=np.float32) if msg.data else np.zeros(0, np.float32)
    return feature_batch([(d.label, d.size) for d in msg.layout.dim], data)


def feature_batch(dims: Sequence[tuple[str, int]], data: np.ndarray) -> FeatureBatch:
    """A features message's (label, size) dims and float32 values as a :class:`FeatureBatch`.

    Raises:
        InputError: the layout does not describe the data (2 dims, frames x features, at least
            one feature per frame: a count of frames without data would be a claim, not data).
    """
    if len(dims) != 2:
        raise InputError(f"features message needs 2 layout dims, got {len(dims)}")
    (frames_label, n_frames), (label, n_features) = dims
    if n_features == 0:
        raise InputError(f"features message of {n_frames} frames of 0 features")
    if data.size != n_frames * n_features:
        raise InputError(
            f"features message holds {data.size} values, layout says {n_frames}x{n_features}"
        )
    number = frames_label.removeprefix(f"{FRAMES_LABEL} from ")
    numbered = number != frames_label and number.isascii() and number.isdigit()
    first = int(number) if numbered and len(number) <= 18 else None  # within int64
    return FeatureBatch(data.reshape(n_frames, n_features), label, first)


def duration_msg(seconds: float) -> Duration:
    """A builtin_interfaces/Duration of ``seconds``."""
    nanoseconds = round(seconds * 1e9)
    return Duration(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def stamp_s(stamp: Time) -> float:
    """A builtin_interfaces/Time (a header stamp) in seconds."""
    return float(stamp.sec + stamp.nanosec * 1e-9)


def published_s(info: MessageInfo | None) -> float | None:
    """When a message was published (publisher's wall clock), else its reception; None: unknown.

    Unknown where rclpy passes no info (Humble, the EventsExecutor).
    """
    if info is None:
        return None
    source_ns = info.get("source_timestamp") or info.get("received_timestamp") or 0
    return source_ns * 1e-9 if source_ns else time.time()


def publisher_of(info: MessageInfo | None) -> bytes | None:
    """The identity of a message's publisher (its DDS gid); None where rclpy does not say.

    Kilted's info carries the gid; Jazzy's and Humble's do not (nor the EventsExecutor's).
    """
    gid = None if info is None else info.get("publisher_gid")
    if not isinstance(gid, Mapping):
        return None
    return bytes(gid.get("data", b""))


def sequence_of(info: MessageInfo | None) -> int | None:
    """A message's sequence number among its publisher's; None where rclpy does not say.

    Jazzy's and Kilted's info carry it (with the publisher's gid only on Kilted's).
    """
    sequence = None if info is None else info.get("publication_sequence_number")
    return sequence if isinstance(sequence, int) else None


class RawTrajectory(NamedTuple):
    """What the motion filter reads of a JointTrajectory: stamp, names, positions per point."""

    stamp_s: float  # header stamp (s)
    joint_names: tuple[str, ...]
    positions: list[np.ndarray]  # per point, float64

    @classmethod
    def of(cls, msg: JointTrajectory) -> RawTrajectory:
        """The stamp, the names and each point's positions (no copy of rclpy's arrays)."""
        return cls(
            stamp_s(msg.header.stamp),
            tuple(msg.joint_names),
            [np.frombuffer(point.positions, dtype=np.float64) for point in msg.points],
        )

    def poses(self, joint_names: Sequence[str], take: int) -> np.ndarray:
        """(n, len(joint_names)) positions of the first ``take`` points, in that joint order.

        Raises:
            ValueError: a joint is missing, or a point has the wrong number of positions.
        """
        index = {name: i for i, name in enumerate(self.joint_names)}
        missing = [n for n in joint_names if n not in index]
        if missing:
            raise ValueError(f"trajectory lacks joints {missing}")
        order = np.array([index[n] for n in joint_names], dtype=np.intp)
        points = self.positions[:take]
        for k, point in enumerate(points):
            if len(point) != len(self.joint_names):
                raise ValueError(
                    f"point {k} has {len(point)} positions for {len(self.joint_names)} joints"
                )
        if not points:
            return np.empty((0, len(joint_names)))
        return np.vstack(points)[:, order]


def trajectory_bytes_cap(max_points: int, n_joints: int) -> int:
    """Largest raw_trajectory decoded: ``max_points`` points carrying all four arrays (bytes).

    A point of CDR holds four float64 arrays (positions, velocities, accelerations, efforts;
    4-byte length each) and a Duration; beyond the cap the message is dropped before decoding,
    so the work of one message stays bounded (decoding costs about 9 us per point in rclpy).
    """
    per_point = 4 * (4 + 8 * n_joints) + 8
    return 1024 + 64 * n_joints + max_points * per_point


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
    positions = np.ascontiguousarray(np.atleast_2d(positions_rad), dtype=np.float64)
    velocities = (
        None
        if velocities_rad_s is None
        else np.ascontiguousarray(np.atleast_2d(velocities_rad_s), dtype=np.float64)
    )
    for i, row in enumerate(positions):
        point = JointTrajectoryPoint()
        point.positions = array.array("d", row.tobytes())  # stored as is, unlike a list
        if velocities is not None:
            point.velocities = array.array("d", velocities[i].tobytes())
        point.time_from_start = duration_msg((i + 1) * period_s)
        msg.points.append(point)
    return msg
