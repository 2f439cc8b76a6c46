"""Retargeted arms are moved clear of Pepper's body before they become training targets."""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import AWAY, INSIDE, RIGHT_AWAY, pose_with

from audio2pose_ros.data.dataset import ClipInfo
from audio2pose_ros.data.importers.body_clearance import (
    TOLERANCE_M,
    TRAINING_CLEARANCE_M,
    clear_of_body,
)
from audio2pose_ros.data.importers.common import assemble_clip
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.timebase import FRAME_RATE_HZ, frame_times_s


@pytest.fixture(scope="module")
def body(robot):
    return BodyModel.load(robot)


def _arm_track(robot, n: int) -> np.ndarray:
    """n frames: the left arm swings from a pose away from the body into the torso and back."""
    away, inside = (pose_with(robot, **pose, **RIGHT_AWAY) for pose in (AWAY, INSIDE))
    phase = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n) / n)  # 0 -> 1 -> 0
    return away + phase[:, None] * (inside - away)


def test_when_an_observed_arm_goes_into_the_torso_expect_it_kept_clear_and_smooth(robot, body):
    angles = _arm_track(robot, 300)
    mask = np.zeros_like(angles, dtype=bool)
    mask[:, robot.group_mask("arms")] = True
    assert body.clearance(angles).min() < -0.05  # the input goes 5 cm into the body
    cleared, moved = clear_of_body(angles, mask, robot)
    clearance = body.clearance(cleared)
    assert clearance.min() >= TRAINING_CLEARANCE_M - TOLERANCE_M
    clear_before = body.clearance(angles) >= TRAINING_CLEARANCE_M + 0.005
    assert clear_before.sum() > 50
    assert np.abs(cleared - angles)[clear_before].max() < 0.02  # frames well clear stay
    assert np.all(cleared >= robot.lower_rad)
    assert np.all(cleared <= robot.upper_rad)
    others = ~robot.group_mask("arms")
    np.testing.assert_array_equal(cleared[:, others], angles[:, others])
    assert moved.max() > 0.1
    assert moved[0] < 0.02
    step = np.abs(np.diff(cleared, axis=0)).max() * FRAME_RATE_HZ
    step_before = np.abs(np.diff(angles, axis=0)).max() * FRAME_RATE_HZ
    assert step < 2.0 * step_before + 0.5, "moving the arm out made it jump"


def test_when_no_arm_is_observed_expect_the_clip_untouched(robot):
    angles = _arm_track(robot, 50)
    mask = np.zeros_like(angles, dtype=bool)
    mask[:, robot.group_mask("head")] = True  # a talking head: the arms are not labelled
    cleared, moved = clear_of_body(angles, mask, robot)
    np.testing.assert_array_equal(cleared, angles)
    assert not moved.any()


def test_when_unobserved_joints_would_help_expect_only_observed_joints_changed(robot, body):
    angles = _arm_track(robot, 200)
    mask = np.zeros_like(angles, dtype=bool)
    observed = [robot.names.index(n) for n in ("LShoulderPitch", "LElbowRoll")]
    mask[:, observed] = True
    cleared, _ = clear_of_body(angles, mask, robot)
    changed = np.abs(cleared - angles).max(axis=0) > 0
    assert not changed[~mask.any(axis=0)].any()


def test_when_an_importer_assembles_a_clip_of_arms_in_the_body_expect_targets_clear(robot, body):
    """Every importer's last step: the clip's targets, and how far each frame moved."""
    fps, n = 30.0, 90
    angles = _arm_track(robot, n)
    observed = np.zeros_like(angles, dtype=bool)
    observed[:, robot.group_mask("arms")] = True
    audio = np.zeros(int(n / fps * 16000), np.float32)
    info = ClipInfo("arms_in", "someone", "synthetic", "CC0")
    clip, extras = assemble_clip(
        np.arange(n) / fps, angles, observed, np.zeros(n), audio, info, robot
    )
    assert len(extras["body_moved_rad"]) == clip.n_frames == len(frame_times_s(audio.size))
    arms = clip.mask[:, robot.group_mask("arms")].all(axis=1)
    assert body.clearance(clip.angles_rad[arms]).min() >= TRAINING_CLEARANCE_M - TOLERANCE_M
    assert extras["body_moved_rad"].max() > 0.1
