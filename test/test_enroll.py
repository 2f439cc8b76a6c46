"""Enrolment: a personal model from a recording, used by --model; style files and refusals."""

import subprocess

import numpy as np
import pytest

from audio2pose_ros.cli.main import main
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.data.importers.media import ffmpeg_executable
from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.style import StyleSettings
from audio2pose_ros.resources import default_checkpoint_path, share_path
from audio2pose_ros.style.figures import StyleError, load_style, preset_names, read_style
from audio2pose_ros.style.personal import checkpoint_digest, enroll, model_and_style
from audio2pose_ros.timebase import SAMPLES_PER_FRAME

# the shared clips, where the Makefile's TALKING_HEADS looks (../shared next to the checkout)
OBAMA = sorted(
    clip
    for up in (("..",), ("..", ".."))
    for clip in share_path(*up, "shared", "data", "talking_heads").glob("obama*.mp4")
)


def read_csv(path):
    return np.loadtxt(path, delimiter=",", skiprows=1)[:, 1:]


def arms_only_dataset(root, robot, speech, slow=False):
    """A data set whose clip observes the arms only (as a BVH of the arms would), on real speech."""
    n = speech.size // SAMPLES_PER_FRAME
    t = np.arange(n) / 100.0
    angles = np.tile(robot.neutral_rad, (n, 1))
    arms = robot.group_mask("arms")
    rate = 0.2 if slow else 1.0
    angles[:, arms] += 0.15 * np.sin(2 * np.pi * rate * t)[:, None]
    mask = np.zeros(angles.shape, dtype=bool)
    mask[:, arms] = True
    dataset = Dataset.create(root, robot)
    info = ClipInfo("arms_only", "someone", "test", "test data")
    dataset.add(Clip(info, speech, angles, mask), robot)
    return root


def test_when_recording_observes_only_the_arms_expect_only_the_arms_adapted(
    tmp_path, robot, speech
):
    source = arms_only_dataset(tmp_path / "data", robot, speech, slow=True)
    lines = []
    result = enroll(source, tmp_path / "me", robot, progress=lines.append)
    assert set(result.style.parts) == {"arms"}
    assert result.settings.head_gain == 1.0
    assert result.settings.head_tempo == 1.0
    assert result.settings.hip_gain == 1.0
    assert result.settings.arms_tempo < 1.0  # slow arm motion against the model's
    assert result.settings.arms_gain != 1.0  # the arms' size is fitted too
    assert len(lines) >= 3  # progress
    style = read_style(tmp_path / "me" / "style.yaml")
    assert style.parts == result.style.parts
    assert style.fitted is not None
    checkpoint, loaded = model_and_style(str(tmp_path / "me"))
    assert loaded == style
    own = tmp_path / "me" / "model.safetensors"  # when the arms' noise was fitted
    assert own.is_file() == (result.arms_noise != 1.0)
    assert checkpoint == (own if own.is_file() else default_checkpoint_path())
    assert style.fitted[0] == checkpoint_digest(checkpoint)
    if not own.is_file():  # else the style alone (result.settings) is not what the folder runs
        assert style.fitted[1] == result.settings


def test_when_synth_runs_a_personal_model_expect_the_style_applied_to_its_part_only(
    tmp_path, robot, speech, speech_path
):
    source = arms_only_dataset(tmp_path / "data", robot, speech, slow=True)
    assert main(["enroll", str(source), "-o", str(tmp_path / "me")]) == 0
    for name, extra in (("default", []), ("me", ["--model", str(tmp_path / "me")])):
        assert main(["synth", str(speech_path), "-o", str(tmp_path / f"{name}.csv"), *extra]) == 0
    default = read_csv(tmp_path / "default.csv")
    mine = read_csv(tmp_path / "me.csv")
    arms, head = robot.group_mask("arms"), robot.group_mask("head")
    np.testing.assert_allclose(mine[:, head], default[:, head], atol=1e-6)
    assert (
        np.abs(np.diff(mine[:, arms], axis=0)).mean()
        < np.abs(np.diff(default[:, arms], axis=0)).mean()
    )


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda p: p / "missing.mp4", "no such file"),
        (lambda p: (p / "folder").mkdir() or p / "folder", "has no index.json"),
    ],
)
def test_when_enrol_source_is_unusable_expect_a_clear_error(tmp_path, robot, make, message):
    with pytest.raises(InputError, match=message):
        enroll(make(tmp_path), tmp_path / "me", robot, progress=lambda _: None)
    assert not (tmp_path / "me").exists()


