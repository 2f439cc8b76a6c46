"""Choose a ``live_groups`` model's sampling settings on validation clips (issue 13).

The part temperatures and the speech gate's rest level of
:class:`~audio2pose_ros.models.live_groups.LiveGroups` act only when sampling
(:data:`~audio2pose_ros.models.live_groups.SAMPLING_SETTINGS`), so they are chosen after
training, on clips the deciding models were not trained on and that are never the reported
test clips. The evidence is a list of :data:`Fold` s, each a trained checkpoint with clips it did
not see; `make default-model` (:mod:`audio2pose_ros.learning.default_model`) uses, for the head,
:func:`cross_validated` models over the training speakers (each speaker's clips predicted by a
model trained without that speaker; the same again inside every leave-one-speaker-out fold, on
that fold's training speakers only) and, for the arms, the shipped model on its validation
stretch of the lecture.

1. Temperatures. Both parts sample at each temperature of :data:`TEMPERATURES`, with
   :data:`N_SEEDS` seeds; per joint group, the samples' motion on every fold's clips that
   observe the group is compared with the real motion (pooled over the seeds and folds:
   :func:`~audio2pose_ros.learning.metrics.sum_segments`) by :func:`score`, which adds the mean
   of the Hellinger distances of speed and acceleration to how far the motion's size is from
   real, ``|ln(std ratio)|``. Each part keeps the temperature with the lowest score, averaged
   over its joint groups weighted by their joint counts; a part whose joints no clip observes
   keeps its configured temperature.
2. Rest level in silence. With those temperatures, every rest level of
   :data:`SILENCE_TEMPERATURES`, from the most noise left in silence to the least, samples the
   same clips' audio with a pause inserted
   (:func:`~audio2pose_ros.learning.evaluation.with_pause`); the first whose speech / pause
   speed ratio reaches :data:`PAUSE_MARGIN` times issue 13's target (:data:`PAUSE_TARGETS`) in
   every scored group is kept (the lowest one if none does): as lively in silence as the "come
   to rest" target allows, with a margin.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning import metrics
from audio2pose_ros.learning.training import TrainSettings, train_on_clips
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ

TEMPERATURES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)
SILENCE_TEMPERATURES = (0.3, 0.2, 0.1, 0.05, 0.02)  # most noise left in silence first
PAUSE_TARGETS = {"head": 2.0, "arms": 1.5, "hip": 1.5}  # issue 13: speech / silence speed
PAUSE_MARGIN = 1.25
N_SEEDS = 4
INNER_FOLDS = 3
GROUPS = ("head", "arms", "hip")
_PART_SETTINGS = ("first_temperature", "second_temperature")

Fold = tuple[Checkpoint, Sequence[Clip]]  # a trained checkpoint and clips it was not trained on


def score(measures: dict[str, float]) -> float:
    """Distance of generated from real motion: mean(H speed, H accel) + |ln(std ratio)|."""
    ratio = measures["std ratio"]
    size = abs(math.log(ratio)) if ratio > 0 else math.inf
    return 0.5 * (measures["H speed"] + measures["H accel"]) + size


@dataclass(frozen=True)
class Trial:
    """One setting tried on one joint group: its measures on the validation clips."""

    setting: str
    value: float
    group: str
    measures: dict[str, float]


@dataclass(frozen=True)
class SamplingChoice:
    """The chosen sampling settings, every trial, and the validation clips they were chosen on.

    Attributes:
        settings: chosen :data:`~audio2pose_ros.models.live_groups.SAMPLING_SETTINGS`.
        trials: every setting tried, per joint group.
        validation: ids of the clips the choice was made on.
        seconds: their length.
        n_models: how many trained models predicted them.

    """

    settings: dict[str, float]
    trials: tuple[Trial, ...]
    validation: tuple[str, ...]
    seconds: float = 0.0
    n_models: int = 0

    def summary(self) -> str:
        """One line: the chosen values and what they were chosen on."""
        chosen = ", ".join(f"{k} = {v:g}" for k, v in self.settings.items()) or "nothing"
        return (
            f"{chosen} (on {len(self.validation)} validation clips, {self.seconds:.0f} s, "
            f"predicted by {self.n_models} model(s), {N_SEEDS} samples each)"
        )

    def table(self) -> str:
        """Plain text: the summary, then one line per trial, the chosen values marked ``*``."""
        lines = [
            self.summary(),
            f"{'setting':<21}{'value':>6}  {'group':<6}{'H speed':>8}{'H accel':>8}"
            f"{'std/real':>9}{'score':>7}{'speech/pause':>13}",
        ]
        for t in self.trials:
            chosen = "*" if self.settings.get(t.setting) == t.value else " "
            m = t.measures
            lines.append(
                f"{t.setting:<21}{t.value:>6g}{chosen} {t.group:<6}"
                + "".join(
                    f"{m[k]:>{w}.2f}" if k in m else f"{'-':>{w}}"
                    for k, w in (("H speed", 8), ("H accel", 8), ("std ratio", 9))
                )
                + (f"{score(m):>7.2f}" if "std ratio" in m else f"{'-':>7}")
                + (f"{m['speech/pause speed']:>13.2f}" if "speech/pause speed" in m else "")
            )
        return "\n".join(lines)


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


def cross_validated(
    model_name: str,
    clips: Sequence[Clip],
    robot: RobotDescription,
    settings: TrainSettings,
    k: int = INNER_FOLDS,
    progress: Callable[[str], None] | None = None,
) -> list[Fold]:
    """Train one model per :func:`speaker_folds` pair; each with the speakers it did not see.

    Each model stops early on the speakers it is then scored on (its validation speakers), so
    it uses all its other speakers for training.
    """
    pairs = speaker_folds(clips, k)
    folds: list[Fold] = []
    for i, (training, validation) in enumerate(pairs):
        if progress is not None:
            speakers = sorted({c.info.speaker for c in validation})
            progress(f"  validation model {i + 1}/{len(pairs)} (without {', '.join(speakers)})")
        checkpoint, _ = train_on_clips(model_name, training, robot, settings, validation=validation)
        folds.append((checkpoint, validation))
    return folds


def _observed(robot: RobotDescription, clips: Sequence[Clip]) -> list[str]:
    return [
        g
        for g in GROUPS
        if robot.group_mask(g).any() and any(c.mask[:, robot.group_mask(g)].any() for c in clips)
    ]


def _part_groups(
    model: LiveGroups, robot: RobotDescription, groups: Sequence[str]
) -> dict[str, list[str]]:
    """Part setting name -> its joint groups among ``groups``."""
    parts: dict[str, list[str]] = {}
    for setting, joints in zip(_PART_SETTINGS, model.groups, strict=True):
        inside = np.zeros(robot.n_joints, bool)
        inside[joints] = True
        parts[setting] = [g for g in groups if not (robot.group_mask(g) & ~inside).any()]
    return parts


def _measures(
    folds: Sequence[Fold],
    settings: dict[str, float],
    robot: RobotDescription,
    n_seeds: int,
    paused: bool,
) -> dict[str, dict[str, float]]:
    """Group -> measures of every fold's samples (seeds 0 .. n - 1) on its clips, pooled."""
    from audio2pose_ros.learning.evaluation import with_pause
    from audio2pose_ros.offline.synthesis import synthesize

    real: dict[str, list[metrics.MotionSegments]] = {}
    generated: dict[str, list[metrics.MotionSegments]] = {}
    for checkpoint, clips in folds:
        model = cast(LiveGroups, checkpoint.model)  # choose_sampling keeps live_groups folds only
        candidate = replace(checkpoint, model=model.with_sampling(**settings))
        groups = _observed(robot, clips)
        for clip in clips:
            audio = with_pause(clip.audio) if paused else clip.audio
            samples = [synthesize(candidate, audio, seed=s)[1] for s in range(n_seeds)]
            n = samples[0].shape[0] if paused else min(samples[0].shape[0], clip.n_frames)
            speech = metrics.energy_vad(audio, n)
            for g in groups:
                joints = robot.group_mask(g)
                known = np.ones((n, int(joints.sum())), bool) if paused else clip.mask[:n, joints]
                if not known.any():
                    continue
                generated.setdefault(g, []).append(
                    metrics.sum_segments(
                        [
                            metrics.segment_statistics(m[:n, joints], known, speech, FRAME_RATE_HZ)
                            for m in samples
                        ]
                    )
                )
                if not paused:
                    true = np.nan_to_num(clip.angles_rad[:n, joints])
                    real.setdefault(g, []).append(
                        metrics.segment_statistics(true, known, speech, FRAME_RATE_HZ)
                    )
    out = {}
    for g, parts in generated.items():
        gen = metrics.concat_segments(parts)
        if paused:
            ratio = metrics.distribution_measures(gen, gen)["speech/silence speed"]
            out[g] = {"speech/pause speed": ratio}
        else:
            out[g] = metrics.distribution_measures(metrics.concat_segments(real[g]), gen)
    return out


