"""Rebuild the default model from the shared recordings, end to end.

With ``arms="learned"`` (the default, :func:`build_learned_default_model`): import the 13
talking-head clips (real head motion, arms out of frame) and the lecture video (real arm and hip
motion, :mod:`audio2pose_ros.data.importers.lecture`), train one streaming sampler with a part per
joint group (``live_groups``: the head part learns from the talking heads, the arm-and-hip part
from the lecture, unobserved joints masked, never filled), choose its sampling settings on
validation clips (:mod:`audio2pose_ros.learning.sampler_selection`), and evaluate where it was not
trained (:mod:`audio2pose_ros.learning.source_holdout`): the head on each talking-head source
held out whole (GRID, Obama; each by a model that never saw that source and chose its settings
without it), the arms and hip on the held-out lecture stretch against the static pose, other
real motion and the prosody rule (:func:`audio2pose_ros.learning.quality.quality_evaluation`).

With ``arms="prosody"`` or ``"neutral"`` (explicitly named options,
:func:`build_default_model`): import the 13 clips (:mod:`audio2pose_ros.data.importers.video`: real
speech, real head motion; arms and hip masked, as they are not visible), split them by clip
(one GRID speaker and one Obama clip held out for test, one of each for validation), fill the
masked arm and hip joints of the training copy with the labelled procedural prosody rule
(:mod:`audio2pose_ros.motion.prosody`), train one streaming MLP (seed 003 section 4.3.3) on all 11
joints, and evaluate it on the held-out clips against the static, mean-motion and
mismatched-motion baselines (:mod:`audio2pose_ros.learning.evaluation`; only the head has ground
truth
there). The result is one checkpoint, as ``inference_node`` expects: its head is learned from
people, its arms and hip imitate the procedural rule, and the model card says so. With
``arms="neutral"`` the arms and hip are trained to stay at the neutral pose instead.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.data.importers.extras import save_extras
from audio2pose_ros.data.importers.video import VideoImportSettings, import_video
from audio2pose_ros.learning.arm_calm import PEOPLE_INFO_KEY
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.motion.prosody import prosody_trajectory
from audio2pose_ros.robot.description import RobotDescription

if TYPE_CHECKING:
    from audio2pose_ros.checkpoints.torch_io import Checkpoint
    from audio2pose_ros.learning.quality import Predictions
    from audio2pose_ros.learning.source_holdout import HoldoutResult
    from audio2pose_ros.learning.training import TrainSettings

GRID_LICENCE = (
    "CC BY 4.0; GRID audio-visual sentence corpus, Cooke, Barker, Cunningham and Shao (2006), "
    "JASA 120(5)"
)
OBAMA_LICENCE = "public domain (work of the US federal government: weekly address)"
TEST_CLIPS = ("grid_sbwe5n", "obama_weekly_address_21")  # one unseen GRID speaker, one Obama clip
VALIDATION_CLIPS = ("grid_lrwp9a", "obama_weekly_address_13")
ARM_MODES = ("prosody", "neutral")  # procedural layers of the MLP build
DEFAULT_SEED = 0  # the seed the inference node samples with unless told otherwise
LIVE_VALIDATION_LECTURE_S = (44.0, 60.0)  # the lecture clip starting here validates


SPEECH_BODY_SEEDS = 8  # seeds per bundled speech clip in the card's body check


@dataclass(frozen=True)
class DefaultModelResult:
    """Where the rebuild wrote its outputs, and the evaluation table."""

    checkpoint: Path
    model_card: Path
    table: str


def clip_info(path: Path) -> ClipInfo:
    """Metadata of one shared clip: speaker, source, licence and split (by clip)."""
    stem = path.stem
    split = "test" if stem in TEST_CLIPS else "validation" if stem in VALIDATION_CLIPS else "train"
    if stem.startswith("obama"):
        return ClipInfo(stem, "obama", f"{path.name} (US weekly address)", OBAMA_LICENCE, split)
    # each GRID clip of the shared set is a different speaker (SOURCES.md: 8 clips, 8 speakers)
    return ClipInfo(
        stem, f"grid_{stem.removeprefix('grid_')}", f"{path.name} (GRID)", GRID_LICENCE, split
    )


def import_talking_heads(
    clips_dir: Path,
    dataset_dir: Path,
    robot: RobotDescription,
    progress: Callable[[str], None] = print,
) -> Dataset:
    """Import every ``*.mpg`` / ``*.mp4`` of the shared folder into a new data set.

    Head and shoulders only (SOURCES.md): MediaPipe Pose is not run, arms and hip are masked.
    """
    dataset = Dataset.create(dataset_dir, robot)
    for path in sorted([*clips_dir.glob("*.mpg"), *clips_dir.glob("*.mp4")]):
        progress(f"importing {path.name}")
        clip, extras = import_video(path, clip_info(path), robot, VideoImportSettings(body=False))
        dataset.add(clip, robot)
        save_extras(dataset, clip.info.clip_id, extras)
    return dataset


def fill_unobserved(
    source: Dataset, target_dir: Path, robot: RobotDescription, arms: str = "prosody"
) -> Dataset:
    """Copy a data set, filling unobserved joints with the prosody rule (or neutral); mask True.

    Observed joints (here the head) keep their measured angles. The copy is a training set for a
    combined model; its clips' ``source`` says which joints are procedural.

    Raises:
        ValueError: ``arms`` is not one of :data:`ARM_MODES`.

    """
    if arms not in ARM_MODES:
        raise ValueError(f"arms {arms!r} not in {ARM_MODES}")
    target = Dataset.create(target_dir, robot)
    spec = FeatureSpec()  # LogFB-26: what the prosody rule reads
    for info in source.clips:
        clip = source.load(info.clip_id)
        if arms == "prosody":
            filled = prosody_trajectory(extract_features(clip.audio, spec), robot)
        else:
            filled = np.broadcast_to(robot.neutral_rad, clip.angles_rad.shape)
        n = min(filled.shape[0], clip.n_frames)
        angles = np.where(clip.mask[:n], clip.angles_rad[:n], filled[:n])
        note = f"{info.source}; unobserved joints filled by the {arms} rule"
        copy = ClipInfo(info.clip_id, info.speaker, note, info.licence, info.split)
        target.add(Clip(copy, clip.audio, angles, np.ones_like(clip.mask[:n])), robot)
    return target


def describe_training_data(arms: str) -> dict[str, str]:
    """What the default model learned from, stored in its checkpoint beside the model card's."""
    return {
        "dataset": "talking_heads: 8 GRID clips (Cooke et al. 2006, CC BY 4.0, attribution "
        "required) and 5 Obama weekly-address clips (public domain)",
        "trained_on": "HeadYaw and HeadPitch: real head motion (MediaPipe FaceMesh) of people "
        f"speaking; arms and hip: not human motion, the {arms} rule "
        "(audio2pose_ros.motion.prosody) filled in where no person was observed",
    }