def test_when_recording_too_short_expect_refusal_naming_the_need(tmp_path, robot, speech):
    source = arms_only_dataset(tmp_path / "data", robot, speech[: 3 * 16000])
    with pytest.raises(StyleError, match="observed for 5 s or more"):
        enroll(source, tmp_path / "me", robot, progress=lambda _: None)


def test_when_enrol_output_is_not_empty_expect_refusal_without_force(tmp_path, capsys):
    out = tmp_path / "me"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert main(["enroll", str(tmp_path / "missing.mp4"), "-o", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert (out / "keep.txt").read_text() == "mine"


GOOD = """audio2pose_style: 1
name: t
parts:
  head:
    seconds: 10
    std_rad: 0.05
    speed_deciles_rad_s: [0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09]
    accel_deciles_rad_s2: [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9]
"""


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (GOOD.replace("std_rad: 0.05", "std_rad: .nan"), "std_rad: nan is not a number"),
        (GOOD.replace("std_rad: 0.05", "std_rad: -1"), "std_rad: -1 is not a number"),
        (GOOD.replace("std_rad: 0.05", "std_rad: 1e300"), "std_rad"),
        (GOOD.replace("0.09]", "0.01]"), "deciles must not decrease"),
        (GOOD.replace("0.09]", "0.09, 1.0]"), "needs 9 numbers"),
        (GOOD.replace("head:", "tail:"), "unknown part 'tail'"),
        (GOOD.replace("audio2pose_style: 1", "audio2pose_style: 7"), "not a style file"),
        ("[1, 2", "style"),
        (GOOD + "fitted: {checkpoint_sha256: abc, settings: {}}\n", "64 hex digits"),
        (
            GOOD + f"fitted: {{checkpoint_sha256: {'a' * 64}, settings: {{arms_gain: 9}}}}\n",
            "arms_gain: value 9",
        ),
        (GOOD + "x" * 70000, "style"),
    ],
)
def test_when_style_file_hostile_expect_clear_refusal(tmp_path, text, message):
    path = tmp_path / "style.yaml"
    path.write_text(text)
    with pytest.raises(StyleError, match=message):
        read_style(path)


def test_when_style_file_good_expect_read_and_written_back_alike(tmp_path):
    path = tmp_path / "style.yaml"
    path.write_text(GOOD)
    style = read_style(path)
    style.write(tmp_path / "again.yaml")
    assert read_style(tmp_path / "again.yaml") == style


def test_when_style_unknown_or_set_badly_expect_clear_errors(tmp_path, speech_path, capsys):
    out = str(tmp_path / "x.csv")
    assert main(["synth", str(speech_path), "-o", out, "--style", "nobody"]) == 1
    assert "not a preset" in capsys.readouterr().err
    assert main(["synth", str(speech_path), "-o", out, "--style-set", "arms=1"]) == 2
    assert "NAME one of" in capsys.readouterr().err
    assert main(["synth", str(speech_path), "-o", out, "--style-set", "arms_gain=nan"]) == 1
    assert "arms_gain: value nan is not finite" in capsys.readouterr().err


def test_when_style_set_given_expect_synth_output_scaled_about_neutral(
    tmp_path, robot, speech_path
):
    base, small = tmp_path / "base.csv", tmp_path / "small.csv"
    assert main(["synth", str(speech_path), "-o", str(base)]) == 0
    assert main(["synth", str(speech_path), "-o", str(small), "--style-set", "head_gain=0"]) == 0
    head = robot.group_mask("head")
    still = read_csv(small)[:, head]
    np.testing.assert_allclose(still, np.tile(robot.neutral_rad[head], (len(still), 1)))
    assert np.ptp(read_csv(base)[:, head]) > 0.01


def test_when_presets_shipped_expect_each_readable_with_figures_and_command():
    names = preset_names()
    assert {"calm_reader", "addressing_camera", "lecturer"} <= set(names)
    for name in names:
        style = load_style(name)
        assert style.parts
        assert style.command == "make style-presets"
        assert style.source


