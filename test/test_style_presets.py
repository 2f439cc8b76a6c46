"""The shipped presets keep their settings resolved against the packaged model: no synthesis at a
start, and the kept settings are what resolving gives."""

from __future__ import annotations

import dataclasses
import shutil

import pytest

from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.robot.description import load_robot
from audio2pose_ros.style import personal
from audio2pose_ros.style.figures import load_style, preset_names, presets_dir, read_style
from audio2pose_ros.style.presets import main


def test_when_a_preset_runs_on_the_packaged_model_expect_its_kept_settings_without_synthesis(
    monkeypatch,
):
    def no_synthesis(checkpoint_path):
        raise AssertionError("the preset was resolved again: the packaged model synthesised")

    monkeypatch.setattr(personal, "model_reference", no_synthesis)
    robot, checkpoint = load_robot(), default_checkpoint_path()
    digest = personal.checkpoint_digest(checkpoint)
    for name in preset_names():
        style = load_style(name)
        assert style.fitted is not None, f"{name} keeps no settings for the packaged model"
        assert style.fitted[0] == digest, (
            f"{name} was resolved for another model: run "
            "`python -m audio2pose_ros.style.presets --resolve`"
        )
        assert personal.style_settings(checkpoint, style, robot) == style.fitted[1]


def test_when_the_model_is_another_expect_the_preset_resolved_against_it(monkeypatch):
    calls = []
    monkeypatch.setattr(personal, "model_reference", lambda path: calls.append(path) or [])
    monkeypatch.setattr(personal, "checkpoint_digest", lambda path: "0" * 64)
    personal.style_settings(default_checkpoint_path(), load_style("calm_reader"), load_robot())
    assert calls == [default_checkpoint_path()]


@pytest.mark.slow
def test_when_presets_are_resolved_again_expect_the_settings_they_keep(tmp_path, capsys):
    copy = tmp_path / "styles"
    shutil.copytree(presets_dir(), copy)
    for path in copy.glob("*.yaml"):  # forget the kept settings
        style = read_style(path)
        path.write_text(style.to_yaml().split("fitted:")[0], encoding="utf-8")
        assert read_style(path).fitted is None
    assert main(["--resolve", str(copy)]) == 0
    assert capsys.readouterr().out.count("resolved ") == len(preset_names())
    for name in preset_names():
        again, kept = read_style(copy / f"{name}.yaml"), load_style(name)
        assert again.parts == kept.parts
        assert again.fitted is not None
        assert kept.fitted is not None
        assert again.fitted[0] == kept.fitted[0]
        # resolve() rounds to 1e-4: another machine's last float digit may flip a rounding
        for field in dataclasses.fields(kept.fitted[1]):
            assert getattr(again.fitted[1], field.name) == pytest.approx(
                getattr(kept.fitted[1], field.name), abs=1e-3
            ), (name, field.name)


def test_when_the_preset_command_is_misused_expect_usage_and_exit_2(capsys):
    assert main(["--resolve", "a", "b"]) == 2
    assert "--resolve [PRESETS_DIR]" in capsys.readouterr().err
    assert main(["--bogus", "a", "b"]) == 2  # not taken for a data set folder
    assert "usage" in capsys.readouterr().err
