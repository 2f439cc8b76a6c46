"""``audio2pose dataset import-*`` at their worst: every input file and the output checked.

Two inputs that would become one clip, a malformed BVH among good ones, a BVH whose frame time
is not a period, a FIFO or a link to ``/dev/zero`` given as input, an output that is a file or
lies in a missing folder. The rule of the importers holds in each case: a bad file is reported
with its name and the reason (exit status 1), the others are imported, nothing is written over
without being asked, and a bad output is refused before any input is read (exit status 2).
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from node_processes import cli_in_child
from recording_fixtures import openface_rotation, write_bvh, write_openface_csv, write_wav
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.cli import main as cli
from audio2pose_ros.data.dataset import ClipInfo, Dataset
from audio2pose_ros.data.importers import ImporterError
from audio2pose_ros.data.importers.common import assemble_clip

BVH = ["--licence", "CC0", "--skeleton", "genea2020"]


def openface_take(folder: Path, stem: str, yaw_amplitude: float = 0.2) -> Path:
    """``<stem>.csv`` (3 s of OpenFace head pose at 30 frames/s) and ``<stem>.wav`` beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    times = np.arange(90) / 30.0
    pose = openface_rotation(yaw_amplitude * np.sin(times), 0.1 * np.cos(times))
    csv = folder / f"{stem}.csv"
    write_openface_csv(csv, times, pose, np.ones(times.size, bool))
    write_wav(folder / f"{stem}.wav", 3.0)
    return csv


def bvh_take(folder: Path, stem: str) -> Path:
    """``<stem>.bvh`` (2 s at 30 frames/s) and ``<stem>.wav`` beside it."""
    folder.mkdir(parents=True, exist_ok=True)
    write_bvh(folder / f"{stem}.bvh", 60, 1.0 / 30.0)
    write_wav(folder / f"{stem}.wav", 2.0)
    return folder / f"{stem}.bvh"


def deep_hierarchy(text: str) -> str:
    """The BVH with a chain of 5000 joints nested under its root."""
    chain = "".join(f"JOINT j{k}\n{{\nOFFSET 0 1 0\n" for k in range(5000))
    chain += "End Site\n{\nOFFSET 0 1 0\n}\n" + "}\n" * 5000
    return text.replace("  JOINT Spine3", chain + "  JOINT Spine3", 1)


def test_when_two_inputs_map_to_one_clip_id_expect_the_later_reported_and_none_replaced(
    capsys, tmp_path
):
    inputs = [
        openface_take(tmp_path / "a", "alice", 0.2),
        openface_take(tmp_path / "b", "alice", 0.4),
    ]
    openface_take(tmp_path / "c", "bob smith", 0.1)
    openface_take(tmp_path / "c", "bob_smith", 0.3)
    out = tmp_path / "data"
    status = cli.main(
        ["dataset", "import-openface", *map(str, inputs), str(tmp_path / "c"), "-o", str(out),
         "--licence", "x"]
    )  # fmt: skip
    printed, stderr = capsys.readouterr()
    assert status == 1
    assert f"2 of 4 files imported into {out}" in printed
    assert re.search(r"b/alice\.csv: clip id 'alice' is that of .*a/alice\.csv", stderr), stderr
    assert re.search(r"bob_smith\.csv: clip id 'bob_smith' is that of .*bob smith\.csv", stderr)
    clips = {c.clip_id: c for c in Dataset.open(out).clips}
    assert sorted(clips) == ["alice", "bob_smith"]
    assert clips["bob_smith"].speaker == "bob smith"  # the first file's clip, not replaced


def test_when_a_clip_id_is_in_the_data_set_already_expect_refused_unless_replace_is_given(
    capsys, tmp_path
):
    csv = openface_take(tmp_path / "rec", "alice")
    out = tmp_path / "data"
    assert (
        audio2pose(capsys, "dataset", "import-openface", csv, "-o", out, "--licence", "x")[0] == 0
    )
    status, stderr = audio2pose(
        capsys, "dataset", "import-openface", csv, "-o", out, "--licence", "y"
    )
    assert status == 1
    assert re.search(r"alice\.csv: clip id 'alice' is in .*data already; give --replace", stderr)
    assert [c.licence for c in Dataset.open(out).clips] == ["x"]
    status, stderr = audio2pose(
        capsys, "dataset", "import-openface", csv, "-o", out, "--licence", "y", "--replace"
    )
    assert status == 0, stderr
    assert [c.licence for c in Dataset.open(out).clips] == ["y"]


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (
            lambda t: t.replace("CHANNELS 3", "CHANNELS nan", 1),
            r"line \d+: CHANNELS count 'nan' is not a whole number",
        ),
        (
            lambda t: re.sub(r"Frames: \d+", "Frames: inf", t),
            r"line \d+: Frames: 'inf' is not a whole number",
        ),
        (
            lambda t: t.replace("Xrotation", "Qrotation", 1),
            r"line \d+: unknown channel 'Qrotation'",
        ),
    ],
    ids=["channels-nan", "frames-inf", "unknown-channel"],
)
def test_when_one_bvh_is_malformed_expect_it_reported_and_the_others_imported(
    capsys, tmp_path, edit, problem
):
    folder = tmp_path / "mocap"
    for stem in ("a_good", "b_bad", "c_good"):
        bvh_take(folder, stem)
    bad = folder / "b_bad.bvh"
    bad.write_text(edit(bad.read_text()))
    out = tmp_path / "data"
    status, stderr = audio2pose(capsys, "dataset", "import-bvh", folder, "-o", out, *BVH)
    assert "internal error" not in stderr, stderr
    assert status == 1
    assert re.search(rf"b_bad\.bvh: {problem}", stderr), stderr
    assert sorted(c.clip_id for c in Dataset.open(out).clips) == ["a_good", "c_good"]


