"""The raw trajectory read from its bytes equals what rclpy's deserializer gives, or is refused."""

from __future__ import annotations

import re
from collections.abc import Iterator

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import Float32MultiArray, MultiArrayDimension
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from audio2pose_ros.errors import InputError
from audio2pose_ros.ros.cdr import RawTrajectory, read_features, read_joint_trajectory
from audio2pose_ros.ros.messages import features_to_msg, msg_to_features


def random_trajectory(rng: np.random.Generator) -> JointTrajectory:
    """Names of any length (also empty and non-ASCII), points with any of the four arrays."""
    msg = JointTrajectory()
    msg.header.stamp.sec = int(rng.integers(-(2**31), 2**31))
    msg.header.stamp.nanosec = int(rng.integers(0, 10**9))
    msg.header.frame_id = "base_link"[: int(rng.integers(0, 10))]
    n_joints = int(rng.integers(0, 20))
    msg.joint_names = [
        ("Joint", "", "ü", "HeadYaw_")[int(rng.integers(0, 4))] + str(k) * int(rng.integers(0, 4))
        for k in range(n_joints)
    ]
    for _ in range(int(rng.integers(0, 6))):
        arrays = [
            rng.standard_normal(int(rng.integers(0, 3)) and n_joints).tolist() for _ in range(4)
        ]
        msg.points.append(
            JointTrajectoryPoint(
                positions=arrays[0],
                velocities=arrays[1],
                accelerations=arrays[2],
                effort=arrays[3],
                time_from_start=Duration(sec=int(rng.integers(0, 9)), nanosec=7),
            )
        )
    return msg


def corruptions(data: bytes, rng: np.random.Generator, n: int = 2000) -> Iterator[bytes]:
    """``n`` copies of ``data`` with one to three bytes after the encapsulation header changed."""
    for _ in range(n):
        corrupted = bytearray(data)
        for at in rng.integers(4, len(data), size=int(rng.integers(1, 4))):
            corrupted[at] = int(rng.integers(0, 256))
        yield bytes(corrupted)


def as_rclpy_reads_it(data: bytes) -> RawTrajectory:
    msg = deserialize_message(data, JointTrajectory)
    return RawTrajectory(
        msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9,
        tuple(msg.joint_names),
        [np.asarray(p.positions, dtype=np.float64) for p in msg.points],
    )


def test_when_random_trajectories_are_read_expect_what_rclpy_reads():
    rng = np.random.default_rng(7)
    for _ in range(300):
        data = serialize_message(random_trajectory(rng))
        ours, theirs = read_joint_trajectory(data), as_rclpy_reads_it(data)
        assert ours.stamp_s == theirs.stamp_s
        assert ours.joint_names == theirs.joint_names
        assert len(ours.positions) == len(theirs.positions)
        for a, b in zip(ours.positions, theirs.positions, strict=True):
            assert np.array_equal(a, b)


def test_when_poses_are_taken_expect_the_robot_order_and_checked_lengths():
    msg = JointTrajectory(joint_names=["b", "a"])
    msg.points = [JointTrajectoryPoint(positions=[2.0, 1.0]) for _ in range(3)]
    raw = read_joint_trajectory(serialize_message(msg))
    assert np.array_equal(raw.poses(["a", "b"], 2), [[1.0, 2.0], [1.0, 2.0]])
    assert raw.poses(["a", "b"], 0).shape == (0, 2)
    with pytest.raises(ValueError, match="lacks joints"):
        raw.poses(["a", "c"], 3)
    msg.points[1].positions = [1.0]
    with pytest.raises(ValueError, match="point 1 has 1 positions for 2 joints"):
        read_joint_trajectory(serialize_message(msg)).poses(["a", "b"], 3)


