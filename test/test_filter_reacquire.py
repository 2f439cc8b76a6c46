"""A short burst of consistent wrong poses, or a track taken up again, is approached gently."""

import numpy as np
import pytest

from audio2pose_ros.motion.approach import APPROACH_VELOCITY_FRACTION
from audio2pose_ros.motion.filter import MotionFilter
from audio2pose_ros.motion.sources import SingleSource

PERIOD = 0.01


def settled(robot, pose):
    filt = MotionFilter(robot)
    t = 0.0
    for _ in range(400):
        t += PERIOD
        filt.push(pose[None, :], t)
        filt.tick(t)
    assert np.abs(filt.position_rad - pose).max() < 1e-3
    return filt, t


def run(filt, t, poses):
    """Feed one pose per tick; (commands, velocities) of every tick."""
    out, velocities = [], []
    for pose in poses:
        t += PERIOD
        filt.push(pose[None, :], t)
        position, velocity = filt.tick(t)
        out.append(position.copy())
        velocities.append(velocity.copy())
    return np.array(out), np.array(velocities), t


@pytest.mark.parametrize("burst", [5, 12, 30])
def test_when_a_burst_of_consistent_wrong_poses_arrives_expect_arm_barely_moves(robot, burst):
    good = robot.neutral_rad.copy()
    good[robot.names.index("LShoulderRoll")] = 0.4  # arm out: clear of the body at every pitch
    joint = robot.names.index("LShoulderPitch")
    good[joint] = 1.0
    filt, t = settled(robot, good)
    wrong = good.copy()
    wrong[joint] = -0.2  # 1.2 rad away, inside the range: consistent with itself
    poses = [wrong] * burst + [good] * 300
    commands, velocities, _ = run(filt, t, poses)
    swing = np.abs(commands - good).max()
    assert swing < 0.1, f"the arm swung {swing:.2f} rad"
    peak = np.abs(velocities).max(axis=0) / filt.limiter.max_velocity_rad_s
    assert peak.max() < 0.5  # well below the velocity limit


def test_when_track_really_moves_expect_it_reached_below_a_third_of_the_velocity_limit(robot):
    good = robot.neutral_rad.copy()
    good[robot.names.index("LShoulderRoll")] = 0.4  # arm out: clear of the body at every pitch
    joint = robot.names.index("LShoulderPitch")
    good[joint] = 1.0
    filt, t = settled(robot, good)
    moved = good.copy()
    moved[joint] = -1.0
    commands, velocities, _ = run(filt, t, [moved] * 800)
    assert commands[-1][joint] == pytest.approx(-1.0, abs=0.02)  # reached
    peak = np.abs(velocities[:, joint]).max() / filt.limiter.max_velocity_rad_s[joint]
    assert peak <= APPROACH_VELOCITY_FRACTION + 0.05


def test_when_two_sources_alternate_expect_only_the_first_followed_until_it_goes_quiet():
    sources = SingleSource(handover_s=0.5)
    admitted = [sources.admit("a" if i % 2 else "b", i * 0.01) for i in range(100)]
    assert admitted[0]  # "b" came first...
    assert not any(admitted[1::2])  # ...and keeps the robot
    assert sources.rivals(1.0) == 1
    assert not sources.admit("a", 1.2)  # "b" last heard at 0.98 s
    assert sources.admit("a", 1.5)  # "b" silent for 0.52 s: "a" takes over
    assert sources.rivals(2.1) == 0


def test_when_a_burst_comes_in_one_message_expect_its_queued_poses_dropped_with_the_track(robot):
    """30 consistent wrong poses in one message, then the real stream: barely a move."""
    good = robot.neutral_rad.copy()
    good[robot.names.index("LShoulderRoll")] = 0.4  # arm out: clear of the body at every pitch
    joint = robot.names.index("LShoulderPitch")
    good[joint] = 1.0
    filt, t = settled(robot, good)
    wrong = good.copy()
    wrong[joint] = -0.2
    t += PERIOD
    filt.push(np.repeat(wrong[None, :], 30, axis=0), t)
    worst = 0.0
    for i in range(300):
        t += PERIOD
        if i % 2 == 0:  # two poses every 20 ms, as inference_node sends them
            filt.push(np.stack([good, good]), t)
        worst = max(worst, float(np.abs(filt.tick(t)[0] - good).max()))
    assert worst < 0.1
