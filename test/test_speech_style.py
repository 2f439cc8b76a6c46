"""The head's motion on speech of other speakers, beside each real source's."""

import numpy as np
import pytest

from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.learning.realism import speed_percentiles
from audio2pose_ros.learning.speech_style import StyleRow, head_style_rows, head_style_table
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.timebase import FRAME_RATE_HZ


def _nodding(robot, clip_id, amplitude_deg, seconds=4.0):
    """A clip whose HeadPitch is a 1 Hz sine; its second half is not observed (huge values)."""
    n = int(seconds * FRAME_RATE_HZ)
    t = np.arange(n) / FRAME_RATE_HZ
    angles = np.tile(robot.neutral_rad, (n, 1))
    angles[:, 0] += np.radians(amplitude_deg) * np.sin(2 * np.pi * t)
    mask = np.zeros((n, robot.n_joints), bool)
    mask[: n // 2, :2] = True
    angles[n // 2 :] = 1e3  # never read: not observed
    info = ClipInfo(clip_id, clip_id, "test", "CC0")
    return Clip(info, np.zeros(int(seconds * 16000), np.float32), angles, mask)


def test_when_real_sources_are_given_expect_their_observed_motion_only(robot):
    clips = [_nodding(robot, "a", 2.0), _nodding(robot, "b", 4.0)]
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    rows = head_style_rows(checkpoint, robot, {}, [0], {"nodders": clips}, "model")
    assert [r.method for r in rows] == ["real, nodders"]  # no speech: no model row
    (row,) = rows
    head = robot.group_mask("head")
    observed = [(c.angles_rad[:200][:, head], c.mask[:200][:, head]) for c in clips]
    speed, accel = speed_percentiles(observed)
    np.testing.assert_allclose(row.speed, speed)
    np.testing.assert_allclose(row.accel, accel)
    # a sine's standard deviation is its amplitude / sqrt 2; averaged over the two clips
    assert row.std_deg[0] == pytest.approx(3.0 / np.sqrt(2), rel=0.01)
    assert row.std_deg[1] == pytest.approx(0.0, abs=1e-9)
    assert row.speed[0, 2] == pytest.approx(np.radians(4.0) * 2 * np.pi, rel=0.01)  # p99: peak
    assert row.seconds == pytest.approx(8.0)


def test_when_the_model_speaks_expect_a_row_per_seed_pooled_and_a_line_per_joint(robot, speech):
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    utterance = speech[: 3 * 16000]
    rows = head_style_rows(
        checkpoint, robot, {"u": utterance}, [0, 1], {"nodders": [_nodding(robot, "a", 2.0)]}, "m"
    )
    assert [r.method for r in rows] == ["m", "real, nodders"]
    model = rows[0]
    assert model.seconds == pytest.approx(2 * len(utterance) / 16000, abs=0.05)
    assert np.isfinite(model.speed).all()
    assert np.isfinite(model.std_deg).all()
    assert (model.speed[:, 2] > 0).all()  # the head moves on speech
    table = head_style_table(rows, ["HeadPitch", "HeadYaw"])
    lines = table.splitlines()
    assert "HeadYaw" in lines[2 * len(rows)]
    assert "real, nodders" in lines[2 * len(rows)]
    assert lines[1 + 2 * len(rows)] == ""  # then the model against each real source
    assert lines[-1].split()[0] == "m"


def _style(method, speed, accel, source=""):
    return StyleRow(method, 1.0, np.array(speed), np.array(accel), np.ones(2), source=source)


def test_when_a_model_row_meets_real_sources_expect_its_percentiles_within_25_percent_counted():
    real = [[0.1, 0.4, 1.0], [0.1, 0.5, 1.4]], [[1.0, 5.0, 10.0], [1.0, 5.0, 15.0]]
    still = np.zeros((2, 3)), np.zeros((2, 3))  # a source whose head never moves
    rows = [
        _style("same", *real),
        _style("twice", *(2 * np.array(p) for p in real)),
        _style("mixed", *(np.array(p) * [[1.24, 1.26, 0.76], [0.74, 1.0, 1.0]] for p in real)),
        _style("real, people", *real, source="people"),
        _style("real, statues", *still, source="statues"),
    ]
    lines = head_style_table(rows, ["HeadPitch", "HeadYaw"]).splitlines()
    assert all(line == line.rstrip() for line in lines[lines.index("") :])
    header = lines[lines.index("") + 1]
    assert "within 25 %" in header
    assert "of 12" in header
    assert lines[lines.index("") + 2].split() == ["method", "people", "statues"]
    counts = {line.split()[0]: line.split()[1:] for line in lines[lines.index("") + 3 :]}
    assert counts["same"] == ["12", "(1.00", "to", "1.00)", "0", "(-)"]
    assert counts["twice"][:4] == ["0", "(2.00", "to", "2.00)"]
    # 1.24 and 0.76 are inside, 1.26 and 0.74 outside: twice per row (speed and acceleration)
    assert counts["mixed"][:4] == ["8", "(0.74", "to", "1.26)"]
    assert len(counts) == 3  # real rows are not compared with each other


def test_when_there_is_no_model_row_or_no_real_source_expect_no_comparison():
    real = _style("real, people", np.ones((2, 3)), np.ones((2, 3)), source="people")
    model = _style("m", np.ones((2, 3)), np.ones((2, 3)))
    for rows in ([real], [model]):
        assert "" not in head_style_table(rows, ["HeadPitch", "HeadYaw"]).splitlines()


def _beating(robot, clip_id, beats_s, seconds=4.0, seed=0):
    """Noise bursts at ``beats_s`` in silence; HeadPitch turns (speed minima) at those times."""
    rng = np.random.default_rng(seed)
    audio = np.zeros(int(seconds * 16000), np.float32)
    for t in beats_s:
        start = int(t * 16000)
        audio[start : start + 3200] = 0.3 * rng.uniform(-1, 1, 3200)
    n = int(seconds * FRAME_RATE_HZ)
    t = np.arange(n) / FRAME_RATE_HZ
    angles = np.tile(robot.neutral_rad, (n, 1))
    period = 2 * (beats_s[1] - beats_s[0])  # extrema one beat apart, one at each burst
    # the turn half a frame late: one frame interval holds the slowest speed, a strict minimum
    phase = t - beats_s[0] - 0.5 / FRAME_RATE_HZ
    angles[:, 0] += np.radians(3.0) * np.cos(2 * np.pi * phase / period)
    mask = np.zeros((n, robot.n_joints), bool)
    mask[:, :2] = True
    return Clip(ClipInfo(clip_id, clip_id, "test", "CC0"), audio, angles, mask)


def test_when_real_heads_turn_on_their_onsets_expect_bc_above_their_shuffled_pairing(robot):
    on_time = [
        _beating(robot, "a", [0.5, 1.5, 2.5, 3.5], seed=1),
        _beating(robot, "b", [1.0, 2.0, 3.0], seed=2),
    ]
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    (row,) = head_style_rows(checkpoint, robot, {}, [0], {"beaters": on_time}, "m")
    assert row.bc > 0.9  # every onset on a turn
    assert row.bc_shuffled < 0.5  # a's onsets half a second from b's turns, and b's from a's
    (alone,) = head_style_rows(checkpoint, robot, {}, [0], {"one": on_time[:1]}, "m")
    assert alone.bc > 0.9
    assert np.isnan(alone.bc_shuffled)  # nothing to pair with
    table = head_style_table([row, alone], ["HeadPitch", "HeadYaw"])
    header, first, second, third, _ = table.splitlines()
    assert header.split()[-2:] == ["BC", "shuffled"]
    assert first.split()[-2:] == [f"{row.bc:.3f}", f"{row.bc_shuffled:.3f}"]
    assert second.split()[-1] == f"{row.std_deg[1]:.2f}"  # BC once per row, not per joint
    assert third.split()[-1] == "-"


def test_when_the_model_speaks_two_utterances_expect_its_bc_shuffled_within_each_seed(
    robot, speech
):
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    utterances = {"u": speech[: 3 * 16000], "v": speech[3 * 16000 : 6 * 16000]}
    (row,) = head_style_rows(checkpoint, robot, utterances, [0, 1], {}, "m")
    assert 0.0 < row.bc <= 1.0
    assert 0.0 < row.bc_shuffled <= 1.0
    assert row.bc != row.bc_shuffled
    (single,) = head_style_rows(checkpoint, robot, {"u": utterances["u"]}, [0, 1], {}, "m")
    assert np.isnan(single.bc_shuffled)
