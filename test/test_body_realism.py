"""Arms against the body on held-out clips: the guard's share and wrist positions vs real."""

from __future__ import annotations

import numpy as np
import pytest
from body_poses import pose_with

from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.learning.body_realism import REAL_HALVES, body_realism, body_table
from audio2pose_ros.robot.body import BodyModel

MARGIN_M = 0.02


def _clip(robot, n: int, seed: int) -> Clip:
    """Arms gesturing in front of the body (clear of it), the head unobserved."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100.0
    lift = 0.6 + 0.3 * np.sin(2 * np.pi * 0.5 * t + rng.uniform(0, 6))
    angles = np.stack(
        [
            pose_with(
                robot,
                LShoulderPitch=lift_i,
                LShoulderRoll=0.5,
                LElbowRoll=-0.8,
                RShoulderPitch=lift_i,
                RShoulderRoll=-0.5,
                RElbowRoll=0.8,
            )
            for lift_i in lift
        ]
    )
    mask = np.zeros_like(angles, dtype=bool)
    mask[:, robot.group_mask("arms")] = True
    info = ClipInfo(f"c{seed}", "s", "synthetic", "CC0", "test")
    return Clip(info, np.zeros(n * 160 + 240, np.float32), angles, mask)


def test_when_motion_is_real_or_still_expect_the_wrists_to_tell_them_apart(robot):
    body = BodyModel.load(robot)
    clips = [_clip(robot, 400, seed) for seed in (1, 2)]
    real = {c.info.clip_id: [c.angles_rad] for c in clips}
    still = {c.info.clip_id: [np.tile(robot.neutral_rad, (c.n_frames, 1))] for c in clips}
    inside = pose_with(
        robot, LShoulderPitch=1.22, LShoulderRoll=0.04, LElbowRoll=-1.32, LElbowYaw=-0.19
    )
    into = {c.info.clip_id: [np.tile(inside, (c.n_frames, 1))] for c in clips}
    rows = body_realism(clips, {"same": real, "still": still, "into": into}, body, MARGIN_M)
    by = {r.method: r for r in rows}
    assert list(by) == [REAL_HALVES, "same", "still", "into"]
    assert max(by["same"].wrist_h) < 1e-9
    assert by["same"].near_pct == 0.0
    assert min(by["still"].wrist_h[0], by["still"].wrist_h[2]) > 0.5  # hands down at the sides
    assert by["into"].inside_pct == 100.0
    assert max(by[REAL_HALVES].wrist_h) < 0.5
    table = body_table(rows, MARGIN_M)
    assert "wrist H z" in table
    assert len(table.splitlines()) == 5


def test_when_speech_is_sampled_at_several_seeds_expect_each_seed_counted_as_check_body_does(
    robot,
):
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.learning.body_realism import speech_body_rows, speech_body_table
    from audio2pose_ros.offline.body_check import check_trajectory
    from audio2pose_ros.offline.synthesis import synthesize
    from audio2pose_ros.resources import bundled_speech_path, default_checkpoint_path

    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    body = BodyModel.load(robot)
    speech = read_wav(bundled_speech_path())[0][: 16000 * 2]
    silence = np.zeros(16000, np.float32)
    seeds = [0, 3]
    rows = speech_body_rows(checkpoint, body, {"speech": speech, "silence": silence}, seeds, 0.05)
    assert [r.clip for r in rows] == ["speech", "silence"]
    per_seed = [
        check_trajectory(body, synthesize(checkpoint, speech, seed=s, body_margin_m=None)[1], 0.05)
        for s in seeds
    ]
    first = rows[0]
    assert first.seeds == 2
    assert first.seconds == 2.0
    assert first.near_pct == pytest.approx(np.mean([r.within_margin_pct for r in per_seed]))
    assert first.worst_near_pct == max(r.within_margin_pct for r in per_seed)
    assert first.worst_inside_pct == max(r.inside_pct for r in per_seed)
    table = speech_body_table(rows, 0.05)
    assert table.splitlines()[0].split()[:3] == ["clip", "seconds", "seeds"]
    assert table.splitlines()[-1].startswith("all")
