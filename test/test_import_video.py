"""Video importer on a real talking-head clip, its geometry on synthetic faces, bad files."""

import subprocess

import numpy as np
import pytest

from audio2pose_ros.data.dataset import ClipInfo
from audio2pose_ros.data.importers import ImporterError, head_pose
from audio2pose_ros.data.importers.media import ffmpeg_executable, read_audio
from audio2pose_ros.data.importers.video import VideoImportSettings, import_video
from audio2pose_ros.resources import share_path
from audio2pose_ros.timebase import complete_frames

GRID_CLIP = share_path("data", "video", "grid_bbaf2n.mpg")  # GRID, CC BY 4.0: data/video/SOURCES.md
HEAD_ONLY = VideoImportSettings(body=False)


def _ffmpeg(*args: str) -> None:
    subprocess.run([ffmpeg_executable(), "-v", "error", "-y", *args], check=True)


@pytest.fixture(scope="module")
def imported(robot):
    tracks = []
    info = ClipInfo("grid_bbaf2n", "grid_s", "GRID corpus", "CC BY 4.0")
    clip, extras = import_video(GRID_CLIP, info, robot, on_tracks=tracks.append)
    return clip, extras, tracks[0]


def test_when_importing_a_talking_head_expect_a_face_in_over_95_percent_of_frames(imported):
    _, _, tracks = imported
    assert tracks.face_found.mean() > 0.95


def test_when_importing_a_talking_head_expect_plausible_head_angles_without_wraps(imported, robot):
    clip, extras, _ = imported
    assert clip.n_frames == complete_frames(clip.audio.size)
    head = [robot.names.index("HeadYaw"), robot.names.index("HeadPitch")]
    angles = clip.angles_rad[:, head]
    assert np.isfinite(angles).all()
    assert clip.mask[:, head].all()
    assert np.abs(angles - robot.neutral_rad[head]).max() < np.deg2rad(30)
    assert np.abs(np.diff(angles, axis=0)).max() < np.deg2rad(2)  # per 10 ms: no jumps
    assert np.isfinite(extras["head_roll_rad"]).all()
    assert np.abs(extras["head_roll_rad"]).max() < np.deg2rad(30)


def test_when_the_arms_are_not_visible_expect_arm_and_hip_joints_masked(imported, robot):
    clip, _, _ = imported
    body = robot.group_mask("arms") | robot.group_mask("hip")
    assert not clip.mask[:, body].any()
    np.testing.assert_allclose(
        clip.angles_rad[:, body],
        np.broadcast_to(robot.neutral_rad[body], clip.angles_rad[:, body].shape),
    )


def test_when_the_video_has_no_audio_track_expect_an_error_naming_the_file(tmp_path, robot):
    silent = tmp_path / "silent.mpg"
    _ffmpeg("-i", str(GRID_CLIP), "-an", "-c:v", "copy", str(silent))
    with pytest.raises(ImporterError, match=r"silent\.mpg: no audio track"):
        import_video(silent, ClipInfo("s", "s", "x", "x"), robot, HEAD_ONLY)


def test_when_the_video_shows_no_face_expect_an_error_naming_the_file(tmp_path, robot):
    blank = tmp_path / "pattern.mp4"
    _ffmpeg(
        "-f", "lavfi", "-i", "testsrc=size=160x120:rate=25:duration=1",
        "-f", "lavfi", "-i", "sine=frequency=220:duration=1",
        "-c:v", "mpeg4", "-c:a", "aac", "-shortest", str(blank),
    )  # fmt: skip
    assert read_audio(blank).size > 8000
    with pytest.raises(ImporterError, match=r"pattern\.mp4: a face was found in only 0 of"):
        import_video(blank, ClipInfo("p", "s", "x", "x"), robot, HEAD_ONLY)


def test_when_the_file_is_not_media_expect_an_error_naming_the_file(tmp_path, robot):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"not a video at all")
    with pytest.raises(ImporterError, match=r"junk\.mp4: not a readable media file"):
        import_video(junk, ClipInfo("j", "s", "x", "x"), robot, HEAD_ONLY)


@pytest.mark.parametrize("ypr_deg", [(0, 0, 0), (25, -10, 5), (-40, 15, -8), (10, 20, 170)])
def test_when_fitting_a_rotated_face_model_expect_its_yaw_pitch_roll(ypr_deg):
    from scipy.spatial.transform import Rotation

    model = head_pose.canonical_face_model().points
    body = Rotation.from_euler("ZYX", np.deg2rad(ypr_deg)).as_matrix()
    camera = head_pose.CAMERA_TO_BODY @ body @ head_pose.CAMERA_TO_BODY.T
    observed = 3.0 * model @ camera.T + np.array([100.0, 50.0, 7.0])
    rotation, residual = head_pose.rigid_fit(model, observed)
    assert residual < 1e-9
    got = np.rad2deg(head_pose.camera_rotation_to_angles(rotation))
    np.testing.assert_allclose(got, ypr_deg, atol=1e-6)


def test_when_a_track_crosses_180_degrees_and_has_a_spike_expect_unwrapped_and_rejected():
    n = 60
    roll = np.deg2rad(178.0 + np.linspace(0, 6, n))
    track = np.stack([np.zeros(n), np.zeros(n), np.angle(np.exp(1j * roll))], axis=1)
    track[30, 0] = np.deg2rad(40)  # a failed fit
    observed = np.ones(n, bool)
    unwrapped = head_pose.unwrap_observed(track, observed)
    assert np.abs(np.diff(unwrapped[:, 2])).max() < np.deg2rad(1)
    kept = head_pose.reject_outliers(unwrapped, observed)
    assert not kept[30]
    assert kept.sum() == n - 1
