"""Data set folders: round trip, attribution kept, bad clips refused with the reason."""

import json

import numpy as np
import pytest

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset, DatasetError
from audio2pose_ros.timebase import complete_frames


def make_clip(robot, clip_id="c1", seconds=1.0, split="train") -> Clip:
    n = int(16000 * seconds)
    frames = complete_frames(n)
    angles = np.tile(robot.neutral_rad, (frames, 1))
    mask = np.ones_like(angles, dtype=bool)
    mask[:, robot.group_mask("arms")] = False  # e.g. a head-only recording
    info = ClipInfo(clip_id, speaker="s1", source="test", licence="CC0", split=split)
    return Clip(info, np.zeros(n, dtype=np.float32), angles, mask)


def test_when_clip_added_and_reopened_expect_same_arrays_and_attribution(tmp_path, robot):
    dataset = Dataset.create(tmp_path / "ds", robot)
    clip = make_clip(robot)
    dataset.add(clip, robot)
    reopened = Dataset.open(tmp_path / "ds", robot)
    loaded = reopened.load("c1")
    np.testing.assert_allclose(loaded.angles_rad, clip.angles_rad, atol=1e-6)
    np.testing.assert_array_equal(loaded.mask, clip.mask)
    assert loaded.info.licence == "CC0"
    assert [c.info.clip_id for c in reopened.iter_split("train")] == ["c1"]
    assert reopened.speakers == ["s1"]


def test_when_expected_frames_expect_feature_grid():
    assert complete_frames(399) == 0
    assert complete_frames(400) == 1
    assert complete_frames(16000) == 98


def test_when_motion_length_does_not_fit_audio_expect_error(tmp_path, robot):
    dataset = Dataset.create(tmp_path / "ds", robot)
    clip = make_clip(robot)
    clip.angles_rad = clip.angles_rad[:50]
    clip.mask = clip.mask[:50]
    with pytest.raises(DatasetError, match="clip c1: 50 motion frames for audio of 98 frames"):
        dataset.add(clip, robot)


def test_when_observed_angle_is_nan_expect_error(tmp_path, robot):
    dataset = Dataset.create(tmp_path / "ds", robot)
    clip = make_clip(robot)
    clip.angles_rad[3, 0] = np.nan
    with pytest.raises(DatasetError, match="NaN"):
        dataset.add(clip, robot)


def test_when_joints_differ_or_index_broken_expect_error(tmp_path, robot):
    Dataset.create(tmp_path / "ds", robot)
    index = json.loads((tmp_path / "ds" / "index.json").read_text())
    index["joint_names"] = index["joint_names"][::-1]
    (tmp_path / "ds" / "index.json").write_text(json.dumps(index))
    with pytest.raises(DatasetError, match="differ from the robot's"):
        Dataset.open(tmp_path / "ds", robot)
    (tmp_path / "ds" / "index.json").write_text("{not json")
    with pytest.raises(DatasetError, match="malformed index"):
        Dataset.open(tmp_path / "ds")
    with pytest.raises(DatasetError, match="not a data set folder"):
        Dataset.open(tmp_path / "missing")


def test_when_split_unknown_expect_error():
    with pytest.raises(DatasetError, match="split 'dev'"):
        ClipInfo("x", "s", "src", "lic", split="dev")
