"""The stream's messages read from and written as their CDR bytes, without rclpy's objects.

The motion filter takes one ``raw_trajectory`` (trajectory_msgs/JointTrajectory) every 10 ms and
needs of it only the header stamp, the joint names and each point's positions; the inference
node takes one ``features`` message (std_msgs/Float32MultiArray) and needs its layout and values.
rclpy's deserializer builds a Python object for every field first (for a trajectory a header, a
list of names, for each point four ``array.array`` and a Duration, each through the generated
classes' checked setters). :func:`read_joint_trajectory` and :func:`read_features` read the
fields straight from the bytes: 16 against 23 us for a raw pose, including the reordering of
its joints that rclpy's reading still needed. The other way, :func:`joint_trajectory_cdr`,
:func:`features_cdr` and :func:`joint_angles_cdr` write the messages the nodes send every frame
(``Publisher.publish`` takes bytes): 5 against 11 us to build a raw pose's message, and the
publisher converts nothing.

The bytes are the CDR (OMG DDS-XTypes, "plain CDR" / XCDR1) that ROS 2 middlewares write: a
4-byte encapsulation header, then the fields in their declaration order, each primitive aligned
to its own size counted from the end of the header, a string as a uint32 length (with its
terminating NUL) and the bytes, a sequence as a uint32 count and the elements (an empty sequence
of float64 needs no alignment). Only little-endian CDR (encapsulation 0x0001, what every
middleware on x86 and ARM writes) is read here; anything else goes to rclpy's own deserializer,
so the result never depends on which path read it (``test/test_cdr.py`` compares both on random
messages). Every length is checked against the bytes left before it is used: a malformed or
hostile message raises :class:`~audio2pose_ros.errors.InputError` and is dropped, it never reads
beyond the message or allocates more than the message holds.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from rclpy.serialization import deserialize_message
from std_msgs.msg import Float32MultiArray
from trajectory_msgs.msg import JointTrajectory

from audio2pose_ros.errors import InputError
from audio2pose_ros.ros.messages import FeatureBatch, feature_batch, frames_label, msg_to_features

CDR_LE = b"\x00\x01"  # the encapsulation of little-endian plain CDR
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time and Duration: int32 sec, uint32 nanosec


class RawTrajectory(NamedTuple):
    """What the motion filter reads of a JointTrajectory."""

    stamp_s: float  # header stamp (s)
    joint_names: tuple[str, ...]
    positions: list[np.ndarray]  # per point, float64 (read-only views of the message's bytes)

    def poses(self, joint_names: Sequence[str], take: int) -> np.ndarray:
        """(n, len(joint_names)) positions of the first ``take`` points, in that joint order.

        Raises:
            ValueError: a joint is missing, or a point has the wrong number of positions.
        """
        order = _order(self.joint_names, joint_names)
        points = self.positions[:take]
        for k, point in enumerate(points):
            if len(point) != len(self.joint_names):
                raise ValueError(
                    f"point {k} has {len(point)} positions for {len(self.joint_names)} joints"
                )
        if len(points) == 1:  # the stream's usual message
            return points[0][order][None, :]
        if not points:
            return np.empty((0, len(joint_names)))
        return np.vstack(points)[:, order]


# The last names read and the last order made: every message of a stream repeats them.
_last_names: tuple[int, int, bytes, tuple[str, ...]] = (-1, -1, b"", ())
_last_order: tuple[tuple[str, ...], Sequence[str], np.ndarray] | None = None


def _order(names: tuple[str, ...], wanted: Sequence[str]) -> np.ndarray:
    """Index into ``names`` of each of ``wanted`` (kept for the same two objects).

    Raises:
        ValueError: a joint is missing.
    """
    global _last_order
    last = _last_order
    if last is not None and last[0] is names and last[1] is wanted:
        return last[2]
    index = {name: i for i, name in enumerate(names)}
    missing = [n for n in wanted if n not in index]
    if missing:
        raise ValueError(f"trajectory lacks joints {missing}")
    order = np.array([index[n] for n in wanted], dtype=np.intp)
    _last_order = (names, wanted, order)
    return order


class _Reader:
    """Sequential reads of little-endian CDR, every one bounds-checked."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 4  # after the encapsulation header; alignment counts from here

    def _take(self, size: int, align: int) -> int:
        start = self.pos + (-(self.pos - 4) % align)
        if size < 0 or start + size > len(self.data):
            raise InputError(f"malformed CDR: {size} bytes wanted at {start} of {len(self.data)}")
        self.pos = start + size
        return start

    def u32(self) -> int:
        return int(_U32.unpack_from(self.data, self._take(4, 4))[0])

    def stamp_s(self) -> float:
        sec, nanosec = _STAMP.unpack_from(self.data, self._take(8, 4))
        return float(sec + nanosec * 1e-9)

    def string(self) -> str:
        size = self.u32()
        start = self._take(size, 1)
        if size == 0 or self.data[start + size - 1] != 0:
            raise InputError("malformed CDR: a string without its terminating NUL")
        try:
            return self.data[start : start + size - 1].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(f"malformed CDR: a string that is not UTF-8 ({exc})") from None

    def count(self, element_size: int) -> int:
        """A sequence's element count, checked against the bytes left (at least 1 byte each)."""
        n = self.u32()
        if n * max(element_size, 1) > len(self.data) - self.pos:
            raise InputError(f"malformed CDR: a sequence of {n} elements in fewer bytes")
        return n

    def numbers(self, dtype: str) -> np.ndarray:
        """A sequence of float64 (``"<f8"``) or float32 (``"<f4"``) values, as a read-only view."""
        size = np.dtype(dtype).itemsize
        n = self.count(size)
        if n == 0:
            return np.empty(0, dtype=dtype)
        return np.frombuffer(self.data, dtype=dtype, count=n, offset=self._take(size * n, size))