@pytest.mark.slow
@pytest.mark.skipif(not OBAMA, reason="the shared talking-head clips are not here")
def test_when_enrolling_a_real_video_expect_a_head_style_and_progress(tmp_path, capsys):
    """Real talking-head video (the Obama clips joined, 15 s): its first 8 s, the head only.

    Whether the head learns depends on whether a fit comes closer than the default on the
    stretches it did not fit; either way ``enroll`` says which, and the folder holds it.
    """
    joined = tmp_path / "obama.mp4"
    inputs = [arg for clip in OBAMA for arg in ("-i", str(clip))]
    streams = "".join(f"[{k}:v][{k}:a]" for k in range(len(OBAMA)))
    subprocess.run(
        [ffmpeg_executable(), "-v", "error", "-y", *inputs, "-filter_complex",
         f"{streams}concat=n={len(OBAMA)}:v=1:a=1[v][a]", "-map", "[v]", "-map", "[a]",
         "-s", "640x360", str(joined)],
        check=True,
    )  # fmt: skip
    assert main(["enroll", str(joined), "-o", str(tmp_path / "me"), "--max-seconds", "8"]) == 0
    captured = capsys.readouterr()
    assert "enroll: tracking face and body" in captured.err
    # head and shoulders: the arms are not seen; the head's verdict is said, either way
    verdicts = [line for line in captured.out.splitlines() if line.startswith("head: ")]
    assert len(verdicts) == 1
    assert not any(line.startswith(("arms: ", "hip: ")) for line in captured.out.splitlines())
    style = read_style(tmp_path / "me" / "style.yaml")
    assert style.fitted is not None
    fitted = style.fitted[1]
    assert (fitted.arms_gain, fitted.hip_gain) == (1.0, 1.0)  # parts not seen keep the model's
    if verdicts[0].startswith("head: kept the default ("):
        assert style.parts == {}
        assert fitted == StyleSettings()
        return
    assert "expected to come" in verdicts[0]
    assert "head_gain:=" in captured.out
    assert set(style.parts) == {"head"}
    assert 5.0 <= style.parts["head"].seconds <= 8.0  # only the first 8 s were tracked
    assert fitted.head_gain != 1.0 or fitted.head_tempo != 1.0  # the head is fitted


def test_when_run_gets_a_personal_model_expect_its_checkpoint_and_style_as_overrides(tmp_path):
    """``audio2pose run --model me/``: the graph's parameters (the run itself is a DDS test)."""
    import argparse

    from audio2pose_ros.cli.style_commands import graph_overrides

    source = tmp_path / "style.yaml"
    source.write_text(GOOD)
    style = read_style(source)
    folder = tmp_path / "me"
    folder.mkdir()
    from audio2pose_ros.resources import default_checkpoint_path
    from audio2pose_ros.style.figures import StyleFile
    from audio2pose_ros.style.personal import checkpoint_digest

    fitted = (checkpoint_digest(default_checkpoint_path()), StyleSettings(head_gain=0.5))
    StyleFile("me", "", "", "", style.parts, fitted).write(folder / "style.yaml")
    args = argparse.Namespace(model=str(folder), style=None, style_set=["head_tempo=0.8"])
    overrides = graph_overrides(args)
    assert overrides[0] == f"model_path:={default_checkpoint_path().resolve()}"
    assert set(overrides[1:]) == {"head_gain:=0.5", "head_tempo:=0.8"}


def test_when_the_folder_holds_a_personal_checkpoint_expect_run_to_load_it_with_its_style(
    tmp_path,
):
    """``audio2pose run --model me/`` with the arms' noise fitted: the folder's own checkpoint."""
    import argparse
    import shutil

    from audio2pose_ros.cli.style_commands import graph_overrides
    from audio2pose_ros.style.figures import StyleFile

    source = tmp_path / "style.yaml"
    source.write_text(GOOD)
    folder = tmp_path / "me"
    folder.mkdir()
    own = folder / "model.safetensors"
    shutil.copyfile(default_checkpoint_path(), own)
    fitted = (checkpoint_digest(own), StyleSettings(arms_rest_pitch_rad=0.25))
    StyleFile("me", "", "", "", read_style(source).parts, fitted).write(folder / "style.yaml")
    args = argparse.Namespace(model=str(folder), style=None, style_set=[])
    assert graph_overrides(args) == [f"model_path:={own.resolve()}", "arms_rest_pitch_rad:=0.25"]
