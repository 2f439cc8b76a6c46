"""``evaluate-style``: a data set given as NAME=DATASET is one source (one person's import), and
the enrolled row is the personal model ``enroll`` makes."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

from audio2pose_ros.audio.wav import read_wav
from audio2pose_ros.checkpoints.torch_io import load_checkpoint
from audio2pose_ros.cli.main import main
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.motion.style import style_trajectory
from audio2pose_ros.resources import default_checkpoint_path
from audio2pose_ros.style import evaluation, personal
from audio2pose_ros.style.evaluation import SourceSpec, source_spec
from audio2pose_ros.style.figures import measure_part
from audio2pose_ros.style.personal import checkpoint_synthesizer, fit_personal
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLES_PER_FRAME

ROOT = Path(__file__).resolve().parent.parent
# GRID-style sentence ids: by clip id (up to the first digit) they would be four sources
IDS = ("bbaf3s", "bbaf4p", "bgaa1a", "lwae8n", "pbio7a")
# short clips first: the enrolment (7 s at most) takes the first two, 6.3 s
SPEECH = ("0880", "0930", "0890", "0920", "0870")


def one_reader(root, robot, speech_files):
    """A data set of one reader's sentences: real speech, a small head motion, head observed."""
    files = {f.stem.rsplit("_", 1)[1]: f for f in speech_files}
    dataset = Dataset.create(root, robot)
    rng = np.random.default_rng(1)
    head = robot.group_mask("head")
    for clip_id, number in zip(IDS, SPEECH, strict=True):
        audio = read_wav(files[number])[0]
        n = audio.size // SAMPLES_PER_FRAME
        angles = np.tile(robot.neutral_rad, (n, 1))
        walk = np.cumsum(rng.normal(0.0, 0.002, (n, int(head.sum()))), axis=0)
        angles[:, head] += walk - walk.mean(axis=0)
        mask = np.zeros(angles.shape, dtype=bool)
        mask[:, head] = True
        info = ClipInfo(clip_id, "reader", "test sentences", "CC BY 4.0 | test attribution")
        dataset.add(Clip(info, audio, angles, mask), robot)
    return root


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("out/data", SourceSpec(Path("out/data"))),
        ("grid_s1=out/s1", SourceSpec(Path("out/s1"), "grid_s1")),
        ("a/b=c", SourceSpec(Path("a/b=c"))),  # not a name before '=': a path
        ("=c", SourceSpec(Path("=c"))),
        ("s1=", SourceSpec(Path("s1="))),
        ("x|y=c", SourceSpec(Path("x|y=c"))),  # would break the table: not a name
    ],
)
def test_when_source_given_expect_name_only_for_name_equals_dataset(text, expected):
    assert source_spec(text) == expected


def test_when_an_existing_path_has_an_equals_sign_expect_it_taken_as_the_path(tmp_path):
    (tmp_path / "s1=data").mkdir()
    text = str(tmp_path / "s1=data")
    assert source_spec(text) == SourceSpec(Path(text))


def test_when_a_data_set_is_named_expect_one_source_and_one_synthesis_per_clip(
    tmp_path, robot, speech_files, monkeypatch, capsys
):
    data = one_reader(tmp_path / "reader", robot, speech_files)
    assert set(evaluation.sources(SourceSpec(data), robot)) == {"bbaf", "bgaa", "lwae", "pbio"}
    calls = []
    real_synthesizer = personal.checkpoint_synthesizer

    def counting(checkpoint):
        run = real_synthesizer(checkpoint)

        def counted(clip):
            calls.append(clip.info.clip_id)
            return run(clip)

        return counted

    monkeypatch.setattr(personal, "checkpoint_synthesizer", counting)
    card = tmp_path / "MODEL_CARD.md"
    card.write_text("# card\n", encoding="utf-8")
    code = main(["evaluate-style", f"reader={data}", "--enroll-seconds", "7", "--card", str(card)])
    assert code == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| reader (18 s) |")]
    methods = ["default (SI)", "enrolled on 6 s (SD)", "real split half"]
    methods.append("real enrolment part (6 s)")
    assert [row.split(" | ")[2] for row in rows] == methods
    assert all(row.startswith("| reader (18 s) | head |") for row in rows)
    assert "| reader (real) | head | 25 |" in out  # the figures of all of its clips
    assert not any(line.startswith(("| bbaf", "| bgaa")) for line in out.splitlines())
    assert sorted(calls) == sorted(IDS)  # enrolment, scores and figures share one synthesis
    origin = f"| reader | `{data}` | 5 | 0.4 | test sentences | CC BY 4.0 \\| test attribution |"
    assert origin in out
    text = card.read_text(encoding="utf-8")
    assert text.startswith("# card\n")
    assert origin in text
    assert rows[1] in text
    rebuild = f"audio2pose evaluate-style reader={data} --enroll-seconds 7 --card {card}"
    assert f"Rebuild: `{rebuild}`" in text