def read_features(data: bytes) -> FeatureBatch:
    """A serialized features message (std_msgs/Float32MultiArray) as a :class:`FeatureBatch`.

    Raises:
        InputError: the bytes are not a Float32MultiArray, or its layout does not describe its
            data (:func:`~audio2pose_ros.ros.messages.feature_batch`).
    """
    if not _little_endian(data):
        return msg_to_features(_rclpy_read(data, Float32MultiArray))
    reader = _Reader(data)
    dims = []
    for _ in range(reader.count(13)):  # a label's length and NUL, size and stride at least
        label = reader.string()
        dims.append((label, reader.u32()))
        reader.u32()  # stride
    reader.u32()  # data_offset
    return feature_batch(dims, reader.numbers("<f4"))


def read_joint_trajectory(data: bytes) -> RawTrajectory:
    """The stamp, joint names and positions of a serialized JointTrajectory.

    Velocities, accelerations, efforts and each point's time are checked for their bounds and
    skipped. Bytes after the message (middlewares may pad it) are ignored.

    Raises:
        InputError: the bytes are not a JointTrajectory (a length beyond the message, a string
            without its NUL or not UTF-8).
    """
    if not _little_endian(data):
        msg = _rclpy_read(data, JointTrajectory)
        stamp = msg.header.stamp
        return RawTrajectory(
            float(stamp.sec + stamp.nanosec * 1e-9),
            tuple(msg.joint_names),
            [np.asarray(point.positions, dtype=np.float64) for point in msg.points],
        )
    global _last_names
    reader = _Reader(data)
    stamp_s = reader.stamp_s()
    reader.string()  # frame_id
    start = reader.pos + (-(reader.pos - 4) % 4)  # where the names' count is
    at, size, block, names = _last_names
    if at == start and data[start : start + size] == block:  # the names of the last message
        reader.pos = start + size
    else:
        names = tuple(reader.string() for _ in range(reader.count(5)))
        _last_names = (start, reader.pos - start, data[start : reader.pos], names)
    positions = []
    for _ in range(reader.count(24)):  # 4 counts and a Duration at least
        positions.append(reader.numbers("<f8"))
        for _ in range(3):  # velocities, accelerations, effort
            reader.numbers("<f8")
        reader.stamp_s()  # time_from_start
    return RawTrajectory(stamp_s, names, positions)


def _little_endian(data: bytes) -> bool:
    """Whether ``data`` is little-endian plain CDR (read here; anything else goes to rclpy).

    Raises:
        InputError: fewer bytes than the encapsulation header.
    """
    if len(data) < 4:
        raise InputError(f"malformed CDR: {len(data)} bytes")
    return data[:2] == CDR_LE


def _rclpy_read(data: bytes, msg_type: type[Any]) -> Any:
    """``data`` through rclpy's deserializer (big-endian or another encoding)."""
    try:
        return deserialize_message(data, msg_type)
    except Exception as exc:  # rclpy raises its own error types for bytes it cannot read
        raise InputError(f"malformed CDR: {exc}") from None


# --- writing ----------------------------------------------------------------------------------


