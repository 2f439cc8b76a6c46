"""``audio2pose check-head``: the model's head motion on speech, beside a data set's real heads."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from synthetic_motion import write_dataset
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.cli import main as cli
from audio2pose_ros.data.dataset import Dataset

ROW = re.compile(
    r"^(?P<method>.+?)\s+(?P<seconds>[\d.]+)\s+(?P<joint>Head\w+)\s+"
    r"(?P<speed>[\d.]+/[\d.]+/[\d.]+)\s+(?P<accel>[\d.]+/[\d.]+/[\d.]+)\s+(?P<std>[\d.]+)"
    r"(?:\s+(?P<bc>[\d.]+|-)\s+(?P<shuffled>[\d.]+|-))?$"  # beat consistency: first joint's line
)


def _rows(out: str) -> list[dict[str, str]]:
    return [m.groupdict() for line in out.splitlines() if (m := ROW.match(line))]


@pytest.fixture(scope="module")
def heads(tmp_path_factory, robot) -> Path:
    root = tmp_path_factory.mktemp("check_head") / "data"
    write_dataset(root, robot, {"train": 2}, seconds=2.0, seed=3)
    return root


def test_when_checked_on_speech_expect_the_models_head_beside_each_real_speaker(
    capsys, speech_files, heads
):
    status = cli.main(["check-head", str(speech_files[0]), "--seeds", "2", "--data", str(heads)])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    rows = _rows(captured.out)
    model = [r for r in rows if r["method"].startswith("model")]
    assert [r["joint"] for r in model] == ["HeadPitch", "HeadYaw"]
    assert 0.0 < float(model[0]["bc"]) <= 1.0
    assert model[0]["shuffled"] == "-"  # one utterance: no other audio to pair it with
    speakers = {info.speaker for info in Dataset.open(heads).clips}
    assert {r["method"] for r in rows} - {model[0]["method"]} == {f"real, {s}" for s in speakers}
    for r in rows:
        speed = np.array(r["speed"].split("/"), float)
        assert np.all(np.diff(speed) >= 0)  # p50 <= p90 <= p99
    # two seeds of the clip: twice its length
    assert float(model[0]["seconds"]) > 2.0


def test_when_seeds_or_data_are_wrong_expect_one_line_and_exit_2(capsys, speech_files, tmp_path):
    status, err = audio2pose(capsys, "check-head", speech_files[0], "--seeds", 0)
    assert status == 2
    assert_one_line(err, "--seeds")
    status, err = audio2pose(capsys, "check-head", speech_files[0], "--data", tmp_path / "none")
    assert status != 0
    assert "Traceback" not in err
    assert "none" in err