def test_when_bytes_are_cut_or_corrupted_expect_input_errors_never_other_failures():
    """Every prefix, and random byte flips, of a message: read or refused, nothing else."""
    rng = np.random.default_rng(3)
    msg = random_trajectory(rng)
    msg.joint_names = ["HeadYaw", "HeadPitch"]
    msg.points = [JointTrajectoryPoint(positions=[0.1, 0.2], velocities=[0.0, 1.0])] * 2
    data = serialize_message(msg)
    whole = read_joint_trajectory(data)
    read = []
    for cut in range(len(data)):
        try:
            read.append(read_joint_trajectory(data[:cut]))
        except InputError:
            assert not read, f"{cut} bytes refused after a shorter cut was read"
    # the cuts that read are those into the bytes after the message (a middleware may pad it)
    assert len(read) < len(data) // 4
    assert all(r.positions[1].tolist() == whole.positions[1].tolist() for r in read)
    for corrupted in corruptions(data, rng):
        try:
            raw = read_joint_trajectory(corrupted)
        except InputError:
            continue
        assert all(len(p) <= len(data) // 8 for p in raw.positions)


def test_when_a_count_claims_more_than_the_message_holds_expect_refused_before_reading():
    msg = JointTrajectory(joint_names=["a"], points=[JointTrajectoryPoint(positions=[1.0])])
    data = bytearray(serialize_message(msg))
    names_count_at = 4 + 4 + 4 + 4 + 4  # header; stamp (8); frame_id: length 1 and its NUL
    assert data[names_count_at : names_count_at + 4] == (1).to_bytes(4, "little")
    data[names_count_at : names_count_at + 4] = (2**32 - 1).to_bytes(4, "little")
    with pytest.raises(InputError, match="sequence of 4294967295 elements"):
        read_joint_trajectory(bytes(data))


def test_when_the_encapsulation_is_not_little_endian_cdr_expect_rclpy_to_read_it():
    msg = JointTrajectory(joint_names=["a"], points=[JointTrajectoryPoint(positions=[1.5])])
    data = bytearray(serialize_message(msg))
    data[1] = 0x00  # CDR_BE, but the fields are little-endian: rclpy's deserializer refuses it
    with pytest.raises(InputError, match="malformed CDR: failed to deserialize"):
        read_joint_trajectory(bytes(data))
    with pytest.raises(InputError, match="3 bytes"):
        read_joint_trajectory(b"\x00\x01\x00")


def test_when_features_messages_are_read_expect_what_rclpy_reads_or_the_same_refusal():
    """Numbered, unnumbered and inconsistent layouts: the same batch or the same error text."""
    rng = np.random.default_rng(11)
    for trial in range(300):
        frames = rng.standard_normal((int(rng.integers(0, 4)), int(rng.integers(0, 30))))
        first = None if trial % 3 else int(rng.integers(0, 10**6))
        msg = features_to_msg(frames, "logfbank26", first)
        if trial % 5 == 1:  # a layout that does not describe the data
            msg.layout.dim = msg.layout.dim[: int(rng.integers(0, 2))]
        if trial % 7 == 2:
            msg.layout.dim.append(MultiArrayDimension(label="ü", size=3, stride=3))
        if trial % 11 == 3 and msg.layout.dim:
            msg.layout.dim[0].size += 1
        data = serialize_message(msg)
        refusal = ""
        try:
            theirs = msg_to_features(deserialize_message(data, Float32MultiArray))
        except InputError as exc:
            refusal = str(exc)
        if refusal:
            with pytest.raises(InputError, match=re.escape(refusal)):
                read_features(data)
            continue
        ours = read_features(data)
        assert (ours.label, ours.first_frame) == (theirs.label, theirs.first_frame)
        assert ours.frames.dtype == theirs.frames.dtype
        assert np.array_equal(ours.frames, theirs.frames)


def test_when_features_bytes_are_corrupted_expect_input_errors_never_other_failures():
    data = serialize_message(features_to_msg(np.ones((2, 26)), "logfbank26", 5))
    rng = np.random.default_rng(5)
    refused = 0
    for corrupted in corruptions(data, rng):
        try:
            batch = read_features(corrupted)
        except InputError:
            refused += 1
            continue
        assert batch.frames.size <= len(data) // 4
    assert refused > 0


def test_when_the_nodes_write_their_messages_as_bytes_expect_rclpy_to_read_the_same_messages():
    """Trajectories (with and without velocities), features and joint angles, any sizes."""
    from builtin_interfaces.msg import Time
    from naoqi_bridge_msgs.msg import JointAnglesWithSpeed

    from audio2pose_ros.ros.cdr import features_cdr, joint_angles_cdr, joint_trajectory_cdr
    from audio2pose_ros.ros.messages import trajectory_msg

    rng = np.random.default_rng(13)
    stamp_ns = 1_795_000_000 * 10**9 + 123_456_789
    stamp = Time(sec=1_795_000_000, nanosec=123_456_789)
    for n_joints in (0, 1, 2, 3, 11, 17):
        names = ["HeadYaw", "ü", "", "LShoulderPitch"] * 5
        names = [f"{name}{k}" * (k % 3) for k, name in enumerate(names[:n_joints])]
        for n_points in (0, 1, 3):
            positions = rng.standard_normal((n_points, n_joints))
            for velocities in (None, rng.standard_normal((n_points, n_joints))):
                data = joint_trajectory_cdr(stamp_ns, names, positions, 0.01, velocities)
                expected = trajectory_msg(names, positions, 0.01, velocities)
                expected.header.stamp = stamp
                assert deserialize_message(data, JointTrajectory) == expected
                assert read_joint_trajectory(data).joint_names == tuple(names)
        angles = rng.standard_normal(n_joints)
        sent = deserialize_message(
            joint_angles_cdr(stamp_ns, names, angles, 0.25), JointAnglesWithSpeed
        )
        assert sent.header.stamp == stamp
        assert (list(sent.joint_names), sent.speed, sent.relative) == (names, 0.25, 0)
        assert np.array_equal(np.asarray(sent.joint_angles), angles.astype(np.float32))
    for n_frames in (0, 1, 2):
        for n_features in (0, 1, 3, 26):
            frames = rng.standard_normal((n_frames, n_features)).astype(np.float32)
            for first, label in ((None, "logfbank26"), (0, ""), (10**12, "ü")):
                data = features_cdr(frames, label, first)
                expected = features_to_msg(frames, label, first)
                assert deserialize_message(data, Float32MultiArray) == expected