def _string(text: str, size: int) -> tuple[list[bytes], int]:
    """A string written after ``size`` bytes: its pieces, and the size after it."""
    data = text.encode("utf-8") + b"\x00"
    pad = -size % 4  # the length is a uint32
    return [bytes(pad), _U32.pack(len(data)), data], size + pad + 4 + len(data)


@functools.lru_cache(maxsize=16)
def _names_block(joint_names: tuple[str, ...]) -> bytes:
    """An empty frame_id and ``joint_names`` as they follow a header stamp, padded to 4 bytes."""
    parts, size = _string("", 8)  # frame_id, after the stamp
    pad = -size % 4  # the names' count is a uint32
    parts += [bytes(pad), _U32.pack(len(joint_names))]
    size += pad + 4
    for name in joint_names:
        written, size = _string(name, size)
        parts += written
    parts.append(bytes(-size % 4))
    return b"".join(parts)


def joint_trajectory_cdr(
    stamp_ns: int,
    joint_names: Sequence[str],
    positions_rad: np.ndarray,
    period_s: float,
    velocities_rad_s: np.ndarray | None = None,
) -> bytes:
    """The CDR bytes of :func:`~audio2pose_ros.ros.messages.trajectory_msg`'s JointTrajectory.

    Stamped ``stamp_ns`` (ns), one point per row of ``positions_rad`` (float64), the first due
    one ``period_s`` after the stamp (with ``velocities_rad_s``, one row each): what a publisher
    sends (``Publisher.publish`` takes bytes) without building the message's objects first.
    """
    names = _names_block(tuple(joint_names))
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    parts = [CDR_LE + b"\x00\x00", _STAMP.pack(sec, nanosec), names]
    size = 8 + len(names)
    positions = np.ascontiguousarray(np.atleast_2d(positions_rad), dtype="<f8")
    velocities = (
        None
        if velocities_rad_s is None
        else np.ascontiguousarray(np.atleast_2d(velocities_rad_s), dtype="<f8")
    )
    parts.append(_U32.pack(len(positions)))
    size += 4
    for i, row in enumerate(positions):
        for values in (row, None if velocities is None else velocities[i]):
            count = 0 if values is None else len(values)
            parts.append(_U32.pack(count))  # 4-aligned: everything before is
            size += 4
            if count:
                pad = -size % 8
                parts += [bytes(pad), values.tobytes()]  # type: ignore[union-attr]
                size += pad + 8 * count
        nanoseconds = round((i + 1) * period_s * 1e9)  # time_from_start, as duration_msg
        parts.append(_EMPTY_PAIR + _STAMP.pack(*divmod(nanoseconds, 1_000_000_000)))
        size += 16
    return b"".join(parts)


_EMPTY_PAIR = _U32.pack(0) * 2  # a point's accelerations and effort: empty


def features_cdr(frames: np.ndarray, label: str, first_frame: int | None = None) -> bytes:
    """The CDR bytes of :func:`~audio2pose_ros.ros.messages.features_to_msg`'s message."""
    n_frames, n_features = frames.shape
    parts = [CDR_LE + b"\x00\x00", _U32.pack(2)]
    size = 4
    for text, dim, stride in (
        (frames_label(first_frame), n_frames, n_frames * n_features),
        (label, n_features, n_features),
    ):
        written, size = _string(text, size)
        parts += written
        pad = -size % 4
        parts += [bytes(pad), _U32.pack(dim), _U32.pack(stride)]
        size += pad + 8
    values = np.ascontiguousarray(frames, dtype="<f4")
    parts += [_U32.pack(0), _U32.pack(values.size), values.tobytes()]  # data_offset, data
    return b"".join(parts)


def joint_angles_cdr(
    stamp_ns: int, joint_names: Sequence[str], angles_rad: np.ndarray, speed: float
) -> bytes:
    """The CDR bytes of a naoqi_bridge_msgs/JointAnglesWithSpeed: absolute angles (float32)."""
    names = _names_block(tuple(joint_names))
    angles = np.ascontiguousarray(angles_rad, dtype="<f4")
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return b"".join(
        (
            CDR_LE + b"\x00\x00",
            _STAMP.pack(sec, nanosec),
            names,
            _U32.pack(angles.size),
            angles.tobytes(),
            _SPEED_RELATIVE.pack(speed, 0),  # speed, relative = 0 (absolute angles)
        )
    )


_SPEED_RELATIVE = struct.Struct("<fB")
