"""``audio2pose render`` options that name paths and sizes: refused at once, inputs kept.

An output (the MP4 or the bag folder) is never, never holds and never lies inside one of the
command's inputs, whatever path names it (the default ``OUT_mcap``, ``--mcap``, a symlink, the
bag's own ``.mcap`` file): one line, exit status 2, and the recording left as it was. A size the
layout cannot hold is refused by the parser, before any synthesis; every size the help
documents renders.
"""

from __future__ import annotations

import argparse
import hashlib
import re
from pathlib import Path

import numpy as np
import pytest
from recording_fixtures import write_wav
from test_cli_errors import assert_one_line, audio2pose

from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.cli.render_commands import register
from audio2pose_ros.data.bag import AUDIO_TOPIC, BagWriter, audio_messages, bag_topics, typestore
from audio2pose_ros.robot.description import RobotDescription

JOINT_ANGLES_TYPE = "naoqi_bridge_msgs/msg/JointAnglesWithSpeed"
SMALL_VIDEO = ["--fps", "5", "--view-width", "160", "--view-height", "64",
               "--curves-height", "100", "--no-progress"]  # fmt: skip


@pytest.fixture
def wav(tmp_path: Path) -> Path:
    path = tmp_path / "speech.wav"
    write_wav(path, 1.0)
    return path


def recorded_bag(path: Path, wav: Path, robot: RobotDescription) -> Path:
    """What ``audio2pose run --record`` keeps: the audio it played and the /joint_angles sent."""
    store = typestore()
    signal, _ = read_wav(wav)
    stamp = store.types["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="")
    with BagWriter(path) as bag:
        for m in audio_messages(signal):
            bag.write(m.topic, m.msgtype, m.timestamp_ns + 10**9, m.data)
        for i in range(50):
            msg = store.types[JOINT_ANGLES_TYPE](
                header=header,
                joint_names=list(robot.names),
                joint_angles=np.asarray(robot.neutral_rad + 0.01 * i, dtype=np.float32),
                speed=0.1,
                relative=0,
            )
            cdr = bytes(store.serialize_cdr(msg, JOINT_ANGLES_TYPE))
            bag.write("/joint_angles", JOINT_ANGLES_TYPE, 10**9 + i * 20_000_000, cdr)
    return path


def contents(folder: Path) -> dict[str, str]:
    """Each entry of a folder: a file's SHA-256, or "folder"."""
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "folder"
        for p in sorted(folder.iterdir())
    }


@pytest.mark.parametrize(
    ("how", "relation"),
    [
        ("default OUT_mcap", "is"),
        ("--mcap BAG", "is"),
        ("--mcap a symlink to BAG", "is"),
        ("--bag BAG/file.mcap, default OUT_mcap", "contains"),
        ("--mcap inside BAG", "is inside"),
        ("-o inside BAG", "is inside"),
    ],
)
def test_when_a_render_output_overlaps_the_input_bag_expect_exit_2_and_the_recording_kept(
    capsys, tmp_path, wav, robot, how, relation
):
    bag = recorded_bag(tmp_path / "take_mcap", wav, robot)
    before = contents(bag)
    (tmp_path / "link").symlink_to(bag)
    video = bag / "take.mp4" if how.startswith("-o") else tmp_path / "take.mp4"
    source = bag / "take_mcap.mcap" if how.startswith("--bag BAG/") else bag
    mcap = {
        "--mcap BAG": [bag],
        "--mcap a symlink to BAG": [tmp_path / "link"],
        "--mcap inside BAG": [bag / "new_mcap"],
    }.get(how, [])
    status, stderr = audio2pose(
        capsys, "render", wav, "--bag", source, "-o", video, *(["--mcap", *mcap] if mcap else []),
        "--force", *SMALL_VIDEO,
    )  # fmt: skip
    assert contents(bag) == before, "the input bag was changed"
    assert AUDIO_TOPIC in bag_topics(bag)
    assert not video.exists()
    assert status == 2
    assert_one_line(stderr, rf": {relation} (the folder \S+ of )?the input --bag ")


def test_when_the_render_bag_is_the_video_expect_exit_2_before_rendering(capsys, tmp_path, wav):
    video = tmp_path / "v.mp4"
    status, stderr = audio2pose(capsys, "render", wav, "-o", video, "--mcap", video, *SMALL_VIDEO)
    assert not video.exists()
    assert status == 2
    assert_one_line(stderr, r"--mcap \S+v\.mp4: is the output -o ")


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--view-width", "32"),
        ("--view-width", "66"),
        ("--curves-height", "32"),
        ("--curves-height", "72"),
    ],
)
def test_when_a_render_size_is_too_small_for_the_layout_expect_exit_2_before_any_work(
    capsys, tmp_path, wav, option, value
):
    # the layout needs 52 + 8 + 8 px across a view (margins, axes) and 26 + 4 x 6 + 3 x 8 px
    # down the curves (bottom margin, gaps, three axes): 66 and 72 px are just too small
    video = tmp_path / "v.mp4"
    status, stderr = audio2pose(capsys, "render", wav, "-o", video, *SMALL_VIDEO, option, value)
    assert not video.exists()
    assert status == 2, stderr
    assert_one_line(stderr, rf"{option}: '{value}' is not an integer in \[")


def documented_minimum(option: str) -> int:
    """The smallest value ``render --help`` gives for a size option."""
    verbs = argparse.ArgumentParser().add_subparsers()
    register(verbs)
    action = next(a for a in verbs.choices["render"]._actions if option in a.option_strings)
    found = re.search(r"even px, (\d+) to \d+", action.help or "")
    assert found, action.help
    return int(found.group(1))


def test_when_rendering_at_the_documented_minimum_of_every_size_expect_a_video(capsys, tmp_path):
    wav = tmp_path / "speech.wav"
    write_wav(wav, 0.5)
    sizes = [
        (option, str(documented_minimum(option)))
        for option in ("--view-width", "--view-height", "--curves-height")
    ]
    video = tmp_path / "v.mp4"
    status, stderr = audio2pose(
        capsys, "render", wav, "-o", video, "--fps", "5", "--no-progress",
        *(text for size in sizes for text in size),
    )  # fmt: skip
    assert status == 0, f"{sizes}: {stderr}"
    assert video.stat().st_size > 0