def choose_sampling(
    folds: Sequence[Fold], robot: RobotDescription, n_seeds: int = N_SEEDS
) -> SamplingChoice:
    """Choose the sampling settings on the folds' clips (see the module docstring).

    Args:
        folds: trained ``live_groups`` checkpoints, each with clips it was not trained on;
            folds of other models are ignored.
        robot: joint order and groups.
        n_seeds: samples per clip and setting.

    """
    folds = [(c, v) for c, v in folds if isinstance(c.model, LiveGroups) and v]
    clips = [clip for _, v in folds for clip in v]
    names = tuple(c.info.clip_id for c in clips)
    seconds = sum(c.n_frames for c in clips) / FRAME_RATE_HZ
    groups = _observed(robot, clips)
    if not groups:
        return SamplingChoice({}, (), names, seconds, len(folds))
    first = cast(LiveGroups, folds[0][0].model)  # only LiveGroups folds are kept above
    parts = {
        setting: part_groups
        for setting, part_groups in _part_groups(first, robot, groups).items()
        if part_groups
    }
    trials: list[Trial] = []
    per_value = {}
    for value in TEMPERATURES:
        per_value[value] = _measures(folds, dict.fromkeys(parts, value), robot, n_seeds, False)
        trials += [
            Trial(s, value, g, per_value[value][g]) for s, part in parts.items() for g in part
        ]
    chosen: dict[str, float] = {}
    for setting, part in parts.items():
        weights = [int(robot.group_mask(g).sum()) for g in part]

        def weighted(v: float, part: list[str] = part, weights: list[int] = weights) -> float:
            return np.average([score(per_value[v][g]) for g in part], weights=weights)

        chosen[setting] = min(TEMPERATURES, key=weighted)
    for rest in SILENCE_TEMPERATURES:
        settings = {**chosen, "silence_temperature": rest}
        ratios = _measures(folds, settings, robot, n_seeds, True)
        trials += [Trial("silence_temperature", rest, g, ratios[g]) for g in groups]
        chosen["silence_temperature"] = rest
        if all(ratios[g]["speech/pause speed"] >= PAUSE_MARGIN * PAUSE_TARGETS[g] for g in groups):
            break
    return SamplingChoice(chosen, tuple(trials), names, seconds, len(folds))


