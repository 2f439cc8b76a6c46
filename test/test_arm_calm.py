"""Calm arms: acceleration at the limiter, wrists above the shoulders, board stretches."""

from __future__ import annotations

import numpy as np
from body_poses import pose_with

from audio2pose_ros.data.importers.lecture import BOARD_PAD_S, BOARD_S, board_frames
from audio2pose_ros.learning.arm_calm import arm_calm, arm_calm_table, at_limit_pct
from audio2pose_ros.learning.command_path import commanded
from audio2pose_ros.robot.body import BodyModel


def _swing(robot, n: int, hz: float, amplitude: float) -> np.ndarray:
    """Both shoulders pitching around a raised pose, from rest at a turning point.

    The arms are held 0.35 rad out from the torso, so the swing stays about 3 cm clear of the
    body: the self-collision guard leaves it alone, and what reaches the acceleration limit is
    the speed alone.
    """
    t = np.arange(n) / 100.0
    lift = 0.8 + amplitude * np.cos(2 * np.pi * hz * t)
    out = dict(LShoulderRoll=0.35, RShoulderRoll=-0.35, LElbowRoll=-0.6, RElbowRoll=0.6)
    return np.stack([pose_with(robot, LShoulderPitch=p, RShoulderPitch=p, **out) for p in lift])


def test_when_the_arms_swing_faster_than_the_robot_can_follow_expect_the_limiter_share_to_rise(
    robot,
):
    slow = commanded(robot, [_swing(robot, 400, 0.5, 0.2)])
    fast = commanded(robot, [_swing(robot, 400, 2.0, 0.3)])
    assert at_limit_pct(robot, slow) < 0.1  # at most the start, from rest
    # two of eight arm joints swing; the limiter brakes and launches them most of the time
    assert at_limit_pct(robot, fast) > 0.5 * 100 * 2 / 8


def test_when_a_wrist_is_raised_above_the_shoulder_expect_it_counted_and_high_ones_apart(robot):
    body = BodyModel.load(robot)
    down = np.tile(robot.neutral_rad, (100, 1))
    level = np.tile(pose_with(robot, LShoulderPitch=-0.1, LElbowRoll=-0.1), (100, 1))
    high = np.tile(pose_with(robot, LShoulderPitch=-1.2, LElbowRoll=-0.1), (100, 1))
    heights = body.wrist_heights(np.stack([down[0], level[0], high[0]]))
    assert heights[0, 0] < 0.0 < heights[1, 0] < 0.1 < heights[2, 0]
    row = arm_calm("m", robot, body, [down, level, high])
    assert abs(row.above_pct - 200 / 3) < 1e-6
    assert abs(row.high_pct - 100 / 3) < 1e-6
    unknown = np.zeros(down.shape, bool)  # frames whose arms are not observed do not count
    assert arm_calm("m", robot, body, [down, (high, unknown)]).above_pct == 0.0
    assert "at limit %" in arm_calm_table([row])


def test_when_a_hand_stays_above_the_shoulder_expect_a_board_stretch_but_not_a_brief_gesture(
    robot,
):
    body = BodyModel.load(robot)
    down = pose_with(robot, LShoulderPitch=1.2, RShoulderPitch=1.2)
    up = pose_with(robot, LShoulderPitch=-1.0, RShoulderPitch=1.2, LElbowRoll=-0.1)
    long_up = round(1.5 * BOARD_S * 100)
    frames = [down] * 200 + [up] * 40 + [down] * 200 + [up] * long_up + [down] * 200
    angles = np.stack(frames)
    known = np.ones(angles.shape, bool)
    board = board_frames(body, angles, known)
    start, pad = 440, round(BOARD_PAD_S * 100)
    assert not board[: start - pad].any()  # a gesture of 0.4 s is talking
    assert board[start : start + long_up].all()
    assert board[start - pad]
    assert board[start + long_up + pad - 1]
    assert not board[start - pad - 1]
    assert not board[start + long_up + pad]
    assert not board[-100:].any()
    assert not board_frames(body, angles, np.zeros(angles.shape, bool)).any()  # unseen: no call
