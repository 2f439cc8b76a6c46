"""Hold out whole recording sources: models that never saw a source, scored on it.

A model scored on speakers of the recordings it was trained on (the same camera, the same kind
of speech, settings tuned on look-alikes) does not say how it does on new recordings. So the
default model's rebuild (:mod:`audio2pose_ros.learning.default_model`) scores the head on each
talking-head **source** it holds out whole: all GRID clips (:data:`GRID`), or all Obama clips
(:data:`OBAMA`). Each fold trains ``live_groups`` on the other sources (the other head source and
the lecture's training stretches), stops early and chooses its sampling settings
(:func:`~audio2pose_ros.learning.sampler_selection.choose_sampling`) on validation clips of its
training sources only, and samples the held-out source's clips. The lecture (:data:`LECTURE`)
is the only recording with arms: its held-out stretch (``TEST_SPAN_S`` of
:mod:`~audio2pose_ros.data.importers.lecture`) is scored with the shipped model, which never
trained on it, and whose arm settings were chosen on another stretch of the same lecture.

**Whose head motion the sampling settings aim at.** GRID's speakers read short prompted command
sentences to a camera and hold their heads four to five times stiller than Obama addressing his
audience (standard deviation 0.3 to 1.6 degrees per clip against 1.3 to 5.5). Neither is the
style of a person the robot has never seen: no model can guess a new speaker's style from the
voice, so the default aims between them. The head's measures are taken against each source's
validation clips apart (:func:`clip_style`) and combined
(:func:`~audio2pose_ros.learning.sampler_selection.between_styles`): the size term is least for
a head sized at the geometric mean of the sources' sizes. The choice also asks the head's speed
and acceleration percentiles (p50, p90, p99) to be the geometric mean over the sources of their
real motion's, each pooled over all its training and validation clips (the ``tail`` term of
:func:`~audio2pose_ros.learning.sampler_selection.score`): a validation clip of a few seconds
holds too few quick nods to judge them, and the Hellinger distance on 0.1 rad/s bins does not
see them. A task whose only head source is one of them (a fold that holds the other out) aims
at that one.

Every fold (and the shipped model) is one :class:`HoldoutTask`: train, choose, sample, in one
picklable call, so the folds run side by side (:func:`~audio2pose_ros.learning.parallel.run_tasks`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip, ClipInfo
from audio2pose_ros.learning.quality import Predictions, with_pause
from audio2pose_ros.learning.sampler_selection import (
    SamplingChoice,
    apply_sampling,
    choose_sampling,
)
from audio2pose_ros.learning.train_state import TrainReport
from audio2pose_ros.learning.training import TrainSettings, train_on_clips
from audio2pose_ros.offline.synthesis import sample_poses, synthesize_samples, to_angles
from audio2pose_ros.robot.description import RobotDescription

GRID, OBAMA, LECTURE = "GRID", "Obama", "lecture"
HEAD_SOURCES = (GRID, OBAMA)
SHIPPED = "shipped"
MODEL_NAME = "live_groups"


def speaker_source(speaker: str) -> str | None:
    """The recording source of a speaker of the default model's data; None for another."""
    from audio2pose_ros.data.importers.lecture import LECTURE_SPEAKER

    if speaker == LECTURE_SPEAKER:
        return LECTURE
    if speaker == "obama":
        return OBAMA
    if speaker.startswith("grid"):
        return GRID
    return None


def recording_source(info: ClipInfo) -> str:
    """The recording source of a clip of the default model's data (by its speaker).

    Raises:
        ValueError: a speaker of none of the sources.

    """
    source = speaker_source(info.speaker)
    if source is None:
        raise ValueError(f"clip {info.clip_id}: speaker {info.speaker!r} of no known source")
    return source


def clip_style(clip: Clip) -> str:
    """The style a clip shows: its recording source, or its speaker for a speaker of none."""
    return speaker_source(clip.info.speaker) or clip.info.speaker


@dataclass(frozen=True)
class HoldoutResult:
    """What one :class:`HoldoutTask` produced.

    Attributes:
        name: :data:`SHIPPED` or the held-out source.
        checkpoint: the trained model with its chosen sampling settings.
        report: its training report.
        choice: the sampling choice (on the task's validation clips).
        samples: clip id -> the model's samples of each scored clip (offline synthesis).
        raw: clip id -> the same samples unsmoothed: the poses the inference node sends, which
            the motion filter's tables (:mod:`~audio2pose_ros.learning.command_path`) command.
        paused: clip id -> its samples on the clip's audio with a pause inserted.
        seconds: wall-clock seconds of each step (``train``, ``choose``, ``sample``), for the
            rebuild's progress lines.

    """

    name: str
    checkpoint: Checkpoint
    report: TrainReport
    choice: SamplingChoice
    samples: dict[str, list[np.ndarray]]
    raw: dict[str, list[np.ndarray]]
    paused: dict[str, list[np.ndarray]]
    seconds: dict[str, float] = field(default_factory=dict)

    def timing(self) -> str:
        """One line: how long each step of the task took."""
        steps = ", ".join(f"{step} {s:.0f} s" for step, s in self.seconds.items())
        return f"{self.name}: {steps} ({self.report.best_epoch + 1} epochs to the best)"


