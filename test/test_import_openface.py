"""OpenFace 2.0 CSV importer: known head angles, sign conventions, masked rows, bad files."""

from pathlib import Path

import numpy as np
import pytest
from recording_fixtures import openface_rotation, write_openface_csv

from audio2pose_ros.data.dataset import ClipInfo
from audio2pose_ros.data.importers import ImporterError
from audio2pose_ros.data.importers.openface import OpenFaceImportSettings, import_openface
from audio2pose_ros.timebase import frame_times_s

FPS = 30.0
SECONDS = 4.0
RAW = OpenFaceImportSettings(centre=False)


def _csv(tmp_path: Path, yaw, pitch, success=None, name="face.csv") -> Path:
    times = np.arange(int(SECONDS * FPS)) / FPS
    yaw, pitch = (
        np.broadcast_to(yaw(times), times.shape),
        np.broadcast_to(pitch(times), times.shape),
    )
    ok = np.ones(times.size, bool) if success is None else success(times)
    path = tmp_path / name
    write_openface_csv(path, times, openface_rotation(yaw, pitch), ok)
    return path


def _import(path: Path, robot, settings=RAW):
    audio = np.zeros(int(SECONDS * 16000), dtype=np.float32)
    return import_openface(path, audio, ClipInfo("c", "s", "test", "CC0"), robot, settings)


def test_when_importing_known_head_angles_expect_them_back_within_half_a_degree(tmp_path, robot):
    yaw = lambda t: 0.4 * np.sin(2 * np.pi * 0.3 * t)  # noqa: E731
    pitch = lambda t: 0.1 + 0.2 * np.sin(2 * np.pi * 0.5 * t)  # noqa: E731
    clip, _ = _import(_csv(tmp_path, yaw, pitch), robot)
    t = frame_times_s(clip.audio.size)
    inner = slice(20, -20)
    got = clip.angles_rad[:, [robot.names.index("HeadYaw"), robot.names.index("HeadPitch")]]
    np.testing.assert_allclose(got[inner, 0], yaw(t)[inner], atol=np.deg2rad(0.5))
    np.testing.assert_allclose(got[inner, 1], pitch(t)[inner], atol=np.deg2rad(0.5))
    assert clip.mask[:, :2].all()
    assert not clip.mask[:, 2:].any()


def _constant_pose(tmp_path: Path, pose_r: list[float], robot, mirror: bool = False):
    path = tmp_path / "constant.csv"
    times = np.arange(60) / FPS
    write_openface_csv(path, times, np.tile(pose_r, (times.size, 1)), np.ones(times.size, bool))
    clip, _ = _import(path, robot, OpenFaceImportSettings(centre=False, mirror=mirror))
    return {n: clip.angles_rad[50, robot.names.index(n)] for n in ("HeadYaw", "HeadPitch")}


def test_when_the_head_looks_down_expect_positive_head_pitch(tmp_path, robot):
    angles = _constant_pose(tmp_path, [0.2, 0.0, 0.0], robot)  # pose_Rx > 0: face turns down
    assert angles["HeadPitch"] == pytest.approx(0.2, abs=1e-3)
    assert angles["HeadYaw"] == pytest.approx(0.0, abs=1e-3)


def test_when_the_head_turns_to_the_speakers_left_expect_positive_yaw_unless_mirrored(
    tmp_path, robot
):
    turn = [0.0, -0.3, 0.0]  # pose_Ry < 0: the face turns towards the image's right
    assert _constant_pose(tmp_path, turn, robot)["HeadYaw"] == pytest.approx(0.3, abs=1e-3)
    mirrored = _constant_pose(tmp_path, turn, robot, mirror=True)["HeadYaw"]
    assert mirrored == pytest.approx(-0.3, abs=1e-3)


def test_when_success_is_zero_for_a_second_expect_those_frames_masked(tmp_path, robot):
    lost = lambda t: (t < 1.5) | (t > 2.5)  # noqa: E731
    path = _csv(tmp_path, lambda t: 0.1, lambda t: 0.0, success=lost)
    clip, _ = _import(path, robot)
    t = frame_times_s(clip.audio.size)
    head = clip.mask[:, robot.names.index("HeadYaw")]
    assert not head[(t > 1.8) & (t < 2.2)].any()
    assert head[t < 1.4].all()
    assert head[t > 2.6].all()


def test_when_centring_expect_the_median_head_pose_at_the_robots_neutral(tmp_path, robot):
    path = _csv(tmp_path, lambda t: 0.3 + 0.1 * np.sin(t), lambda t: 0.25)
    clip, _ = _import(path, robot, OpenFaceImportSettings())
    for name in ("HeadYaw", "HeadPitch"):
        j = robot.names.index(name)
        assert np.median(clip.angles_rad[:, j]) == pytest.approx(robot.neutral_rad[j], abs=0.02)


def test_when_columns_are_missing_expect_an_error_naming_the_file_and_columns(tmp_path, robot):
    path = tmp_path / "wrong.csv"
    path.write_text("frame, timestamp, success, pose_Rx\n1, 0.0, 1, 0.1\n")
    with pytest.raises(ImporterError, match=r"wrong\.csv: not an OpenFace 2\.0 CSV: missing"):
        _import(path, robot)


def test_when_no_row_tracked_a_face_expect_an_error_naming_the_file(tmp_path, robot):
    path = _csv(tmp_path, lambda t: 0.0, lambda t: 0.0, success=lambda t: t < 0, name="x.csv")
    with pytest.raises(ImporterError, match=r"x\.csv: no row with success = 1"):
        _import(path, robot)
