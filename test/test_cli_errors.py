"""Worst-case options and files for every verb: one line on stderr, the right exit status.

Exit status: 2 for a bad option, 1 for bad data, 70 for a bug. Nothing here may print a
traceback (except a bug under ``--debug``), loop without end, or grow without bound. Each case
runs the real console entry, ``audio2pose_ros.cli.main.main``, in this process.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.audio.pcm import S16LE_MONO_16K, PcmFormat, encode_pcm
from audio2pose_ros.cli import main as cli
from audio2pose_ros.data import bag as bag_module
from audio2pose_ros.data.bag import (
    AUDIO_DATA_TYPE,
    AUDIO_INFO_TOPIC,
    AUDIO_INFO_TYPE,
    AUDIO_TOPIC,
    BagError,
    BagWriter,
    read_bag_audio,
    typestore,
)
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.topics import JOINT_ANGLES, absolute


def audio2pose(capsys: pytest.CaptureFixture[str], *argv: object) -> tuple[int, str]:
    """Run ``audio2pose argv...``; return the exit status and stderr (argparse exits included)."""
    try:
        status = cli.main([str(a) for a in argv])
    except SystemExit as exc:
        status = exc.code
    return status, capsys.readouterr().err


def assert_one_line(stderr: str, pattern: str) -> None:
    import re

    assert "Traceback" not in stderr, stderr
    assert stderr.count("\n") == 1, stderr
    assert stderr.endswith("\n"), stderr
    assert re.search(pattern, stderr), stderr


def speech_bag(path: Path, info: PcmFormat, payload: bytes, data: bytes | None = None) -> Path:
    """A bag with one AudioInfo and one AudioData (``data`` as raw CDR when given)."""
    store = typestore()
    info_cdr = store.serialize_cdr(
        store.types[AUDIO_INFO_TYPE](**info.audio_info_fields()), AUDIO_INFO_TYPE
    )
    audio = store.types[AUDIO_DATA_TYPE](data=np.frombuffer(payload, dtype=np.uint8))
    with BagWriter(path) as bag:
        bag.write(AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE, 1, bytes(info_cdr))
        bag.write(
            AUDIO_TOPIC,
            AUDIO_DATA_TYPE,
            2,
            data if data is not None else bytes(store.serialize_cdr(audio, AUDIO_DATA_TYPE)),
        )
    return path


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["run", "--rate", "0"], r"--rate: '0' is not a finite number in \(0, 100\]"),
        (["run", "--rate", "-1"], "--rate: '-1' is not a finite number"),
        (["run", "--rate", "nan"], "--rate: 'nan' is not a finite number"),
        (["run", "--rate", "inf"], "--rate: 'inf' is not a finite number"),
        (["run", "--rate", "fast"], "--rate: 'fast' is not a number"),
        (["bag", "replay", "b", "--rate", "0"], "--rate: '0' is not a finite number"),
        (["bag", "replay", "b", "--wait-s", "-1"], "--wait-s: '-1' is not a finite number"),
        (["bag", "from-wav", "x.wav", "-o", "b", "--min-bytes", "0"], r"--min-bytes: '0'"),
        (["bag", "from-wav", "x.wav", "-o", "b", "--max-bytes", "9" * 30], "--max-bytes: '99"),
        (["bench", "--frames", "0"], r"--frames: '0' is not an integer in \[10, 1000000\]"),
        (["bench", "--duration", "nan"], "--duration: 'nan' is not a finite number"),
        (["render", "x.wav", "-o", "x.mp4", "--fps", "0"], "--fps: '0' is not a finite number"),
        (["render", "x.wav", "-o", "x.mp4", "--view-width", "-2"], "--view-width: '-2'"),
        (["distill-prosody", "x.wav", "-o", "m", "--seed", "-1"], "--seed: '-1' is not an"),
        (["evaluate", "c", "--data", "d", "--samples", "0"], "--samples: '0' is not an integer"),
    ],
)
def test_when_an_option_value_is_absurd_expect_exit_2_and_one_line_naming_it(
    capsys, argv: list[str], option: str
):
    status, stderr = audio2pose(capsys, *argv)
    assert status == 2
    assert_one_line(stderr, option)


def test_when_min_bytes_and_max_bytes_are_zero_expect_refused_not_endless(capsys, tmp_path):
    status, stderr = audio2pose(
        capsys, "bag", "from-wav", tmp_path / "x.wav", "-o", tmp_path / "b",
        "--min-bytes", "0", "--max-bytes", "0",
    )  # fmt: skip
    assert status == 2
    assert_one_line(stderr, "--min-bytes: '0' is not an integer in")


def test_when_min_bytes_exceeds_max_bytes_expect_usage_error(capsys, tmp_path, speech_path):
    status, stderr = audio2pose(
        capsys, "bag", "from-wav", speech_path, "-o", tmp_path / "b",
        "--min-bytes", "100", "--max-bytes", "10",
    )  # fmt: skip
    assert status == 2
    assert_one_line(stderr, "--min-bytes 100 is larger than --max-bytes 10")


def test_when_record_without_play_expect_usage_error(capsys, tmp_path):
    status, stderr = audio2pose(capsys, "run", "--record", tmp_path / "x")
    assert status == 2
    assert_one_line(stderr, "audio2pose run: error: --record needs --play")


@pytest.mark.parametrize(
    ("make", "problem"),
    [
        (lambda d: d / "missing 🙂.wav", "missing 🙂.wav: WAV file not found"),
        (lambda d: d, "is a directory, expected a WAV file"),
        (lambda _: Path("/dev/zero"), "/dev/zero: not a regular file"),
    ],
)
def test_when_the_input_is_missing_a_directory_or_a_device_expect_exit_1(
    capsys, tmp_path, make, problem
):
    wav = make(tmp_path)
    if wav == tmp_path:
        wav = tmp_path / "folder.wav"
        wav.mkdir()
    status, stderr = audio2pose(capsys, "synth", wav, "-o", tmp_path / "o.csv")
    assert status == 1
    assert_one_line(stderr, problem)


def test_when_the_output_folder_does_not_exist_expect_usage_error(capsys, tmp_path, speech_path):
    status, stderr = audio2pose(capsys, "synth", speech_path, "-o", tmp_path / "no" / "o.csv")
    assert status == 2
    assert_one_line(stderr, r"-o .*o\.csv: folder .*no does not exist")


def test_when_the_checkpoint_is_crafted_expect_one_line_not_recursion_error(
    capsys, tmp_path, speech_path
):
    deep = tmp_path / "deep.safetensors"
    text = b"[" * 10_000 + b"]" * 10_000
    deep.write_bytes(struct.pack("<Q", len(text)) + text)
    status, stderr = audio2pose(capsys, "synth", speech_path, "-o", tmp_path / "o.csv",
                                "--model", deep)  # fmt: skip
    assert status == 1
    assert_one_line(stderr, "deep.safetensors: safetensors header nests 10000 levels deep")


def test_when_the_bag_holds_invalid_cdr_expect_one_line_naming_topic(capsys, tmp_path):
    bag = speech_bag(tmp_path / "bag", S16LE_MONO_16K, b"", data=b"\x00\x01\x00\x00\xff")
    status, stderr = audio2pose(capsys, "synth", bag, "-o", tmp_path / "o.csv")
    assert status == 1
    assert_one_line(stderr, r"/audio/audio at 2 ns: invalid audio_common_msgs/msg/AudioData CDR")


def test_when_bag_audio_decodes_beyond_the_cap_expect_refused_before_decoding(
    tmp_path, monkeypatch
):
    rate_8k = PcmFormat(sample_rate_hz=8000)
    bag = speech_bag(tmp_path / "bag", rate_8k, encode_pcm(np.zeros(16000), rate_8k))
    monkeypatch.setattr(bag_module, "MAX_BAG_AUDIO_S", 1.0)  # the bag holds 2 s of audio
    with pytest.raises(BagError, match=r"audio at 8000 Hz decodes to more than 1 s at 16000 Hz"):
        read_bag_audio(bag)


def test_when_a_bag_claims_1_hz_expect_one_line_not_gigabytes(capsys, tmp_path):
    one_hz = json.loads(json.dumps(S16LE_MONO_16K.audio_info_fields()))
    one_hz["sample_rate"] = 1
    store = typestore()
    with BagWriter(tmp_path / "bag") as bag:
        info = store.types[AUDIO_INFO_TYPE](**one_hz)
        bag.write(
            AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE, 1, bytes(store.serialize_cdr(info, AUDIO_INFO_TYPE))
        )
        audio = store.types[AUDIO_DATA_TYPE](data=np.zeros(200_000, dtype=np.uint8))
        bag.write(
            AUDIO_TOPIC, AUDIO_DATA_TYPE, 2, bytes(store.serialize_cdr(audio, AUDIO_DATA_TYPE))
        )
    status, stderr = audio2pose(capsys, "synth", tmp_path / "bag", "-o", tmp_path / "o.csv")
    assert status == 1
    assert_one_line(stderr, "bag: .*(unusable AudioInfo|decodes to more than)")


def test_when_a_bag_names_an_unknown_message_type_expect_it_never_imported(
    capsys, tmp_path, monkeypatch
):
    from rosbags.typesys import get_types_from_msg

    marker = tmp_path / "imported"
    package = tmp_path / "evil_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "msg.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    store = typestore()
    store.register(get_types_from_msg("string data\n", "evil_pkg/msg/Payload"))
    payload = store.serialize_cdr(
        store.types["evil_pkg/msg/Payload"](data="x"), "evil_pkg/msg/Payload"
    )
    writer = BagWriter(tmp_path / "bag")
    writer.store = store
    with writer:
        writer.write("/payload", "evil_pkg/msg/Payload", 1, bytes(payload))
    status, stderr = audio2pose(capsys, "bag", "replay", tmp_path / "bag", "--wait-s", "0")
    assert status == 1
    assert_one_line(stderr, r"bag: no audio to replay .*/payload \(evil_pkg/msg/Payload, not a")
    status, stderr = audio2pose(
        capsys, "bag", "replay", tmp_path / "bag", "--topics", "/payload", "--wait-s", "0"
    )
    assert status == 1
    assert_one_line(stderr, "/payload: message type 'evil_pkg/msg/Payload' is not one this")
    assert not marker.exists()


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        ("motion_filter_node: [1, 2\n", r"params\.yaml: not valid YAML at line 2"),
        ("- a\n- b\n", "a parameters file is a mapping of node names"),
        ("motion_filter_node:\n  ros__parameters: [1]\n", "ros__parameters must be a mapping"),
        (
            "motion_filter_node:\n  ros__parameters:\n    robot_description: [x]\n",
            "robot_description must be a string",
        ),
        (
            "motion_filter_node:\n  ros__parameters:\n    robot_description: ROBOT\n",
            r"bad_robot\.yaml: joints\[0\] \(J1\): field max_rad must be a number",
        ),
    ],
)
def test_when_the_parameters_file_is_malformed_expect_one_line_naming_it(
    capsys, tmp_path, speech_path, content, problem
):
    robot = tmp_path / "bad_robot.yaml"
    robot.write_text(
        "robot: r\njoints:\n  - {name: J1, group: head, min_rad: -1, max_rad: '1', "
        "max_velocity_rad_s: 1, max_acceleration_rad_s2: 1, neutral_rad: 0}\n"
    )
    params = tmp_path / "params.yaml"
    params.write_text(content.replace("ROBOT", str(robot)))
    status, stderr = audio2pose(
        capsys, "plot-filter", speech_path, "-o", tmp_path / "p.png", "--params-file", params
    )
    assert status == 1
    assert_one_line(stderr, problem)


def test_when_a_command_has_a_bug_expect_it_reported_as_a_bug_and_traceback_only_with_debug(
    capsys, monkeypatch, tmp_path
):
    def buggy(args: object) -> int:
        raise ValueError("list index confusion")

    monkeypatch.setattr(cli, "command_synth", buggy)
    argv = ["synth", str(default_checkpoint_path()), "-o", str(tmp_path / "o.csv")]
    status, stderr = audio2pose(capsys, *argv)
    assert status == cli.EXIT_INTERNAL_ERROR
    assert_one_line(
        stderr,
        r"^audio2pose synth: internal error \(a bug\): ValueError: list index confusion; run "
        "with --debug for the traceback",
    )
    status, stderr = audio2pose(capsys, "--debug", *argv)
    assert status == cli.EXIT_INTERNAL_ERROR
    assert "Traceback (most recent call last)" in stderr
    assert stderr.splitlines()[-1].startswith("audio2pose synth: internal error (a bug)")


def test_when_render_is_given_a_bag_with_invalid_joint_angles_expect_one_line(
    capsys, tmp_path, speech_path
):
    with BagWriter(tmp_path / "bag") as bag:
        bag.write(
            absolute(JOINT_ANGLES), "naoqi_bridge_msgs/msg/JointAnglesWithSpeed", 1, b"\x00\x01"
        )
    status, stderr = audio2pose(
        capsys, "render", speech_path, "-o", tmp_path / "v.mp4", "--bag", tmp_path / "bag"
    )
    assert status == 1
    assert_one_line(stderr, "/joint_angles at 1 ns: invalid naoqi_bridge_msgs/msg/JointAngles")


@pytest.mark.parametrize(
    ("mappings", "problem"),
    [
        ("cmu: [\n", r"maps\.yaml: not valid YAML at line 2"),
        ("- 1\n", r"maps\.yaml: expected a mapping of skeleton names"),
        ("cmu: 3\n", r"maps\.yaml: skeleton 'cmu' needs a 'joints' mapping"),
        ("/dev/zero", "/dev/zero: not a regular file, expected a skeleton mappings file"),
    ],
)
def test_when_the_bvh_mappings_file_is_unusable_expect_one_line_not_a_bug(
    capsys, tmp_path, mappings, problem
):
    path = Path(mappings) if mappings.startswith("/dev") else tmp_path / "maps.yaml"
    if path.parent == tmp_path:
        path.write_text(mappings)
    (tmp_path / "take.bvh").write_text("HIERARCHY\n")
    status, stderr = audio2pose(
        capsys, "dataset", "import-bvh", tmp_path / "take.bvh", "-o", tmp_path / "d",
        "--licence", "x", "--skeleton", "cmu", "--mappings", path,
    )  # fmt: skip
    assert status == 1
    assert_one_line(stderr, problem)


def test_when_demo_out_is_a_file_expect_usage_error_before_starting_anything(capsys, tmp_path):
    (tmp_path / "file").write_text("")
    status, stderr = audio2pose(capsys, "demo", "--out", tmp_path / "file")
    assert status == 2
    assert_one_line(stderr, "--out .*file: exists and is not a directory")


def test_when_replaying_a_bag_with_invalid_cdr_expect_refused_before_publishing(capsys, tmp_path):
    bag = speech_bag(tmp_path / "bag", S16LE_MONO_16K, b"", data=b"\x00\x01\x00\x00\xff")
    status, stderr = audio2pose(capsys, "bag", "replay", bag, "--wait-s", "0")
    assert status == 1
    assert_one_line(stderr, r"bag replay: error: .*/audio/audio at 2 ns: invalid audio_common")


def test_when_a_bag_spans_centuries_expect_replay_refused_not_sleeping(capsys, tmp_path):
    store = typestore()
    info = store.serialize_cdr(
        store.types[AUDIO_INFO_TYPE](**S16LE_MONO_16K.audio_info_fields()), AUDIO_INFO_TYPE
    )
    with BagWriter(tmp_path / "bag") as bag:
        bag.write(AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE, 1, bytes(info))
        bag.write(AUDIO_INFO_TOPIC, AUDIO_INFO_TYPE, 2**62, bytes(info))
    status, stderr = audio2pose(capsys, "bag", "replay", tmp_path / "bag", "--wait-s", "0")
    assert status == 1
    assert_one_line(stderr, r"replaying would take 4\.61e\+09 s at --rate 1; at most 86400 s")


@pytest.fixture
def console_not_started(monkeypatch):
    """Should a bad file pass the check, the console would start: the test fails instead."""
    import audio2pose_ros.ros.console_runner as runner

    def refuse(*_args, **_kwargs):
        raise AssertionError("the parameters file passed the check; the console would start")

    monkeypatch.setattr(runner, "run_console", refuse)


def _alias_bomb(levels: int) -> str:
    """Nested YAML aliases: 9**levels leaves from a few hundred bytes ("billion laughs")."""
    lines = ['a0: &a0 ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels)]
    return "\n".join([*lines, f"console_node:\n  ros__parameters:\n    host: *a{levels - 1}\n"])


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b'console_node:\n  ros__parameters:\n    token: "\xff\xfe"\n', "not UTF-8"),
        (b"console_node:\n  ros__parameters: [1, 2]\n", "ros__parameters must be a mapping"),
        (b"- just\n- a list\n", "a parameters file is a mapping of node names"),
        (_alias_bomb(6).encode(), "aliases"),
    ],
    ids=["not-utf8", "parameters-list", "document-list", "alias-bomb"],
)
def test_when_the_console_parameters_file_is_malformed_expect_one_line_not_a_bug(
    capsys, tmp_path, console_not_started, content, problem
):
    """The console's check before anything starts reads the file as every parameters file is."""
    params = tmp_path / "params.yaml"
    params.write_bytes(content)
    status, stderr = audio2pose(capsys, "console", "--no-graph", "--params-file", params)
    assert status == 1
    assert_one_line(stderr, problem)
    assert len(stderr) < 500