@dataclass(frozen=True)
class HoldoutTask:
    """Train ``live_groups``, choose its sampling settings, sample the scored clips.

    A picklable callable for :func:`~audio2pose_ros.learning.parallel.run_tasks`.

    Attributes:
        name: :data:`SHIPPED` or the held-out source.
        training: the clips it trains on.
        validation: early stopping and the sampling choice (never scored clips; each
            :func:`clip_style` apart for the head); the audio of the training clips that do not
            label the arms also counts for the arms' body budget, and the real motion of the
            training and validation clips together sets the head's percentile targets (the
            ``tail`` term of the choice's score, between the styles) and the arms' calm budget.
        scored: clips to sample (the held-out source's, or the lecture's test stretch).
        robot: joint order and limits.
        settings: training settings.
        n_samples: samples per scored clip (seeds ``seed`` .. ``seed + n_samples - 1``).
        seed: first sampling seed.
        start: a pretrained ``live_groups`` checkpoint to train from (None = new weights).

    """

    name: str
    training: tuple[Clip, ...]
    validation: tuple[Clip, ...]
    scored: tuple[Clip, ...]
    robot: RobotDescription
    settings: TrainSettings
    n_samples: int
    seed: int
    start: Checkpoint | None = None

    def __call__(self) -> HoldoutResult:
        """Run the task."""
        start = time.perf_counter()
        checkpoint, report = train_on_clips(
            MODEL_NAME,
            self.training,
            self.robot,
            self.settings,
            None,
            self.validation,
            self.start,
        )
        seconds = {"train": time.perf_counter() - start}
        start = time.perf_counter()
        arms = self.robot.group_mask("arms")
        unlabelled = [c.audio for c in self.training if not c.mask[:, arms].any()]
        choice = choose_sampling(
            [(checkpoint, self.validation)],
            self.robot,
            body_audio=unlabelled,
            reference=self.training + self.validation,
            style_of=clip_style,
        )
        checkpoint = apply_sampling(checkpoint, choice)
        seconds["choose"] = time.perf_counter() - start
        start = time.perf_counter()
        seeds = range(self.seed, self.seed + self.n_samples)
        poses = {c.info.clip_id: sample_poses(checkpoint, c.audio, seeds) for c in self.scored}
        paused = {
            c.info.clip_id: synthesize_samples(checkpoint, with_pause(c.audio), seeds)
            for c in self.scored
        }
        seconds["sample"] = time.perf_counter() - start
        return HoldoutResult(
            self.name,
            checkpoint,
            report,
            choice,
            {i: [to_angles(checkpoint, p) for p in ps] for i, ps in poses.items()},
            {i: [to_angles(checkpoint, p, smooth=False) for p in ps] for i, ps in poses.items()},
            paused,
            seconds,
        )


def split_training(
    clips: Sequence[Clip],
    validation_ids: set[str],
    held_out: Callable[[ClipInfo], bool] = lambda info: False,
) -> tuple[tuple[Clip, ...], tuple[Clip, ...]]:
    """(training, validation) of the build, without the clips ``held_out`` names.

    The lecture's held-out stretch (split 'test') is never trained on; of the rest, the clips of
    ``validation_ids`` stop the training early and the others train. A fold that holds out a
    source or a speaker trains as the shipped model does on what is left.
    """
    usable = [c for c in clips if c.info.split != "test" and not held_out(c.info)]
    return (
        tuple(c for c in usable if c.info.clip_id not in validation_ids),
        tuple(c for c in usable if c.info.clip_id in validation_ids),
    )


def holdout_tasks(
    clips: Sequence[Clip],
    validation_ids: set[str],
    robot: RobotDescription,
    settings: TrainSettings,
    n_samples: int,
    seed: int,
    start: Checkpoint | None = None,
) -> list[HoldoutTask]:
    """The shipped model's task, then one per held-out head source (:data:`HEAD_SOURCES`).

    With a pretrained ``start``, every task trains from it except a fold that holds out a
    source ``start`` learned from (:func:`learned_sources`): that fold would otherwise be
    scored on recordings its weights have seen, so it starts from new weights.

    Args:
        clips: every clip: the talking heads and all lecture stretches (split 'test' = the
            lecture's held-out stretch, never trained on).
        validation_ids: the shipped model's validation clips; a fold keeps those of its
            training sources.
        robot: joint order and limits.
        settings: training settings.
        n_samples: samples per scored clip.
        seed: first sampling seed.
        start: a pretrained ``live_groups`` checkpoint (None = every task from new weights).

    """
    seen = learned_sources(start) if start is not None else frozenset()
    lecture_test = tuple(c for c in clips if c.info.split == "test")
    tasks = [
        HoldoutTask(
            SHIPPED,
            *split_training(clips, validation_ids),
            lecture_test,
            robot,
            settings,
            n_samples,
            seed,
            start,
        )
    ]
    for source in HEAD_SOURCES:

        def of_source(info: ClipInfo, source: str = source) -> bool:
            return recording_source(info) == source

        tasks.append(
            HoldoutTask(
                source,
                *split_training(clips, validation_ids, of_source),
                tuple(c for c in clips if of_source(c.info)),
                robot,
                settings,
                n_samples,
                seed,
                None if source in seen else start,
            )
        )
    return tasks


def learned_sources(checkpoint: Checkpoint) -> frozenset[str]:
    """The recording sources of the speakers a checkpoint learned from (its ``speakers``).

    A checkpoint started from another (``started_from``) learned from that one's speakers too.
    Speakers of no known source (:func:`speaker_source`) count as their own source.
    """
    speakers: set[str] = set()
    info: Any = checkpoint.info
    while isinstance(info, dict):
        speakers.update(str(s) for s in info.get("speakers", []))
        info = info.get("started_from")
    return frozenset(speaker_source(speaker) or speaker for speaker in speakers)


def fold_predictions(results: Sequence[HoldoutResult]) -> tuple[Predictions, Predictions]:
    """The folds' samples as one method (each clip sampled by the fold that held it out)."""
    label = f"{MODEL_NAME} (source held out)"
    samples: Predictions = {label: {}}
    paused: Predictions = {label: {}}
    for result in results:
        if result.name != SHIPPED:
            samples[label] |= result.samples
            paused[label] |= result.paused
    return samples, paused
