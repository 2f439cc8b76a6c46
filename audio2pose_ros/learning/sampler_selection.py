"""Choose a ``live_groups`` model's sampling settings on validation clips (issue 13).

The part temperatures and the speech gate's rest level of
:class:`~audio2pose_ros.models.live_groups.LiveGroups` act only when sampling
(:data:`~audio2pose_ros.models.live_groups.SAMPLING_SETTINGS`), so they are chosen after
training, on the clips that stopped training early: never on the clips the model is tested on.
`make default-model` does it for the shipped model (validation: two talking-head clips and one
lecture stretch) and, the same way, inside every leave-one-speaker-out fold (validation: that
fold's early-stopping speakers), so the reported head numbers measure the whole procedure.

1. Temperatures. Both parts sample at each temperature of :data:`TEMPERATURES`, with
   :data:`N_SEEDS` seeds; per joint group with real motion in the validation clips, the
   samples' motion is compared with the real motion (pooled over the seeds:
   :func:`~audio2pose_ros.learning.metrics.sum_segments`) by :func:`score`, which adds the mean
   of the Hellinger distances of speed and acceleration to how far the motion's size is from real,
   ``|ln(std ratio)|``. Each part keeps the temperature with the lowest score, averaged over its
   joint groups weighted by their joint counts; a part without validation motion keeps its
   configured temperature.
2. Rest level in silence. With those temperatures, every rest level of
   :data:`SILENCE_TEMPERATURES`, from the most noise left in silence to the least, samples the
   validation audio with a pause inserted
   (:func:`~audio2pose_ros.learning.evaluation.with_pause`); the first whose speech / pause speed ratio reaches
   :data:`PAUSE_MARGIN` times issue 13's target
   (:data:`PAUSE_TARGETS`) in every scored group is kept (the lowest one if none does): as
   lively in silence as the "come to rest" target allows, with a margin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import MOTION_RATE_HZ, Clip
from audio2pose_ros.learning import metrics
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.robot.description import RobotDescription

TEMPERATURES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
SILENCE_TEMPERATURES = (0.3, 0.2, 0.1, 0.05, 0.02)  # most noise left in silence first
PAUSE_TARGETS = {"head": 2.0, "arms": 1.5, "hip": 1.5}  # issue 13: speech / silence speed
PAUSE_MARGIN = 1.25
N_SEEDS = 6
_PART_SETTINGS = ("first_temperature", "second_temperature")


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
    """The chosen sampling settings, every trial, and the validation clips they were chosen on."""

    settings: dict[str, float]
    trials: tuple[Trial, ...]
    validation: tuple[str, ...]

    def table(self) -> str:
        """Plain text: one line per trial, the chosen values marked with ``*``."""
        lines = [
            f"chosen on {', '.join(self.validation)} ({N_SEEDS} seeds each): "
            + ", ".join(f"{k} = {v:g}" for k, v in self.settings.items()),
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


def _part_groups(model: LiveGroups, robot: RobotDescription, clips: Sequence[Clip]) -> list[dict]:
    """Per part: its setting name and its joint groups with real motion in ``clips``."""
    parts = []
    for setting, joints in zip(_PART_SETTINGS, model.groups, strict=True):
        inside = np.zeros(robot.n_joints, bool)
        inside[joints] = True
        groups = [
            g
            for g in ("head", "arms", "hip")
            if robot.group_mask(g).any()
            and not (robot.group_mask(g) & ~inside).any()
            and any(c.mask[:, robot.group_mask(g)].any() for c in clips)
        ]
        parts.append({"setting": setting, "groups": groups})
    return parts


def _measures(
    checkpoint: Checkpoint,
    clips: Sequence[Clip],
    robot: RobotDescription,
    groups: Sequence[str],
    n_seeds: int,
    paused: bool,
) -> dict[str, dict[str, float]]:
    """Group -> measures of the checkpoint's samples (seeds 0 .. n - 1) on the clips."""
    from audio2pose_ros.learning.evaluation import with_pause
    from audio2pose_ros.offline.synthesis import synthesize

    real: dict[str, list[metrics.MotionSegments]] = {g: [] for g in groups}
    generated: dict[str, list[metrics.MotionSegments]] = {g: [] for g in groups}
    for clip in clips:
        audio = with_pause(clip.audio) if paused else clip.audio
        samples = [synthesize(checkpoint, audio, seed=s)[1] for s in range(n_seeds)]
        n = min(samples[0].shape[0], clip.n_frames)
        speech = metrics.energy_vad(audio, samples[0].shape[0] if paused else n)
        true = np.nan_to_num(clip.angles_rad[:n])
        for g in groups:
            joints = robot.group_mask(g)
            if paused:
                everywhere = np.ones((samples[0].shape[0], int(joints.sum())), bool)
                generated[g].append(
                    metrics.sum_segments(
                        [
                            metrics.segment_statistics(
                                m[:, joints], everywhere, speech, MOTION_RATE_HZ
                            )
                            for m in samples
                        ]
                    )
                )
                continue
            mask = clip.mask[:n, joints]
            if not mask.any():
                continue
            real[g].append(
                metrics.segment_statistics(true[:, joints], mask, speech, MOTION_RATE_HZ)
            )
            generated[g].append(
                metrics.sum_segments(
                    [
                        metrics.segment_statistics(m[:n, joints], mask, speech, MOTION_RATE_HZ)
                        for m in samples
                    ]
                )
            )
    out = {}
    for g in groups:
        gen = metrics.concat_segments(generated[g])
        if paused:
            ratio = metrics.distribution_measures(gen, gen)["speech/silence speed"]
            out[g] = {"speech/pause speed": ratio}
        else:
            out[g] = metrics.distribution_measures(metrics.concat_segments(real[g]), gen)
    return out


