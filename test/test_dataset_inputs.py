"""Data set folders at their worst: every file of one is checked as it is read.

A data set may be hand-edited, half copied or made by someone else: its index with entries of
the wrong type, nested without end or listing a clip twice; a FIFO or a link to ``/dev/zero``
in place of a file; a clip whose ``.npy`` header claims gigabytes; a clip whose arrays
``Dataset.add`` would have refused. Each is one line naming the file (exit status 1), refused
before anything large is allocated, never trained on.
"""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
from node_processes import cli_in_child
from test_cli_errors import assert_one_line, audio2pose
from test_train_inputs import small_dataset

from audio2pose_ros.data.dataset import Dataset, DatasetError
from audio2pose_ros.data.importers.extras import extras_path, load_extras, save_extras


def edit_index(root: Path, edit) -> None:
    index = json.loads((root / "index.json").read_text())
    edit(index)
    (root / "index.json").write_text(json.dumps(index))


def edit_clip(root: Path, clip_id: str, **arrays: np.ndarray) -> None:
    """Replace arrays of a stored clip, as a broken copy or a hand-edited file would."""
    path = root / "clips" / f"{clip_id}.npz"
    with np.load(path) as data:
        stored = dict(data)
    stored.update(arrays)
    np.savez_compressed(path, **stored)


def claim_audio_samples(root: Path, clip_id: str, n_samples: int) -> None:
    """Rewrite a clip whose audio header claims ``n_samples`` float32 samples; 64 bytes follow."""
    path = root / "clips" / f"{clip_id}.npz"
    with np.load(path) as stored:
        arrays = dict(stored)
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f4", "fortran_order": False, "shape": (n_samples,)}
    )
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("audio.npy", header.getvalue() + bytes(64))
        for name in ("angles_rad", "mask"):
            buffer = io.BytesIO()
            np.save(buffer, arrays[name])
            archive.writestr(f"{name}.npy", buffer.getvalue())


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda i: i["clips"][0].update(speaker=None), "speaker"),
        (lambda i: i["clips"][0].update(speaker=5), "speaker"),
        (lambda i: i["clips"][0].update(speaker=["x"]), "speaker"),
        (lambda i: i["clips"][0].update(licence={"a": 1}), "licence"),
    ],
    ids=["speaker-null", "speaker-int", "speaker-list", "licence-object"],
)
def test_when_an_index_entry_field_is_not_a_string_expect_malformed_index_exit_1(
    capsys, tmp_path, robot, edit, problem
):
    data = small_dataset(tmp_path / "ds", robot)
    edit_index(data, edit)
    status, stderr = audio2pose(capsys, "dataset", "info", data)
    assert status == 1, stderr
    assert_one_line(stderr, rf"index\.json: malformed index \(clips\[0\]: .*{problem} must be")


def test_when_the_index_nests_100000_levels_expect_malformed_index_not_recursion_error(
    capsys, tmp_path, robot
):
    data = small_dataset(tmp_path / "ds", robot)
    (data / "index.json").write_text("[" * 100_000 + "]" * 100_000)
    status, stderr = audio2pose(capsys, "dataset", "info", data)
    assert status == 1, stderr
    assert_one_line(stderr, r"index\.json: malformed index \(nests 100000 levels deep")


def test_when_the_index_lists_a_clip_twice_expect_malformed_index_not_counted_twice(
    capsys, tmp_path, robot
):
    data = small_dataset(tmp_path / "ds", robot)
    edit_index(data, lambda i: i["clips"].append(dict(i["clips"][0])))
    status, stderr = audio2pose(capsys, "dataset", "info", data)
    assert status == 1, stderr
    assert_one_line(
        stderr, r"malformed index \(clips\[3\]: clip id 'c0' is also that of clips\[0\]"
    )


@pytest.mark.parametrize(
    ("target", "kind"),
    [("index.json", "fifo"), ("clips/c0.npz", "fifo"), ("index.json", "dev_zero")],
)
def test_when_a_data_set_file_is_special_expect_refused_at_once_in_bounded_memory(
    tmp_path, robot, target, kind
):
    data = small_dataset(tmp_path / "ds", robot)
    path = data / target
    path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    else:
        path.symlink_to("/dev/zero")
    try:
        result = cli_in_child("dataset", "info", data, timeout=10)
    except subprocess.TimeoutExpired:
        pytest.fail(f"dataset info on a {kind} {target} did not end within 10 s")
    assert result.returncode == 1, result.stderr[-500:]
    assert_one_line(result.stderr, rf"{re.escape(path.name)}: not a regular file")


def test_when_a_clip_extras_file_is_a_fifo_expect_refused_not_taken_for_no_extras(tmp_path, robot):
    dataset = Dataset.open(small_dataset(tmp_path / "ds", robot))
    save_extras(dataset, "c0", {"head_roll_rad": np.zeros(98)})
    path = extras_path(dataset, "c0")
    path.unlink()
    os.mkfifo(path)
    with pytest.raises(DatasetError, match=r"c0\.extras\.npz: not a regular file"):
        load_extras(dataset, "c0")


