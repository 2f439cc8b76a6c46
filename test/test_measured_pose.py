"""MeasuredPoseCheck: which measured joint states are the robot's (no ROS; hand-made messages)."""

from __future__ import annotations

import numpy as np
import pytest

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.measured import (
    AGREE_TOLERANCE_RAD,
    ANONYMOUS,
    MAX_AGE_S,
    MAX_FUTURE_S,
    MAX_SOURCES,
    SOURCE_WINDOW_S,
    MeasuredPoseCheck,
)

NOW = 1_800_000_000.0  # the node clock (s since the epoch)


@pytest.fixture
def check(robot):
    return MeasuredPoseCheck(robot.names, robot.max_velocity_rad_s)


def read(check, robot, pose, stamp=NOW, source="driver", arrival=0.0, names=None, published=None):
    names = list(robot.names) if names is None else names
    return check.read(names, list(pose), stamp, published, NOW, source, arrival)


def test_when_a_joint_is_listed_twice_expect_the_message_refused_naming_it(check, robot):
    far = robot.neutral_rad.copy()
    far[robot.names.index("LShoulderPitch")] -= 1.37
    names = [*robot.names, "LShoulderPitch"]  # the last occurrence would have won
    reading = read(
        check, robot, [*robot.neutral_rad, far[robot.names.index("LShoulderPitch")]], names=names
    )
    assert reading.pose_rad is None
    assert reading.kind == "duplicate"
    assert "LShoulderPitch" in reading.reason
    assert check.counts.duplicate == 1
    assert check.refusing(0.5)
    assert not check.refusing(SOURCE_WINDOW_S + 0.1)


def test_when_another_joint_is_listed_twice_expect_a_partial_message_not_a_refusal(check, robot):
    reading = read(check, robot, [0.0, 0.0], names=["LFinger", "LFinger"])
    assert reading.kind == "partial"


@pytest.mark.parametrize(
    ("offset_s", "kind"), [(-60.0, "old"), (3600.0, "future"), (-MAX_AGE_S - 0.01, "old")]
)
def test_when_stamped_old_or_ahead_expect_refused(check, robot, offset_s, kind):
    reading = read(check, robot, robot.neutral_rad, stamp=NOW + offset_s)
    assert reading.pose_rad is None
    assert reading.kind == kind
    assert getattr(check.counts, kind) == 1
    assert check.live_sources(0.0) == 0  # a refused reading makes no source


def test_when_stamped_within_the_bounds_expect_the_pose(check, robot):
    for offset_s in (-MAX_AGE_S + 0.01, 0.0, MAX_FUTURE_S - 0.01):
        reading = read(check, robot, robot.neutral_rad, stamp=NOW + offset_s)
        np.testing.assert_array_equal(reading.pose_rad, robot.neutral_rad)


def test_when_unstamped_expect_the_publication_time_judged_instead(check, robot):
    """A driver that does not stamp: the DDS source timestamp stands in for the stamp."""
    fresh = read(check, robot, robot.neutral_rad, stamp=0.0, published=NOW - 0.01)
    assert fresh.kind == "pose"
    replayed = read(check, robot, robot.neutral_rad, stamp=0.0, published=NOW - 60.0)
    assert replayed.kind == "old"
    unknown = read(check, robot, robot.neutral_rad, stamp=0.0, published=None)
    assert unknown.kind == "pose"  # no publication time: as fresh as it arrived
    assert check.counts.unstamped == 3


def test_when_names_and_positions_differ_in_number_expect_an_input_error(check, robot):
    with pytest.raises(InputError, match="11 names, 10 positions"):
        read(check, robot, robot.neutral_rad[:-1])


def test_when_two_sources_send_poses_far_apart_expect_a_conflict_until_one_stops(check, robot):
    other = robot.neutral_rad.copy()
    other[robot.names.index("LShoulderPitch")] -= 1.37
    for k in range(10):
        t = k * 0.02
        read(check, robot, robot.neutral_rad, stamp=NOW + t, source="robot", arrival=t)
        read(check, robot, other, stamp=NOW + t + 0.005, source="second robot", arrival=t)
    assert check.live_sources(0.2) == 2
    assert check.disagreement_rad(0.2) > 1.0
    assert check.conflict(0.2)
    # the second robot's driver stops; the robot's goes on: the conflict ends
    for k in range(10, 70):
        t = k * 0.02
        read(check, robot, robot.neutral_rad, stamp=NOW + t, source="robot", arrival=t)
    assert check.live_sources(1.4) == 1
    assert not check.conflict(1.4)