def apply_sampling(checkpoint: Checkpoint, choice: SamplingChoice) -> Checkpoint:
    """The checkpoint with the chosen settings (same weights), the choice noted in its info.

    Checkpoints of other models, or an empty choice, are returned unchanged.
    """
    model = checkpoint.model
    if not isinstance(model, LiveGroups) or not choice.settings:
        return checkpoint
    info = {**checkpoint.info, "sampling_chosen_on": list(choice.validation)}
    return replace(checkpoint, model=model.with_sampling(**choice.settings), info=info)


def select_sampling(
    checkpoint: Checkpoint,
    validation: Sequence[Clip],
    robot: RobotDescription,
    n_seeds: int = N_SEEDS,
) -> tuple[Checkpoint, SamplingChoice]:
    """Choose on one checkpoint's validation clips and apply: (tuned checkpoint, choice)."""
    choice = choose_sampling([(checkpoint, validation)], robot, n_seeds)
    return apply_sampling(checkpoint, choice), choice


def fold_tuner(
    robot: RobotDescription,
    settings: TrainSettings,
    progress: Callable[[str], None] | None = None,
    choices: list[SamplingChoice] | None = None,
) -> Callable[[Checkpoint, list[Clip]], Checkpoint]:
    """The ``tune`` of a leave-one-speaker-out evaluation for ``live_groups``.

    Each fold's settings are chosen by :func:`cross_validated` over that fold's training
    speakers only (the held-out speaker is never seen), so the reported numbers measure the
    whole procedure. Other models pass unchanged. Each choice is appended to ``choices``.
    """

    def tune(fold: Checkpoint, training: list[Clip]) -> Checkpoint:
        if fold.model.name != "live_groups":
            return fold
        inner = cross_validated("live_groups", training, robot, settings, progress=progress)
        choice = choose_sampling(inner, robot)
        if choices is not None:
            choices.append(choice)
        if progress is not None:
            progress("  chosen: " + choice.summary())
        return apply_sampling(fold, choice)

    return tune
