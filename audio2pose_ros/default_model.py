"""Rebuild the default model from the shared talking-head clips, end to end.

Steps: import the 13 clips (:mod:`audio2pose_ros.importers.video`: real speech, real head
motion; arms and hip masked, as they are not visible), split them by clip (one GRID speaker and
one Obama clip held out for test, one of each for validation), fill the masked arm and hip
joints of the training copy with the labelled procedural prosody rule
(:mod:`audio2pose_ros.motion.prosody`), train one streaming MLP (seed 003 section 4.3.3) on all 11
joints, and evaluate it on the held-out clips against the static, mean-motion and
mismatched-motion baselines (:mod:`audio2pose_ros.evaluation`; only the head has ground truth
there). The result is one checkpoint, as ``inference_node`` expects: its head is learned from
people, its arms and hip imitate the procedural rule, and the model card says so. With
``arms="neutral"`` the arms and hip are trained to stay at the neutral pose instead.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.importers.extras import save_extras
from audio2pose_ros.importers.video import import_video
from audio2pose_ros.motion.prosody import prosody_trajectory
from audio2pose_ros.robot import RobotDescription

GRID_LICENCE = (
    "CC BY 4.0; GRID audio-visual sentence corpus, Cooke, Barker, Cunningham and Shao (2006), "
    "JASA 120(5)"
)
OBAMA_LICENCE = "public domain (work of the US federal government: weekly address)"
TEST_CLIPS = ("grid_sbwe5n", "obama_weekly_address_21")  # one unseen GRID speaker, one Obama clip
VALIDATION_CLIPS = ("grid_lrwp9a", "obama_weekly_address_13")
ARM_MODES = ("prosody", "neutral")


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
    """Import every ``*.mpg`` / ``*.mp4`` of the shared folder into a new data set."""
    dataset = Dataset.create(dataset_dir, robot)
    for path in sorted([*clips_dir.glob("*.mpg"), *clips_dir.glob("*.mp4")]):
        progress(f"importing {path.name}")
        clip, extras = import_video(path, clip_info(path), robot)
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
    from audio2pose_ros.default_model_card import write_default_model_card
    from audio2pose_ros.evaluation import evaluate
    from audio2pose_ros.models.checkpoint import save_checkpoint
    from audio2pose_ros.training import TrainSettings, state_path_for, train_from_dataset

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