def build_default_model(
    clips_dir: Path,
    out_dir: Path,
    work_dir: Path,
    robot: RobotDescription,
    arms: str = "prosody",
    max_epochs: int = 2000,
    seed: int = 0,
    progress: Callable[[str], None] = print,
) -> DefaultModelResult:
    """Import, train, evaluate and write ``out_dir/default.safetensors`` and its model card.

    Args:
        clips_dir: the shared talking-head clips (``../shared/data/talking_heads``).
        out_dir: where the checkpoint, MODEL_CARD.md and metrics.txt go.
        work_dir: scratch folder for the data sets (replaced).
        robot: joint order, limits and neutral pose.
        arms: ``"prosody"`` (labelled procedural arms and hip) or ``"neutral"``.
        max_epochs: training epochs at most (early stopping usually ends sooner).
        seed: training seed.
        progress: receives one line per step.

    """
    from audio2pose_ros.checkpoints.torch_io import save_checkpoint
    from audio2pose_ros.learning.evaluation import evaluate
    from audio2pose_ros.learning.talking_heads_card import write_default_model_card
    from audio2pose_ros.learning.train_state import state_path_for
    from audio2pose_ros.learning.training import TrainSettings, train_from_dataset

    shutil.rmtree(work_dir, ignore_errors=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    imported = import_talking_heads(clips_dir, work_dir / "talking_heads", robot, progress)
    progress(f"filling arms and hip of the training copy with the {arms} rule")
    filled = fill_unobserved(imported, work_dir / "talking_heads_filled", robot, arms)
    checkpoint_path = out_dir / "default.safetensors"
    progress("training the MLP")
    checkpoint, report = train_from_dataset(
        filled.root,
        checkpoint_path,
        robot,
        model_name="mlp",
        settings=TrainSettings(max_epochs=max_epochs, seed=seed),
    )
    state_path_for(checkpoint_path).unlink(missing_ok=True)  # resume state: not shipped
    checkpoint.info.update(describe_training_data(arms))
    save_checkpoint(checkpoint_path, checkpoint)  # the checkpoint says what it learned from
    progress("evaluating on the held-out clips")
    evaluation = evaluate([(checkpoint_path, checkpoint)], imported, robot, split="test")
    table = evaluation.table()
    (out_dir / "metrics.txt").write_text(table + "\n", encoding="utf-8")
    card = write_default_model_card(out_dir, checkpoint, report, imported, evaluation, arms)
    return DefaultModelResult(checkpoint_path, card, table)


@dataclass(frozen=True)
class LearnedBuildSettings:
    """Training and evaluation budget of :func:`build_learned_default_model`.

    Attributes:
        max_epochs: epochs at most (early stopping on the validation clips usually ends sooner).
        batch_size: 2 s windows per optimiser step.
        patience: epochs without validation improvement before training stops (the
            validation loss mixes head and arm clips, so this is more than the seed's 10).
        samples: samples per clip, pooled by the distribution measures and compared by the
            diversity measure.
        seed: training seed.
        workers: trainings side by side, one process each
            (:func:`~audio2pose_ros.learning.parallel.run_tasks`).

    """

    max_epochs: int = 200
    batch_size: int = 8
    patience: int = 30
    samples: int = 3
    seed: int = 0
    workers: int = 1

    def train_settings(self, max_epochs: int, seed: int | None = None) -> TrainSettings:
        """The TrainSettings of one training run of this budget (no progress bars)."""
        from audio2pose_ros.learning.training import TrainSettings

        return TrainSettings(
            max_epochs=max_epochs,
            batch_size=self.batch_size,
            patience=self.patience,
            seed=self.seed if seed is None else seed,
            show_progress=False,
        )


def validation_ids(clips: list[Clip]) -> set[str]:
    """Early-stopping clips: the usual talking-head pair and one training lecture stretch."""
    ids = set(VALIDATION_CLIPS)
    lecture = [
        c
        for c in clips
        if c.info.split == "train"
        and c.info.clip_id.startswith("lecture_")
        and LIVE_VALIDATION_LECTURE_S[0]
        <= float(c.info.clip_id.removeprefix("lecture_").removesuffix("s"))
        < LIVE_VALIDATION_LECTURE_S[1]
    ]
    ids |= {c.info.clip_id for c in lecture[:1]}
    return ids


def calm_table(
    checkpoint: Checkpoint, shipped: HoldoutResult, test: Sequence[Clip], seeds: range
) -> str:
    """The card's calm-arms table (:mod:`~audio2pose_ros.learning.arm_calm`), with its heading.

    Rows: the people's figures the arm part's settings were chosen within (the lecturer's
    training and validation stretches, commanded: the choice's calm budget, also kept in the
    checkpoint's info); the lecture's held-out stretch, real and the shipped model's samples,
    commanded; the shipped model on the bundled LibriVox speech over ``seeds``, commanded.
    """
    from audio2pose_ros.learning.arm_calm import arm_calm, arm_calm_table, model_calm, people_row
    from audio2pose_ros.learning.command_path import commanded
    from audio2pose_ros.robot.body import BodyModel

    robot = checkpoint.robot
    body = BodyModel.load(robot)
    people = people_row(checkpoint)
    rows = [people] if people is not None else []
    real = commanded(robot, [c.angles_rad for c in test])
    known = [(m, c.mask) for m, c in zip(real, test, strict=True)]
    rows.append(arm_calm("people: lecturer, held-out stretch", robot, body, known))
    model = [m for c in test for m in commanded(robot, shipped.raw[c.info.clip_id])]
    rows.append(arm_calm("shipped, held-out lecture stretch", robot, body, model))
    label = f"shipped, LibriVox, seeds {seeds.start}..{seeds.stop - 1}"
    rows.append(model_calm(checkpoint, bundled_speech(), seeds, label))
    return (
        "calm arms, commanded (shipped motion filter): arm joint-frames at the acceleration "
        "limit, frames with a wrist above its shoulder and more than 10 cm above it, "
        "shoulder-pitch and elbow-yaw speed (rad/s) / acceleration (rad/s^2) percentiles\n"
        + arm_calm_table(rows)
    )


def prosody_predictions(
    clips: Sequence[Clip], robot: RobotDescription
) -> tuple[Predictions, Predictions]:
    """The prosody rule's motion on the clips and on their audio with a pause (a baseline)."""
    from audio2pose_ros.learning.quality import PROSODY_RULE, with_pause

    spec = FeatureSpec()  # LogFB-26: what the rule reads

    def rule(audio: np.ndarray) -> list[np.ndarray]:
        return [prosody_trajectory(extract_features(audio, spec), robot)]

    return (
        {PROSODY_RULE: {c.info.clip_id: rule(c.audio) for c in clips}},
        {PROSODY_RULE: {c.info.clip_id: rule(with_pause(c.audio)) for c in clips}},
    )


def bundled_speech() -> dict[str, np.ndarray]:
    """The bundled LibriVox clips (``data/speech``), 16 kHz: other speakers than the data's."""
    from audio2pose_ros.audio.wav import read_wav
    from audio2pose_ros.resources import bundled_speech_paths

    return {p.stem: read_wav(p)[0] for p in bundled_speech_paths()}


def describe_learned_data() -> dict[str, str]:
    """What the learned default model learned from, stored in its checkpoint."""
    from audio2pose_ros.data.importers.lecture import LECTURE_LICENCE

    return {
        "dataset": "talking_heads: 8 GRID clips (Cooke et al. 2006, CC BY 4.0, attribution "
        "required) and 5 Obama weekly-address clips (public domain); lecture: " + LECTURE_LICENCE,
        "trained_on": "HeadYaw and HeadPitch: real head motion (MediaPipe FaceMesh) of people "
        "speaking; arms and hip: real upper-body motion (MediaPipe Pose, retargeted) of one "
        "lecturer, masked where his arms are not visible",
        "default_seed": str(DEFAULT_SEED),
    }


def import_both(
    clips_dir: Path,
    lecture_video: Path,
    work_dir: Path,
    robot: RobotDescription,
    workers: int,
    progress: Callable[[str], None],
) -> tuple[Dataset, Dataset]:
    """Import the talking heads and the lecture, side by side when there are two workers."""
    from audio2pose_ros.data.importers.lecture import import_lecture
    from audio2pose_ros.learning.parallel import report, run_tasks

    step = progress if workers == 1 else report
    heads, lecture = run_tasks(
        [
            partial(import_talking_heads, clips_dir, work_dir / "talking_heads", robot, step),
            partial(import_lecture, lecture_video, work_dir / "lecture", robot, step),
        ],
        min(workers, 2),
    )
    return heads, lecture


def build_learned_default_model(
    clips_dir: Path,
    lecture_video: Path,
    out_dir: Path,
    work_dir: Path,
    robot: RobotDescription,
    settings: LearnedBuildSettings | None = None,
    progress: Callable[[str], None] = print,
    start: Checkpoint | None = None,
) -> DefaultModelResult:
    """Import, train ``live_groups``, evaluate on held-out sources and lecture, write the card.

    The shipped model and one model per held-out talking-head source train side by side
    (:mod:`audio2pose_ros.learning.source_holdout`); the head is scored per held-out source,
    the arms and hip on the lecture's held-out stretch, each against its baselines.

    Args:
        clips_dir: the shared talking-head clips (``../shared/data/talking_heads``).
        lecture_video: ``../shared/data/lecture_video/physicsworks.webm``.
        out_dir: where the checkpoint, MODEL_CARD.md, metrics.txt and figures go.
        work_dir: scratch folder for the data sets (replaced).
        robot: joint order, limits and neutral pose.
        settings: training and evaluation budget.
        progress: receives one line per step.
        start: a pretrained ``live_groups`` checkpoint every training starts from, except a
            fold that holds out a source it learned from
            (:func:`~audio2pose_ros.learning.source_holdout.holdout_tasks`); None = new weights.

    """
    from audio2pose_ros.checkpoints.torch_io import save_checkpoint
    from audio2pose_ros.learning.body_realism import (
        body_realism,
        body_table,
        speech_body_rows,
        speech_body_table,
    )
    from audio2pose_ros.learning.command_path import command_path_table
    from audio2pose_ros.learning.model_card import SourceReport, write_learned_model_card
    from audio2pose_ros.learning.parallel import run_tasks
    from audio2pose_ros.learning.quality import STATIC, quality_evaluation, real_motion_of
    from audio2pose_ros.learning.source_holdout import (
        HEAD_SOURCES,
        LECTURE,
        fold_predictions,
        holdout_tasks,
        recording_source,
    )
    from audio2pose_ros.learning.speech_style import head_style_rows, head_style_table
    from audio2pose_ros.motion.filter_settings import MotionFilterSettings
    from audio2pose_ros.robot.body import BodyModel

    settings = settings or LearnedBuildSettings()
    shutil.rmtree(work_dir, ignore_errors=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    heads, lecture = import_both(
        clips_dir, lecture_video, work_dir, robot, settings.workers, progress
    )
    head_clips = [heads.load(c.clip_id) for c in heads.clips]
    lecture_clips = [lecture.load(c.clip_id) for c in lecture.clips]
    validation = validation_ids(head_clips + [c for c in lecture_clips if c.info.split == "train"])
    train_settings = settings.train_settings(settings.max_epochs)
    tasks = holdout_tasks(
        head_clips + lecture_clips,
        validation,
        robot,
        train_settings,
        settings.samples,
        DEFAULT_SEED,
        start,
    )
    for task in tasks:
        begin = "from the given checkpoint" if task.start is not None else "from new weights"
        progress(
            f"training live_groups ({task.name}, {begin}) on {len(task.training)} clips, "
            "validation "
            f"{sorted(c.info.clip_id for c in task.validation)}; then choosing its sampling "
            "settings on the validation clips (the arms' body budget also on the speech of "
            "its training clips without arms)"
        )
    results = run_tasks(tasks, settings.workers)
    shipped = results[0]
    for result in results:
        progress("  " + result.timing())
    progress("  chosen (shipped): " + shipped.choice.summary())
    checkpoint = replace(
        shipped.checkpoint,
        info={
            **shipped.checkpoint.info,
            **describe_learned_data(),
            PEOPLE_INFO_KEY: json.dumps(dict(shipped.choice.calm)),
        },
    )
    checkpoint_path = out_dir / "default.safetensors"
    save_checkpoint(checkpoint_path, checkpoint)
    folds, folds_paused = fold_predictions(results)
    reports = []
    commands = []  # what the motion filter commands, per held-out source (command_path)
    sample_seeds = range(DEFAULT_SEED, DEFAULT_SEED + settings.samples)
    for source in HEAD_SOURCES:
        progress(f"evaluating the head on {source}, held out, offline and as commanded")
        held = [c for c in head_clips if recording_source(c.info) == source]
        others = [c for c in head_clips if recording_source(c.info) != source]
        baseline = {"real motion of another source": real_motion_of(held, others)}
        fold = next(r for r in results if r.name == source)
        quality = quality_evaluation(
            held,
            {k: {c.info.clip_id: v[c.info.clip_id] for c in held} for k, v in folds.items()}
            | baseline,
            robot,
            out_dir / f"head_{source.lower()}_distributions.png",
            paused={
                k: {c.info.clip_id: v[c.info.clip_id] for c in held}
                for k, v in folds_paused.items()
            },
        )
        reports.append(SourceReport(source, "head", held, quality, fold.choice))
        commands.append(
            command_path_table(
                fold.checkpoint,
                held,
                fold.samples,
                fold.raw,
                "held out",
                sample_seeds,
                f"{source} held out",
            )
        )
    progress("evaluating the arms and hip on the lecture's held-out stretch, also as commanded")
    test = [c for c in lecture_clips if c.info.split == "test"]
    stretches = [c for c in lecture_clips if c.info.split == "train"]
    rule, rule_paused = prosody_predictions(test, robot)
    label = next(iter(folds)).replace("source held out", "shipped")
    arms = quality_evaluation(
        test,
        {label: shipped.samples}
        | rule
        | {"other lecture stretches": real_motion_of(test, stretches)},
        robot,
        out_dir / "arms_distributions.png",
        paused={label: shipped.paused} | rule_paused,
    )
    reports.append(SourceReport(LECTURE, "arms and hip", test, arms, shipped.choice))
    commands.append(
        command_path_table(
            checkpoint,
            test,
            shipped.samples,
            shipped.raw,
            "shipped",
            sample_seeds,
            f"{LECTURE} held out",
        )
    )
    command = "\n\n".join(commands)
    progress("measuring the arms against the body on the lecture's held-out stretch")
    margin = MotionFilterSettings.body_margin_m
    still = {c.info.clip_id: [np.tile(robot.neutral_rad, (c.n_frames, 1))] for c in test}
    body_rows = body_realism(
        test,
        {label: shipped.samples, STATIC: still}
        | {"other lecture stretches": real_motion_of(test, stretches)},
        BodyModel.load(robot),
        margin,
    )
    body = f"arms against the body, {LECTURE} held out (first sample of each clip)\n" + body_table(
        body_rows, margin
    )
    progress("measuring the arms against the body on other speakers' speech")
    seeds = range(DEFAULT_SEED, DEFAULT_SEED + SPEECH_BODY_SEEDS)
    speech_rows = speech_body_rows(
        checkpoint, BodyModel.load(robot), bundled_speech(), seeds, margin
    )
    learned = cast(LiveGroups, checkpoint.model)  # the shipped model is live_groups
    unaware = replace(checkpoint, model=learned.with_sampling(body_band_m=0.0))
    unaware_rows = speech_body_rows(unaware, BodyModel.load(robot), bundled_speech(), seeds, margin)
    body += (
        f"\n\narms against the body on the bundled LibriVox speech (other speakers, in no step "
        f"of the build), seeds {seeds.start}..{seeds.stop - 1}\n"
        + speech_body_table(speech_rows, margin)
        + "\n\nthe same without body-aware sampling (body_band_m = 0: the arm noise ignores "
        "the body)\n" + speech_body_table(unaware_rows, margin)
    )
    progress("measuring how calm the commanded arms are, against the lecturer's")
    calm = calm_table(checkpoint, shipped, test, seeds)
    progress("measuring the head on other speakers' speech")
    style_rows = head_style_rows(
        checkpoint,
        robot,
        bundled_speech(),
        seeds,
        {s: [c for c in head_clips if recording_source(c.info) == s] for s in HEAD_SOURCES},
        f"shipped, LibriVox, seeds {seeds.start}..{seeds.stop - 1}",
    )
    style = head_style_table(
        style_rows, [n for n, m in zip(robot.names, robot.group_mask("head"), strict=True) if m]
    )
    table = "\n\n".join(report.heading() + "\n" + report.quality.table() for report in reports)
    table += "\n\n" + command + "\n\n" + body
    table += "\n\n" + calm
    table += "\n\nthe head on other speakers' speech\n" + style
    selection = "\n\n".join(
        f"sampling settings of the {r.name} model\n" + r.choice.table() for r in results
    )
    (out_dir / "metrics.txt").write_text(table + "\n\n" + selection + "\n", encoding="utf-8")
    card = write_learned_model_card(
        out_dir,
        checkpoint,
        heads,
        lecture,
        reports,
        results,
        body,
        style,
        command,
        calm,
    )
    return DefaultModelResult(checkpoint_path, card, table)