def test_when_a_clip_claims_a_64_gib_array_expect_refused_before_allocating(
    capsys, tmp_path, robot
):
    data = small_dataset(tmp_path / "ds", robot)
    claim_audio_samples(data, "c0", 1 << 34)
    status, stderr = audio2pose(capsys, "dataset", "info", data)
    assert status == 1, stderr
    assert_one_line(stderr, r"c0\.npz: clip c0: audio holds 17179869184 samples, more than")


def test_when_a_clip_claims_more_audio_than_its_motion_covers_expect_refused_before_reading_it(
    tmp_path, robot
):
    """200 MB of audio declared for 98 motion frames: refused from the headers alone."""
    data = small_dataset(tmp_path / "ds", robot)
    claim_audio_samples(data, "c0", 50_000_000)
    dataset = Dataset.open(data, robot)
    tracemalloc.start()
    try:
        with pytest.raises(DatasetError, match=r"clip c0: 98 motion frames for audio of \d+"):
            dataset.load("c0")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 20_000_000, f"{peak} bytes allocated to refuse it"


@pytest.mark.parametrize(
    ("arrays", "problem"),
    [
        ({"mask": np.ones((5, 2), bool)}, "mask must be bool with the angles' shape"),
        (
            {"angles_rad": np.zeros((98, 3), np.float32), "mask": np.ones((98, 3), bool)},
            r"angles shape \(98, 3\), expected \(T, 11\)",
        ),
        ({"audio": np.zeros((16000, 2), np.float32)}, "audio must be mono"),
        ({"angles_rad": np.zeros((98, 11), np.complex64)}, "angles_rad is complex64"),
        ({"mask": np.ones((98, 11), np.int64)}, "mask is int64, expected bool"),
        (
            {
                "audio": np.zeros(0, np.float32),
                "angles_rad": np.zeros((0, 11), np.float32),
                "mask": np.ones((0, 11), bool),
            },
            "no complete frame",
        ),
    ],
    ids=["mask-5x2", "three-joints", "stereo-audio", "complex-angles", "int-mask", "no-frame"],
)
def test_when_a_stored_clip_has_arrays_add_refuses_expect_exit_1_naming_it(
    capsys, tmp_path, robot, arrays, problem
):
    data = small_dataset(tmp_path / "ds", robot)
    edit_clip(data, "c0", **arrays)
    status, stderr = audio2pose(capsys, "dataset", "info", data)
    assert status == 1, stderr
    assert_one_line(stderr, rf"c0\.npz: clip c0: {problem}")


def test_when_a_stored_clip_has_nan_observed_angles_expect_train_refuses_not_trains_zero(
    capsys, tmp_path, robot
):
    data = small_dataset(tmp_path / "ds", robot)
    with np.load(data / "clips" / "c0.npz") as stored:
        angles = stored["angles_rad"].copy()
    angles[:] = np.nan  # every observed angle of the one training clip
    edit_clip(data, "c0", angles_rad=angles)
    out = tmp_path / "m.safetensors"
    status, stderr = audio2pose(
        capsys, "train", "--data", data, "-o", out, "--model", "mlp", "--max-epochs", "1"
    )
    assert not out.exists(), "a model was trained on NaN angles read as 0 rad"
    assert status == 1
    assert_one_line(stderr, "clip c0: observed angles contain NaN")


def test_when_a_stored_clip_has_10_motion_frames_for_98_audio_frames_expect_refused(
    capsys, tmp_path, robot
):
    data = small_dataset(tmp_path / "ds", robot)
    with np.load(data / "clips" / "c0.npz") as stored:
        edit_clip(data, "c0", angles_rad=stored["angles_rad"][:10], mask=stored["mask"][:10])
    out = tmp_path / "m.safetensors"
    status, stderr = audio2pose(
        capsys, "train", "--data", data, "-o", out, "--model", "mlp", "--max-epochs", "1"
    )
    assert not out.exists(), "trained on a clip cut to 10 of 98 frames"
    assert status == 1
    assert_one_line(stderr, "clip c0: 10 motion frames for audio of 98 frames")


def test_when_a_clip_id_is_added_twice_expect_refused_unless_replace_is_given(tmp_path, robot):
    dataset = Dataset.open(small_dataset(tmp_path / "ds", robot), robot)
    clip = dataset.load("c1")
    with pytest.raises(DatasetError, match=r"clip id 'c1' is in the data set already"):
        dataset.add(clip, robot)
    dataset.add(clip, robot, replace=True)
    assert [c.clip_id for c in Dataset.open(tmp_path / "ds").clips] == ["c0", "c2", "c1"]
