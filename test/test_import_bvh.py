"""BVH importer: parsing, retargeting known motion, bad files."""

from pathlib import Path

import numpy as np
import pytest
from recording_fixtures import NAMES, known_angles, write_bvh

from audio2pose_ros.data.dataset import ClipInfo
from audio2pose_ros.data.importers import ImporterError
from audio2pose_ros.data.importers.bvh import import_bvh, load_mappings, read_bvh, retarget
from audio2pose_ros.timebase import frame_times_s

FRAME_TIME_S = 1.0 / 30.0
N_FRAMES = 150  # 5 s


@pytest.fixture
def bvh_file(tmp_path: Path) -> Path:
    path = tmp_path / "known.bvh"
    write_bvh(path, N_FRAMES, FRAME_TIME_S)
    return path


def test_when_retargeting_a_bvh_of_known_motion_expect_the_angles_per_frame(bvh_file, robot):
    motion = read_bvh(bvh_file)
    angles, observed, _ = retarget(motion, load_mappings()["genea2020"], robot, bvh_file)
    expected = known_angles(np.arange(N_FRAMES) * FRAME_TIME_S)
    assert observed.all()
    for j, name in enumerate(robot.names):
        np.testing.assert_allclose(angles[:, j], expected[name], atol=1e-6, err_msg=name)


def test_when_importing_a_bvh_of_known_motion_expect_angles_within_one_degree(bvh_file, robot):
    audio = np.zeros(int(N_FRAMES * FRAME_TIME_S * 16000), dtype=np.float32)
    info = ClipInfo("known", "s", "test", "CC0")
    clip, extras = import_bvh(bvh_file, audio, info, robot, load_mappings()["genea2020"])
    assert robot.names == NAMES
    expected = known_angles(frame_times_s(audio.size))
    inner = slice(20, -20)  # away from the filter's edges and the last BVH frame
    for j, name in enumerate(robot.names):
        error_deg = np.rad2deg(np.abs(clip.angles_rad[inner, j] - expected[name][inner]))
        assert error_deg.max() < 1.0, f"{name}: {error_deg.max():.2f} deg"
    assert not extras["body_moved_rad"].any()  # the known motion is clear of Pepper's body
    assert clip.mask[inner].all()
    assert np.abs(extras["head_roll_rad"][inner]).max() < np.deg2rad(1.0)


def test_when_mapping_names_a_missing_joint_expect_an_error_listing_the_files_joints(
    bvh_file, robot
):
    mapping = dict(load_mappings()["genea2020"], head="b_head")
    with pytest.raises(ImporterError, match=r"known\.bvh: no joint 'b_head'.*LeftForeArm"):
        retarget(read_bvh(bvh_file), mapping, robot, bvh_file)


def test_when_the_bvh_is_truncated_expect_an_error_naming_the_file(bvh_file):
    text = bvh_file.read_text()
    cut = bvh_file.with_name("cut.bvh")
    cut.write_text(text[: int(len(text) * 0.8)])
    with pytest.raises(ImporterError, match=r"cut\.bvh: truncated BVH"):
        read_bvh(cut)
    cut.write_text(text[: text.index("MOTION") - 20])
    with pytest.raises(ImporterError, match=r"cut\.bvh: truncated BVH"):
        read_bvh(cut)


def test_when_the_hierarchy_is_malformed_expect_the_line_in_the_error(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 zero\n")
    with pytest.raises(ImporterError, match=r"bad\.bvh: line 4: 'zero' is not a number"):
        read_bvh(path)


def test_when_a_mapping_lacks_a_role_expect_an_error(tmp_path):
    path = tmp_path / "maps.yaml"
    path.write_text("mine:\n  joints: {pelvis: Hips, head: Head}\n")
    with pytest.raises(ImporterError, match="skeleton 'mine' lacks roles"):
        load_mappings(path)
