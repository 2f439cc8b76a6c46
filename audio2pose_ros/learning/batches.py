"""Training data: clips to utterances, the validation hold-out, batch windows.

Seed 003 section 4.3.3: each utterance pairs z-normalised features with joint angles normalised
to [0, 1] (eq. 3.14) and a mask for the joints a recording does not show.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.errors import InputError
from audio2pose_ros.robot.description import RobotDescription

HOLDOUTS = ("clip", "speaker")


class TrainingError(InputError):
    """Training cannot start or resume: empty splits, unknown speaker, mismatched state."""


@dataclass(frozen=True)
class Utterance:
    """One training clip, frame-aligned at the feature rate.

    Attributes:
        name: clip identifier (used for utterance-level splits).
        features: (T, n_features) z-normalised audio features.
        targets: (T, n_joints) joint angles normalised to [0, 1].
        mask: (T, n_joints) True where the target is known.

    """

    name: str
    features: np.ndarray
    targets: np.ndarray
    mask: np.ndarray

    def __post_init__(self) -> None:
        """Check that the arrays are frame-aligned."""
        n = self.features.shape[0]
        if self.targets.shape[0] != n or self.mask.shape != self.targets.shape:
            raise ValueError(
                f"utterance {self.name}: features {self.features.shape}, targets "
                f"{self.targets.shape} and mask {self.mask.shape} are not frame-aligned"
            )


def windows(
    utterances: Sequence[Utterance], length: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Cut utterances into non-overlapping windows (last one right-aligned, short ones padded)."""
    feats, targets, masks = [], [], []
    for utt in utterances:
        n = utt.features.shape[0]
        if n < length:
            pad = length - n
            feats.append(np.pad(utt.features, ((0, pad), (0, 0))))
            targets.append(np.pad(utt.targets, ((0, pad), (0, 0))))
            masks.append(np.pad(utt.mask, ((0, pad), (0, 0))))
            continue
        starts = list(range(0, n - length + 1, length))
        if starts[-1] != n - length:
            starts.append(n - length)
        for s in starts:
            feats.append(utt.features[s : s + length])
            targets.append(utt.targets[s : s + length])
            masks.append(utt.mask[s : s + length])
    return (
        torch.tensor(np.stack(feats), dtype=torch.float32),
        torch.tensor(np.stack(targets), dtype=torch.float32),
        torch.tensor(np.stack(masks), dtype=torch.bool),
    )


def utterance_tensors(utt: Utterance) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One utterance as a batch of one: (1, T, F) features, (1, T, J) targets and mask."""
    return (
        torch.tensor(utt.features[None], dtype=torch.float32),
        torch.tensor(utt.targets[None], dtype=torch.float32),
        torch.tensor(utt.mask[None]),
    )


def clip_utterance(
    clip: Clip, spec: FeatureSpec, normalizer: FeatureNormalizer, robot: RobotDescription
) -> Utterance:
    """Features, targets in [0, 1] (eq. 3.14, clamped to the limits) and mask of one clip.

    Features and motion are cut to the shorter of the two; unknown angles become 0.5 (masked).
    """
    features = normalizer.apply(extract_features(clip.audio, spec))
    n = min(features.shape[0], clip.n_frames)
    known = clip.mask[:n]
    targets = np.where(
        known, np.clip(robot.normalize(np.nan_to_num(clip.angles_rad[:n])), 0, 1), 0.5
    )
    return Utterance(clip.info.clip_id, features[:n], targets, known.copy())


@dataclass
class TrainingData:
    """Utterances of both splits and the feature normaliser fitted on the training clips."""

    train: list[Utterance]
    validation: list[Utterance]
    normalizer: FeatureNormalizer
    speakers: list[str]


def hold_out(
    clips: list[Clip], fraction: float, holdout: str, seed: int
) -> tuple[list[Clip], list[Clip]]:
    """Split training clips into train and validation, by clip or by whole speakers."""
    rng = np.random.default_rng(seed)
    if holdout == "speaker":
        speakers = sorted({c.info.speaker for c in clips})
        if len(speakers) < 2:
            raise TrainingError("holding out by speaker needs training clips of two speakers")
        count = min(len(speakers) - 1, max(1, round(fraction * len(speakers))))
        held = set(rng.permutation(speakers)[:count].tolist())
        return [c for c in clips if c.info.speaker not in held], [
            c for c in clips if c.info.speaker in held
        ]
    if len(clips) < 2:
        raise TrainingError("need two training clips to hold one out for validation")
    count = min(len(clips) - 1, max(1, round(fraction * len(clips))))
    held_idx = set(rng.permutation(len(clips))[:count].tolist())
    return [c for i, c in enumerate(clips) if i not in held_idx], [
        c for i, c in enumerate(clips) if i in held_idx
    ]


def prepare_training_data(
    dataset: Dataset,
    robot: RobotDescription,
    spec: FeatureSpec,
    speaker: str | None = None,
    validation_fraction: float = 0.2,
    holdout: str = "clip",
    seed: int = 0,
) -> TrainingData:
    """Read the training and validation utterances of a data set.

    Validation is the data set's 'validation' split (of ``speaker`` if given); without one, a
    ``validation_fraction`` of the training clips is held out, by clip or by speaker
    (subject-independent validation). The normaliser is fitted on the training clips: on one
    speaker's clips when ``speaker`` is given (per-speaker z-normalisation, seed 003 section
    3.2 step 8), else on all speakers together.

    Raises:
        TrainingError: unknown speaker, unknown holdout, or no clips to train on.

    """
    if holdout not in HOLDOUTS:
        raise TrainingError(f"holdout {holdout!r} not in {HOLDOUTS}")
    if speaker is not None and speaker not in dataset.speakers:
        raise TrainingError(f"{dataset.root}: no speaker {speaker!r}; has {dataset.speakers}")

    def of_speaker(split: str) -> list[Clip]:
        return [c for c in dataset.iter_split(split) if speaker in (None, c.info.speaker)]

    train_clips, val_clips = of_speaker("train"), of_speaker("validation")
    if not train_clips:
        raise TrainingError(
            f"{dataset.root}: no training clips" + (f" of {speaker}" * bool(speaker))
        )
    if not val_clips:
        train_clips, val_clips = hold_out(train_clips, validation_fraction, holdout, seed)
    return training_data_from_clips(train_clips, val_clips, robot, spec)


def training_data_from_clips(
    train_clips: Sequence[Clip],
    val_clips: Sequence[Clip],
    robot: RobotDescription,
    spec: FeatureSpec,
) -> TrainingData:
    """Utterances of given training and validation clips, normalised by the training clips.

    Raises:
        TrainingError: no joint angle of the training clips, or (when there are validation
            clips) of the validation clips, is observed: the loss over nothing observed is 0,
            which would read as a perfect fit of an untrained model.
    """
    normalizer = FeatureNormalizer.fit(
        np.concatenate([extract_features(c.audio, spec) for c in train_clips])
    )
    data = TrainingData(
        train=[clip_utterance(c, spec, normalizer, robot) for c in train_clips],
        validation=[clip_utterance(c, spec, normalizer, robot) for c in val_clips],
        normalizer=normalizer,
        speakers=sorted({c.info.speaker for c in train_clips}),
    )
    for split, utterances in (("training", data.train), ("validation", data.validation)):
        if utterances and not any(u.mask.any() for u in utterances):
            names = ", ".join(u.name for u in utterances[:3]) + ", ..." * (len(utterances) > 3)
            raise TrainingError(f"no joint angle is observed in the {split} clips ({names})")
    return data