def test_when_the_makefile_evaluates_style_expect_grid_s1_only_when_its_data_set_is_there(
    tmp_path,
):
    def command(folder):
        lines = subprocess.run(
            ["make", "-n", "-C", str(ROOT), "evaluate-style", f"GRID_S1={folder}"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.splitlines()
        return next(line for line in lines if "audio2pose evaluate-style" in line)

    folder = tmp_path / "s1"
    folder.mkdir()
    assert "grid_s1=" not in command(folder)  # a clean clone: no s1 data set
    (folder / "index.json").write_text("{}", encoding="utf-8")
    assert f"grid_s1={folder}" in command(folder)


def lively_arms(root, robot, speech_files):
    """One person's sentences with arms far livelier than the default model's (arms observed)."""
    files = {f.stem.rsplit("_", 1)[1]: f for f in speech_files}
    dataset = Dataset.create(root, robot)
    arms = robot.group_mask("arms")
    phases = np.arange(arms.sum())[None, :]
    for clip_id, number in zip(IDS, SPEECH, strict=True):
        audio = read_wav(files[number])[0]
        n = audio.size // SAMPLES_PER_FRAME
        t = np.arange(n)[:, None] / 100.0
        angles = np.tile(robot.neutral_rad, (n, 1))
        angles[:, arms] += 0.3 * np.sin(2 * np.pi * 1.3 * t + phases) * np.sin(np.pi * 0.4 * t)
        mask = np.zeros(angles.shape, dtype=bool)
        mask[:, arms] = True
        dataset.add(
            Clip(ClipInfo(clip_id, "lively", "test", "test data"), audio, angles, mask), robot
        )
    return root


@pytest.mark.slow
def test_when_enrolment_fits_the_arms_noise_expect_the_enrolled_row_to_run_the_personal_model(
    tmp_path, robot, speech_files
):
    """The SD row is what ``enroll`` makes and ``--model`` runs, not the style on the default."""
    data = lively_arms(tmp_path / "lively", robot, speech_files)
    lines = []
    out = evaluation.evaluate_sources([SourceSpec(data, "lively")], robot, 7.0, lines.append)
    dataset = Dataset.open(data, robot)
    clips = [dataset.load(info.clip_id) for info in dataset.clips]
    enrol, held = clips[:2], clips[2:]  # 6.3 s enrolled (at most 7 s)
    checkpoint = load_checkpoint(default_checkpoint_path(), robot=robot)
    fitted = fit_personal(enrol, robot, checkpoint)  # what enroll fits on the same clips
    assert fitted.arms_noise > 1.0  # lively arms: a personal checkpoint

    def size_ratio(model, settings):
        run = checkpoint_synthesizer(model)
        motion = []
        for clip in held:
            angles = run(clip)[: clip.n_frames]  # as long as the clip, its last pose held
            angles = np.pad(angles, ((0, clip.n_frames - len(angles)), (0, 0)), mode="edge")
            styled = style_trajectory(robot, settings, angles, FRAME_RATE_HZ)
            motion.append((styled, clip.mask))
        real = [(c.angles_rad, c.mask) for c in held]
        sizes = [measure_part(m, robot, "arms", FRAME_RATE_HZ, 1.0) for m in (motion, real)]
        return f"{sizes[0].std_rad / sizes[1].std_rad:.2f}"

    personal_ratio = size_ratio(fitted.checkpoint, fitted.settings)
    assert personal_ratio != size_ratio(checkpoint, fitted.style_alone)  # the test can tell
    row = next(line for line in out.splitlines() if "| enrolled on 6 s (SD) |" in line)
    assert row.startswith("| lively (18 s) | arms |")
    assert row.split(" | ")[5] == personal_ratio
    assert f"| lively | 6 | arms | {fitted.arms_noise:g}x |" in out  # the fits table
    assert any(f"{fitted.arms_noise:g}x" in line for line in lines)  # and the progress


def test_when_a_long_clip_follows_a_short_first_one_expect_enrolment_cut_from_it(robot):
    """A lecture whose first stretch with arms is 4 s, then 30 s: enrolled on 27 s, not 4 s."""

    def clip(clip_id, seconds):
        n = seconds * 100
        audio = np.zeros(n * SAMPLES_PER_FRAME, dtype=np.float32)
        angles = np.tile(robot.neutral_rad, (n, 1))
        info = ClipInfo(clip_id, "lewin", "test", "test data")
        return Clip(info, audio, angles, np.ones(angles.shape, dtype=bool))

    clips = [clip("lecture_000.00s", 4), clip("lecture_016.01s", 30), clip("x_2", 20)]
    enrol, held = evaluation._split(clips, 60.0)
    assert [c.n_frames for c in enrol] == [400, 2300]  # half of 54 s: 27 s
    assert [c.n_frames for c in held] == [700, 2000]
    assert enrol[1].audio.size == 2300 * SAMPLES_PER_FRAME
    assert held[0].audio.size == 700 * SAMPLES_PER_FRAME
    longer = [clip("a_1", 20), *clips[1:]]  # whole clips when they hold half the budget
    whole, rest = evaluation._split(longer, 60.0)
    assert whole == longer[:1]
    assert rest == longer[1:]