def test_when_two_sources_agree_on_a_moving_robot_expect_no_conflict(check, robot):
    """A relay of the driver's messages, 30 ms late, while a joint moves at its velocity limit."""
    joint = robot.names.index("HeadYaw")
    speed = robot.max_velocity_rad_s[joint]
    for k in range(20):
        t = k * 0.02
        pose = robot.neutral_rad.copy()
        pose[joint] = -1.0 + speed * 0.01 * k
        read(check, robot, pose, stamp=NOW + t, source="driver", arrival=t)
        relayed = pose.copy()
        relayed[joint] += speed * 0.01  # 10 ms further on: as it was later
        read(check, robot, relayed, stamp=NOW + t + 0.01, source="relay", arrival=t + 0.03)
    assert check.live_sources(0.4) == 2
    assert check.disagreement_rad(0.4) <= AGREE_TOLERANCE_RAD
    assert not check.conflict(0.4)


def test_when_a_source_is_heard_expect_how_long_it_has_been_heard(check, robot):
    assert check.heard_for_s("driver", 0.0) == 0.0
    read(check, robot, robot.neutral_rad, arrival=1.0)
    read(check, robot, robot.neutral_rad, arrival=1.5)
    assert check.heard_for_s("driver", 1.5) == pytest.approx(0.5)


def test_when_more_sources_than_compared_send_poses_expect_a_conflict(check, robot):
    for k in range(MAX_SOURCES + 1):  # all agree, but one is more than is compared
        read(check, robot, robot.neutral_rad, source=f"publisher {k}", arrival=0.01 * k)
    assert check.live_sources(0.1) == MAX_SOURCES
    assert check.conflict(0.1)
    assert not check.conflict(0.1 + SOURCE_WINDOW_S + 0.01)  # ...until they have gone quiet


def test_when_a_second_source_stamps_its_poses_apart_expect_the_conflict_still_seen(check, robot):
    """Stamps 0.3 s behind the robot's would excuse 2.2 rad of motion at the velocity limit."""
    other = robot.neutral_rad.copy()
    other[robot.names.index("LShoulderPitch")] -= 1.37
    for k in range(30):
        t = k * 0.02
        read(check, robot, robot.neutral_rad, stamp=NOW + t, source="robot", arrival=t)
        read(check, robot, other, stamp=NOW + t - 0.3, source="replay", arrival=t)
    assert check.conflict(0.6)


def test_when_publishers_cannot_be_told_apart_and_disagree_expect_a_conflict_until_one_stops(
    check, robot
):
    """Without gids (Jazzy, Humble) two drivers' interleaved poses are two tracks."""
    other = robot.neutral_rad.copy()
    other[robot.names.index("LShoulderPitch")] -= 1.37
    names = list(robot.names)

    def anonymous(pose, t):
        return check.read(names, list(pose), NOW + t, None, NOW + t, ANONYMOUS, t)

    for k in range(10):
        t = k * 0.02
        anonymous(robot.neutral_rad, t)
        anonymous(other, t + 0.005)
    assert check.live_sources(0.2) == 2
    assert check.conflict(0.2)
    for k in range(10, 70):  # the second driver stops
        assert anonymous(robot.neutral_rad, k * 0.02).kind == "pose"
    assert check.live_sources(1.4) == 1
    assert not check.conflict(1.4)
    assert check.heard_for_s(ANONYMOUS, 1.4) == pytest.approx(1.4)  # its first pose at 0


def test_when_an_anonymous_driver_moves_a_joint_at_its_velocity_limit_expect_one_track(
    check, robot
):
    joint = robot.names.index("RElbowYaw")
    speed = robot.max_velocity_rad_s[joint]
    for k in range(50):
        t = k * 0.02
        pose = robot.neutral_rad.copy()
        pose[joint] = -1.5 + speed * t
        read(check, robot, pose, stamp=NOW + t, source=ANONYMOUS, arrival=t)
    assert check.live_sources(1.0) == 1
    assert not check.conflict(1.0)


def test_when_an_anonymous_second_source_stamps_its_poses_apart_expect_the_conflict_still_seen(
    check, robot
):
    """Stamps 0.3 s behind excuse nothing: the time between arrivals bounds the motion."""
    other = robot.neutral_rad.copy()
    other[robot.names.index("LShoulderPitch")] -= 1.37
    for k in range(30):
        t = k * 0.02
        read(check, robot, robot.neutral_rad, stamp=NOW + t, source=ANONYMOUS, arrival=t)
        read(check, robot, other, stamp=NOW + t - 0.3, source=ANONYMOUS, arrival=t + 0.001)
    assert check.conflict(0.6)


def test_when_anonymous_messages_come_from_a_driver_and_a_stale_replay_expect_two_publishers(
    check, robot
):
    """The replay's poses are all refused (old stamps): it has no track, its refusals count."""
    names = list(robot.names)
    for k in range(10):
        t = k * 0.02
        check.read(names, list(robot.neutral_rad), NOW + t, None, NOW + t, ANONYMOUS, t)
        check.read(names, list(robot.neutral_rad), NOW - 60, None, NOW + t, ANONYMOUS, t)
    assert check.anonymous_publishers(0.2) == 2
    assert check.anonymous_publishers(0.2 + SOURCE_WINDOW_S + 0.01) == 0  # both gone quiet
