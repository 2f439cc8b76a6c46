"""``audio2pose dataset ...``: multi-file imports that report bad files and go on; info."""

import argparse
from pathlib import Path

import numpy as np
import pytest
from recording_fixtures import openface_rotation, write_bvh, write_openface_csv, write_wav

from audio2pose_ros.cli.dataset_commands import register
from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.data.importers.extras import load_extras
from audio2pose_ros.errors import UsageError
from audio2pose_ros.resources import share_path


def run(*argv: str) -> int:
    parser = argparse.ArgumentParser(prog="audio2pose")
    register(parser.add_subparsers(dest="verb", required=True))
    args = parser.parse_args(list(argv))
    return args.func(args)


@pytest.fixture
def recordings(tmp_path: Path) -> Path:
    folder = tmp_path / "rec"
    folder.mkdir()
    times = np.arange(90) / 30.0
    pose = openface_rotation(0.2 * np.sin(times), 0.1 * np.cos(times))
    for name in ("alice", "bob"):
        write_openface_csv(folder / f"{name}.csv", times, pose, np.ones(times.size, bool))
        write_wav(folder / f"{name}.wav", 3.0)
    (folder / "broken.csv").write_text("frame, timestamp\n1, 0.0\n")
    write_wav(folder / "broken.wav", 3.0)
    write_openface_csv(folder / "no_audio.csv", times, pose, np.ones(times.size, bool))
    return folder


def test_when_importing_a_folder_with_bad_files_expect_them_reported_and_the_rest_imported(
    recordings, tmp_path, capsys
):
    out = tmp_path / "data"
    code = run("dataset", "import-openface", str(recordings), "-o", str(out), "--licence", "CC0")
    captured = capsys.readouterr()
    assert code == 1
    assert "2 of 4 files imported" in captured.out
    assert "broken.csv: not an OpenFace 2.0 CSV" in captured.err
    assert "no_audio.csv: no audio next to it" in captured.err
    dataset = Dataset.open(out)
    assert sorted(c.clip_id for c in dataset.clips) == ["alice", "bob"]
    assert {c.speaker for c in dataset.clips} == {"alice", "bob"}
    assert {c.licence for c in dataset.clips} == {"CC0"}
    assert load_extras(dataset, "alice")["head_roll_rad"].shape == (dataset.load("alice").n_frames,)


def test_when_every_file_imports_expect_exit_code_zero_and_info_lists_them(
    recordings, tmp_path, capsys
):
    out = tmp_path / "data"
    files = [str(recordings / "alice.csv"), str(recordings / "bob.csv")]
    assert run("dataset", "import-openface", *files, "-o", str(out), "--licence", "CC0",
               "--speaker", "carol", "--split", "test") == 0  # fmt: skip
    assert run("dataset", "info", str(out)) == 0
    printed = capsys.readouterr().out
    assert "2 clips, 1 speakers" in printed
    assert "alice" in printed
    assert "carol" in printed
    assert "licence: CC0 (2 clips)" in printed


def test_when_importing_bvh_with_a_known_skeleton_expect_all_joints_observed(tmp_path):
    folder = tmp_path / "mocap"
    folder.mkdir()
    write_bvh(folder / "take.bvh", 60, 1.0 / 30.0)
    write_wav(folder / "take.wav", 2.0)
    out = tmp_path / "data"
    assert run("dataset", "import-bvh", str(folder), "-o", str(out), "--licence", "CC0",
               "--skeleton", "genea2020") == 0  # fmt: skip
    clip = Dataset.open(out).load("take")
    assert clip.mask[5:-5].all()


def test_when_the_skeleton_is_unknown_expect_a_usage_error_listing_the_known_ones(tmp_path):
    with pytest.raises(UsageError, match=r"unknown skeleton 'nope'; known: .*genea2020"):
        run("dataset", "import-bvh", str(tmp_path), "-o", str(tmp_path / "d"), "--licence", "x",
            "--skeleton", "nope")  # fmt: skip


GRID_CLIP = share_path("data", "video", "grid_bbaf2n.mpg")  # GRID, CC BY 4.0: data/video/SOURCES.md


def test_when_importing_videos_with_one_bad_expect_speed_reported_and_the_good_one_kept(
    tmp_path, capsys
):
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"no video")
    out = tmp_path / "data"
    code = run("dataset", "import-video", str(GRID_CLIP), str(junk), "-o", str(out),
               "--licence", "CC BY 4.0", "--no-body")  # fmt: skip
    captured = capsys.readouterr()
    assert code == 1
    assert "junk.mp4: not a readable media file" in captured.err
    assert "frames/s; face found in 100.0 %" in captured.out
    assert [c.clip_id for c in Dataset.open(out).clips] == ["grid_bbaf2n"]
