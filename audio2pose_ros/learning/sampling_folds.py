"""The sampling choice's evidence: models trained without the speakers they are scored on.

:func:`speaker_folds` deals the training speakers into folds; :func:`cross_validated` trains one
model per fold (:func:`cross_validation_tasks`: the same trainings, not yet run, for a pool of
processes), each to be scored by :func:`~audio2pose_ros.learning.sampler_selection.choose_sampling`
on the speakers it did not see. :class:`FoldTuner` is the ``tune`` of a leave-one-speaker-out
evaluation: each fold's sampling settings chosen on that fold's training speakers only.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning.sampler_selection import Fold, apply_sampling, choose_sampling
from audio2pose_ros.learning.train_state import TrainReport
from audio2pose_ros.learning.training import TrainSettings, train_on_clips
from audio2pose_ros.robot.description import RobotDescription

__all__ = ["INNER_FOLDS", "FoldTuner", "cross_validated", "cross_validation_tasks", "speaker_folds"]

INNER_FOLDS = 3


def speaker_folds(
    clips: Sequence[Clip], k: int = INNER_FOLDS
) -> list[tuple[list[Clip], list[Clip]]]:
    """Split clips by speaker into ``k`` (training, validation) pairs; each speaker validates once.

    Speakers are sorted and dealt round-robin, so the split is the same on every rebuild.
    Fewer speakers than ``k`` give one fold per speaker; a single speaker gives no fold.
    """
    speakers = sorted({c.info.speaker for c in clips})
    if len(speakers) < 2:
        return []
    k = min(k, len(speakers))
    folds = []
    for i in range(k):
        held = set(speakers[i::k])
        folds.append(
            (
                [c for c in clips if c.info.speaker not in held],
                [c for c in clips if c.info.speaker in held],
            )
        )
    return folds


def cross_validation_tasks(
    model_name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    settings: TrainSettings,
    k: int = INNER_FOLDS,
    progress: Callable[[str], None] | None = None,
) -> tuple[list[Callable[[], tuple[Checkpoint, TrainReport]]], list[list[Clip]]]:
    """The trainings of :func:`cross_validated`, not yet run, and each one's validation clips.

    Each model stops early on the speakers it is then scored on (its validation speakers), so
    it uses all its other speakers for training. The trainings are picklable, for
    :func:`~audio2pose_ros.learning.parallel.run_tasks`.
    """
    pairs = speaker_folds(clips, k)
    if progress is not None:
        for i, (_, validation) in enumerate(pairs):
            speakers = sorted({c.info.speaker for c in validation})
            progress(f"  validation model {i + 1}/{len(pairs)} (without {', '.join(speakers)})")
    tasks: list[Callable[[], tuple[Checkpoint, TrainReport]]] = [
        partial(train_on_clips, model_name, training, robot, settings, None, validation)
        for training, validation in pairs
    ]
    return tasks, [validation for _, validation in pairs]


def cross_validated(
    model_name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    settings: TrainSettings,
    k: int = INNER_FOLDS,
    progress: Callable[[str], None] | None = None,
) -> list[Fold]:
    """Train one model per :func:`speaker_folds` pair, in order; each with its unseen speakers."""
    tasks, held = cross_validation_tasks(model_name, clips, robot, settings, k, progress)
    return [(task()[0], validation) for task, validation in zip(tasks, held, strict=True)]


@dataclass(frozen=True)
class FoldTuner:
    """The ``tune`` of a leave-one-speaker-out evaluation for ``live_groups`` (picklable).

    Each fold's settings are chosen by :func:`cross_validated` over that fold's training
    speakers only (the held-out speaker is never seen), so the reported numbers measure the
    whole procedure; the choice's summary is noted in the tuned checkpoint's info as
    ``sampling_choice``. Other models pass unchanged.

    Attributes:
        robot: joint order and groups.
        settings: training settings of the cross-validation models.
        verbose: print one line per step to standard error.

    """

    robot: RobotDescription
    settings: TrainSettings
    verbose: bool = False

    def __call__(self, fold: Checkpoint, training: list[Clip]) -> Checkpoint:
        """The fold's checkpoint with the settings chosen on its training speakers."""
        if fold.model.name != "live_groups":
            return fold
        from audio2pose_ros.learning.parallel import report

        progress = report if self.verbose else None
        inner = cross_validated(
            "live_groups", training, self.robot, self.settings, progress=progress
        )
        choice = choose_sampling(inner, self.robot)
        if progress is not None:
            progress("  chosen: " + choice.summary())
        tuned = apply_sampling(fold, choice)
        return replace(tuned, info={**tuned.info, "sampling_choice": choice.summary()})