def _with(checkpoint: Checkpoint, model: LiveGroups, **settings: float) -> Checkpoint:
    return replace(checkpoint, model=model.with_sampling(**settings))


def select_sampling(
    checkpoint: Checkpoint,
    validation: Sequence[Clip],
    robot: RobotDescription,
    n_seeds: int = N_SEEDS,
) -> tuple[Checkpoint, SamplingChoice]:
    """Choose the sampling settings of a ``live_groups`` checkpoint (see the module docstring).

    Args:
        checkpoint: a trained checkpoint; other models are returned unchanged.
        validation: clips the model was not trained on and is not tested on.
        robot: joint order and groups.
        n_seeds: samples per clip and setting.

    Returns:
        The checkpoint with the chosen settings (same weights; its info records the choice) and
        the choice with every trial.

    """
    model = checkpoint.model
    names = tuple(c.info.clip_id for c in validation)
    if not isinstance(model, LiveGroups) or not validation:
        return checkpoint, SamplingChoice({}, (), names)
    parts = [p for p in _part_groups(model, robot, validation) if p["groups"]]
    groups = [g for p in parts for g in p["groups"]]
    trials: list[Trial] = []
    if not parts:
        return checkpoint, SamplingChoice({}, (), names)
    per_value = {}
    for value in TEMPERATURES:
        candidate = _with(checkpoint, model, first_temperature=value, second_temperature=value)
        per_value[value] = _measures(candidate, validation, robot, groups, n_seeds, paused=False)
        for part in parts:
            for g in part["groups"]:
                trials.append(Trial(part["setting"], value, g, per_value[value][g]))
    chosen: dict[str, float] = {}
    for part in parts:
        weights = [int(robot.group_mask(g).sum()) for g in part["groups"]]
        chosen[part["setting"]] = min(
            TEMPERATURES,
            key=lambda v, part=part, weights=weights: np.average(
                [score(per_value[v][g]) for g in part["groups"]], weights=weights
            ),
        )
    for rest in SILENCE_TEMPERATURES:
        candidate = _with(checkpoint, model, **{**chosen, "silence_temperature": rest})
        ratios = _measures(candidate, validation, robot, groups, n_seeds, paused=True)
        for g in groups:
            trials.append(Trial("silence_temperature", rest, g, ratios[g]))
        chosen["silence_temperature"] = rest
        if all(ratios[g]["speech/pause speed"] >= PAUSE_MARGIN * PAUSE_TARGETS[g] for g in groups):
            break
    tuned = _with(checkpoint, model, **chosen)
    tuned.info = {**checkpoint.info, "sampling_chosen_on": list(names)}
    return tuned, SamplingChoice(chosen, tuple(trials), names)