def test_when_a_bvh_nests_5000_joints_deep_expect_it_imported_not_a_recursion_error(
    capsys, tmp_path
):
    take = bvh_take(tmp_path, "take")
    take.write_text(deep_hierarchy(take.read_text()))
    out = tmp_path / "data"
    status, stderr = audio2pose(capsys, "dataset", "import-bvh", take, "-o", out, *BVH)
    assert status == 0, stderr
    assert Dataset.open(out).load("take").mask[5:-5].all()


@pytest.mark.parametrize("frame_time", ["nan", "inf", "1e300", "1e-300"])
def test_when_the_bvh_frame_time_is_not_a_usable_period_expect_refused_not_an_empty_clip(
    capsys, tmp_path, frame_time
):
    take = bvh_take(tmp_path, "take")
    take.write_text(re.sub(r"Frame Time: \S+", f"Frame Time: {frame_time}", take.read_text()))
    out = tmp_path / "data"
    status, stderr = audio2pose(capsys, "dataset", "import-bvh", take, "-o", out, *BVH)
    assert [c.clip_id for c in Dataset.open(out).clips] == []
    assert status == 1
    assert re.search(r"take\.bvh: line \d+: Frame Time \S+ s is not a period in", stderr), stderr


def test_when_no_source_frame_falls_on_the_audio_expect_the_clip_refused_by_every_importer(
    robot,
):
    """The step all importers share: a clip that observes nothing is not a training example."""
    times = 100.0 + np.arange(30) / 30.0  # a second of motion, 100 s after 1 s of audio
    angles = np.tile(robot.neutral_rad, (times.size, 1))
    observed = np.ones(angles.shape, dtype=bool)
    audio = np.zeros(16000, np.float32)
    info = ClipInfo("late", "s", "test", "CC0")
    with pytest.raises(ImporterError, match=r"clip late: no joint observed at any of the 98"):
        assemble_clip(times, angles, observed, np.zeros(times.size), audio, info, robot)


@pytest.mark.parametrize(
    ("verb", "kind"),
    [("import-openface", "fifo"), ("import-bvh", "fifo"), ("import-openface", "dev_zero")],
)
def test_when_an_importer_input_is_special_expect_refused_at_once_and_the_others_imported(
    tmp_path, verb, kind
):
    folder = tmp_path / "rec"
    if verb == "import-openface":
        openface_take(folder, "a_good")
        suffix, extra = ".csv", ["--licence", "CC0"]
    else:
        bvh_take(folder, "a_good")
        suffix, extra = ".bvh", BVH
    special = folder / f"take{suffix}"
    write_wav(folder / "take.wav", 1.0)
    if kind == "fifo":
        os.mkfifo(special)
    else:
        special.symlink_to("/dev/zero")
    try:
        result = cli_in_child("dataset", verb, folder, "-o", tmp_path / "data", *extra, timeout=10)
    except subprocess.TimeoutExpired:
        pytest.fail(f"dataset {verb} on a {kind} did not end within 10 s")
    assert result.returncode == 1, result.stderr[-500:]
    assert f"take{suffix}: not a regular file" in result.stderr
    assert "1 of 2 files imported" in result.stdout
    assert [c.clip_id for c in Dataset.open(tmp_path / "data").clips] == ["a_good"]


@pytest.mark.parametrize("output", ["the input CSV", "/dev/full", "a folder of other files"])
def test_when_import_output_is_not_a_data_set_folder_expect_usage_error_and_nothing_written(
    capsys, tmp_path, output
):
    csv = openface_take(tmp_path / "rec", "take")
    before = {p.name: p.read_bytes() for p in csv.parent.iterdir()}
    out = {"the input CSV": csv, "/dev/full": Path("/dev/full")}.get(output, csv.parent)
    status, stderr = audio2pose(
        capsys, "dataset", "import-openface", csv, "-o", out, "--licence", "CC0"
    )
    assert {p.name: p.read_bytes() for p in csv.parent.iterdir()} == before
    assert status == 2, stderr
    assert_one_line(stderr, rf"-o {re.escape(str(out))}: exists and is not a data set folder")


def test_when_import_output_lies_in_a_missing_folder_expect_usage_error_not_created(
    capsys, tmp_path
):
    csv = openface_take(tmp_path / "rec", "take")
    out = tmp_path / "missing" / "deep" / "data"
    status, stderr = audio2pose(
        capsys, "dataset", "import-openface", csv, "-o", out, "--licence", "CC0"
    )
    assert status == 2, stderr
    assert_one_line(stderr, r"-o .*missing/deep/data: folder .*missing/deep does not exist")
    assert not (tmp_path / "missing").exists()
