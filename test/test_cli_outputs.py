"""No verb writes over one of its inputs, and an existing output is replaced only with --force."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from test_cli_errors import audio2pose

QUICK = ("--no-progress", "--fps", "5")  # what is replaced is tested, not the picture


@pytest.fixture
def wav(tmp_path: Path, speech_files: list[Path]) -> Path:
    copy = tmp_path / "in.wav"
    shutil.copyfile(speech_files[1], copy)
    return copy


def same_input(wav: Path, how: str) -> Path:
    """A path naming the input file: itself, through a symlink, a hard link or ``./``."""
    if how == "same path":
        return wav
    if how == "dot path":
        return wav.parent / "." / wav.name
    other = wav.parent / f"other_{how.replace(' ', '_')}.csv"
    (os.symlink if how == "symlink" else os.link)(wav, other)
    return other


@pytest.mark.parametrize("how", ["same path", "dot path", "symlink", "hard link"])
@pytest.mark.parametrize("verb", ["synth", "plot-filter"])
def test_when_output_is_the_input_expect_exit_2_and_the_input_intact(capsys, wav, how, verb):
    before = wav.read_bytes()
    out = same_input(wav, how)
    status, err = audio2pose(capsys, verb, wav, "-o", out, "--force")
    assert status == 2, err
    assert "is the input" in err
    assert "Traceback" not in err
    assert wav.read_bytes() == before


def test_when_output_exists_expect_refused_without_force_and_replaced_with_it(
    capsys, wav, tmp_path
):
    out = tmp_path / "out.csv"
    out.write_text("keep me\n")
    status, err = audio2pose(capsys, "synth", wav, "-o", out)
    assert status == 2
    assert "exists already; give --force" in err
    assert out.read_text() == "keep me\n"
    status, err = audio2pose(capsys, "synth", wav, "-o", out, "--force")
    assert status == 0, err
    assert out.read_text().startswith("time_s")


def test_when_render_output_is_the_input_expect_exit_2(capsys, wav):
    status, err = audio2pose(capsys, "render", wav, "-o", wav)
    assert status == 2
    assert "is the input" in err


def test_when_render_run_again_with_force_expect_its_bag_replaced_but_no_other_folder(
    capsys, wav, tmp_path
):
    out = tmp_path / "out.mp4"
    status, err = audio2pose(capsys, "render", wav, "-o", out, *QUICK)
    assert status == 0, err
    bag = tmp_path / "out_mcap"
    assert (bag / "metadata.yaml").is_file()
    status, err = audio2pose(capsys, "render", wav, "-o", out, *QUICK)
    assert status == 2
    assert "give --force" in err
    status, err = audio2pose(capsys, "render", wav, "-o", out, *QUICK, "--force")
    assert status == 0, err
    assert (bag / "metadata.yaml").is_file()
    keep = tmp_path / "keep"
    keep.mkdir()
    (keep / "notes.txt").write_text("mine\n")
    status, err = audio2pose(capsys, "render", wav, "-o", out, "--mcap", keep, *QUICK, "--force")
    assert status == 2
    assert "is not a rosbag2 bag" in err
    assert (keep / "notes.txt").read_text() == "mine\n"
