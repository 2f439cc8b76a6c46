"""Choose a ``live_groups`` model's sampling settings on validation clips.

The part temperatures and noise burstiness, the noise's correlation and the speech gate's rest
level of :class:`~audio2pose_ros.models.live_groups.LiveGroups` act only when sampling
(:data:`~audio2pose_ros.models.live_groups.SAMPLING_SETTINGS`), so they are chosen after
training, on clips the deciding models were not trained on and that are never the reported
test clips. The evidence is a list of :data:`Fold` s, each a trained checkpoint with clips it did
not see; `make default-model` (:mod:`audio2pose_ros.learning.default_model`) uses, for the head,
:func:`~audio2pose_ros.learning.sampling_folds.cross_validated` models over the training
speakers (each speaker's clips predicted by a model trained without that speaker; the same
again inside every leave-one-speaker-out fold, on that fold's training speakers only) and, for
the arms, the shipped model on its validation
stretch of the lecture.

1. Noise and temperatures. Both parts sample with every combination of a noise correlation of
   :data:`CORRELATIONS`, a burstiness of :data:`BURSTS`
   (:mod:`audio2pose_ros.models.sampling_noise`) and a temperature of :data:`TEMPERATURES`,
   :data:`N_SEEDS` samples per clip; per joint group, the samples' motion on every fold's clips
   that observe the group is compared with the real motion (pooled over the samples and folds:
   :func:`~audio2pose_ros.learning.metrics.sum_segments`) by :func:`score`, which adds the mean
   of the Hellinger distances of speed and acceleration to how far the motion's size is from
   real, ``|ln(std ratio)|``, and, for the groups of :data:`TAIL_GROUPS` when a reference is
   given, how far its speed and acceleration percentiles are from the reference's
   (:func:`tail_distance`: whether the head makes real speakers' quick nods). Each part keeps
   the correlation, burstiness and temperature
   with the lowest score, averaged over its joint groups weighted by their joint counts (its own
   ``first_correlation`` / ``second_correlation``: a head's quick nods and an arm's slow swings
   need noise of different speeds). A part whose joints no clip observes keeps its configured
   settings. The part that moves the arms also has a body budget: its samples, on every clip's
   audio and on the audio of clips that do not label the arms (other speakers, other rooms:
   the arms must keep off the body on speech unlike the few minutes they learned from), may
   bring an arm closer than the self-collision guard's margin to the robot's body
   (:class:`~audio2pose_ros.robot.body.BodyModel`) in at most :data:`BODY_BUDGET_PCT` of the
   frames; a setting within the budget beats every setting over it, and if none is within, the
   one least over it wins. Every part likewise has a budget of :data:`GATE_BUDGET_PCT` of raw
   steps (consecutive sampled poses, before any smoothing) that the motion filter's input gate
   would refuse as faster than the robot can move (:func:`_gate_bound`): the filter drops such
   poses, so a setting that makes them is over budget by their share. Given real motion
   (``reference``), the arms also have a calm budget: the real arms through the motion filter
   (:func:`calm_reference`) set how often the commanded arms may sit at the acceleration limit
   and hold a wrist above the shoulder (:data:`CALM_KEYS`); every sample drawn, commanded on
   the same speech as the body budget's, is measured, and the worst sample's figures count
   (:func:`worst_calm`), their overrun like the body budget's. The :data:`N_SEEDS` samples
   of an utterance are the motions of seeds 0, 2, 4 and 6
   (:meth:`~audio2pose_ros.models.live_groups.LiveGroups.sample`: sample s draws as seed 2 s),
   the same on every utterance, as a robot running with one seed. Commanding them through the
   filter costs more than sampling, so a setting's calm figures are measured only where they
   can change the choice (:func:`_best`; the same choice as measuring all, and the trial
   table leaves the others blank). Every setting samples the
   arms with the body in mind
   (:mod:`audio2pose_ros.models.body_noise`: the arm noise fades within :data:`BODY_BAND_M` of
   the guard's margin), and the choice keeps that on. The guard stays on the robot; this keeps
   it from shaping the motion. Every setting also samples within the robot's velocity limits
   (``velocity_limit`` = :data:`VELOCITY_LIMIT`: no sampled step outruns a joint), and the
   choice keeps that on too: the gate then refuses no step, and a hot setting whose network
   widens its spread for a frame or two no longer loses on the gate's budget (the arms' raw
   samples did, which held their temperature at 2 and their motion at 0.64 of real).

   A part whose joints span several groups (the arms and the hip) then tries one temperature
   per group: the grid's choice is its largest group's (the score weighs groups by their
   joint counts), so each smaller group in turn tries every temperature of
   :data:`TEMPERATURES`, the rest of the part at its best so far, at its best correlation and
   burstiness, sampled on the clips that observe the part and the body budget's speech (the
   hip sways less than the arms swing: at the temperature that sizes the arms, the hip moved
   up to twice as much as the lecturer's).

   A part of at most :data:`PER_JOINT_MAX` joints, all in :data:`TAIL_GROUPS` (the head), then
   also tries one burstiness per joint (:func:`_per_joint_parts`): every tuple of
   :data:`BURSTS` values that are not all equal, at the part's best correlation so far and at
   its best temperature and the ones beside it in :data:`TEMPERATURES`, sampled on the clips
   that observe the part. People turn their heads in rarer, quicker bursts than they nod,
   which one burstiness for both head joints cannot give; the arms keep one burstiness for
   all their joints (3^8 tuples would be too many to sample).
2. Rest level in silence. With those settings, every rest level of
   :data:`SILENCE_TEMPERATURES`, from the most noise left in silence to the least, samples the
   same clips' audio with a pause inserted
   (:func:`~audio2pose_ros.learning.quality.with_pause`); the first whose speech / pause
   speed ratio reaches :data:`PAUSE_MARGIN` times the speech / pause target
   (:data:`PAUSE_TARGETS`) in
   every scored group is kept (the lowest one if none does): as lively in silence as the "come
   to rest" target allows, with a margin.

The features of every clip are computed once and every setting samples all its seeds in one
batch (:func:`~audio2pose_ros.offline.synthesis.sample_normalized`), so the search costs
sampling, not feature extraction.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.data.importers.body_clearance import TRAINING_CLEARANCE_M
from audio2pose_ros.learning import metrics, realism
from audio2pose_ros.learning.arm_calm import CALM_KEYS, arm_calm, figures
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.models.sampling_noise import Burst, format_per_joint
from audio2pose_ros.models.speech_gate import PART_BURST_KEYS, PART_CORRELATION_KEYS
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLE_RATE_HZ

TEMPERATURES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0)
BURSTS = (0.0, 0.6, 1.2)  # log-std of the noise's burst envelope (0 = steady noise)
CORRELATIONS = (0.95, 0.975, 0.99)  # AR(1) coefficient of the noise (second order)
SILENCE_TEMPERATURES = (0.3, 0.2, 0.1, 0.05, 0.02)  # most noise left in silence first
PAUSE_TARGETS = {"head": 2.0, "arms": 1.5, "hip": 1.5}  # targets: speech / silence speed
PAUSE_MARGIN = 1.25
N_SEEDS = 4
BODY_MARGIN_M = MotionFilterSettings.body_margin_m  # the self-collision guard's default margin
BODY_BUDGET_PCT = 1.0  # sampled arm frames allowed closer to the body than the margin
# body-aware sampling: the arm noise is whole from the clearance the training targets keep
BODY_BAND_M = round(TRAINING_CLEARANCE_M - BODY_MARGIN_M, 6)
GATE_BUDGET_PCT = 0.05  # raw steps the motion filter's input gate may refuse as implausible
VELOCITY_LIMIT = 1.0  # sampled steps within the robot's velocity limits (velocity_limit)
BODY_CHECK_EVERY = 4  # frames: the share is estimated on every 4th sampled frame
GROUPS = ("head", "arms", "hip")
TAIL_GROUPS = ("head",)  # groups whose speed percentiles are matched to a reference (score)
PER_JOINT_MAX = 2  # joints of a part whose burstiness is also tried per joint (BURSTS^joints)
_PART_SETTINGS = ("first_temperature", "second_temperature")
_PART_BURSTS = dict(zip(_PART_SETTINGS, PART_BURST_KEYS, strict=True))
_PART_CORRELATIONS = dict(zip(_PART_SETTINGS, PART_CORRELATION_KEYS, strict=True))

Fold = tuple[Checkpoint, Sequence[Clip]]  # a trained checkpoint and clips it was not trained on
Setting = Burst  # a sampling setting's value: a number, or a burstiness per joint


def score(measures: dict[str, float]) -> float:
    """Distance of generated from real motion.

    ``mean(H speed, H accel) + |ln(std ratio)|``, plus the ``tail`` measure where there is one:
    the mean ``|ln|`` of the ratios of the speed and acceleration percentiles to the reference's
    (:func:`tail_distance`).
    """
    ratio = measures["std ratio"]
    size = abs(math.log(ratio)) if ratio > 0 else math.inf
    return 0.5 * (measures["H speed"] + measures["H accel"]) + size + measures.get("tail", 0.0)


def tail_distance(
    generated: Sequence[realism.Motion], reference: tuple[np.ndarray, np.ndarray]
) -> float:
    """Mean ``|ln(generated / reference)|`` over the joints' speed and acceleration percentiles.

    The percentiles are :data:`~audio2pose_ros.learning.realism.PERCENTILES` (p50, p90, p99):
    the Hellinger distance on 0.1 rad/s bins barely sees a head whose speeds all lie in the
    first few bins, and not at all whether its quick nods (p99) are there. Percentiles are
    floored at 1e-4 so that a still motion is far, not infinitely far.
    """
    speed, accel = realism.speed_percentiles(generated, FRAME_RATE_HZ)
    ratios = np.concatenate(
        [
            (np.maximum(speed, 1e-4) / np.maximum(reference[0], 1e-4)).ravel(),
            (np.maximum(accel, 1e-4) / np.maximum(reference[1], 1e-4)).ravel(),
        ]
    )
    return float(np.mean(np.abs(np.log(ratios))))


@dataclass(frozen=True)
class Trial:
    """One setting tried on one joint group: its measures on the validation clips.

    Attributes:
        setting: the part's temperature setting, or ``silence_temperature``.
        value: its value.
        group: the joint group measured.
        measures: the distribution measures, or the speech/pause speed ratio.
        correlation: the noise correlation sampled with (part trials).
        burst: the part's noise burstiness sampled with (part trials).

    """

    setting: str
    value: Setting
    group: str
    measures: dict[str, float]
    correlation: float | None = None
    burst: Burst | None = None


@dataclass(frozen=True)
class SamplingChoice:
    """The chosen sampling settings, every trial, and the validation clips they were chosen on.

    Attributes:
        settings: chosen :data:`~audio2pose_ros.models.live_groups.SAMPLING_SETTINGS`.
        trials: every setting tried, per joint group.
        validation: ids of the clips the choice was made on.
        seconds: their length.
        n_models: how many trained models predicted them.
        body_seconds: length of the further speech the arms' body budget was checked on.
        calm: the arms' calm budget (:data:`CALM_KEYS` of :func:`calm_reference`: the real
            people's figures through the motion filter); empty without one.

    """

    settings: dict[str, Setting]
    trials: tuple[Trial, ...]
    validation: tuple[str, ...]
    seconds: float = 0.0
    n_models: int = 0
    body_seconds: float = 0.0
    calm: Mapping[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: the chosen values and what they were chosen on."""
        chosen = (
            ", ".join(f"{k} = {format_per_joint(v)}" for k, v in self.settings.items()) or "nothing"
        )
        more = (
            f"; the arms' body budget also on {self.body_seconds:.0f} s of other speech"
            if self.body_seconds
            else ""
        )
        if self.calm:
            budget = ", ".join(f"{k} <= {v:.1f}" for k, v in self.calm.items())
            more += f"; the arms' calm budget (the people's, commanded): {budget}"
        return (
            f"{chosen} (on {len(self.validation)} validation clips, {self.seconds:.0f} s, "
            f"predicted by {self.n_models} model(s), {N_SEEDS} samples each{more})"
        )

    def _chosen(self, trial: Trial) -> bool:
        if self.settings.get(trial.setting) != trial.value:
            return False
        if trial.correlation is None:
            return True
        burst = self.settings.get(_PART_BURSTS.get(trial.setting, ""))
        correlation = self.settings.get(_PART_CORRELATIONS.get(trial.setting, ""))
        return correlation == trial.correlation and burst == trial.burst

    def table(self) -> str:
        """Plain text: the summary, then one line per trial, the chosen ones marked ``*``."""
        lines = [
            self.summary(),
            f"{'setting':<21}{'corr':>6}{'burst':>8}{'value':>8}  {'group':<6}{'H speed':>8}"
            f"{'H accel':>8}{'std/real':>9}{'tail':>6}{'score':>7}{'speech/pause':>13}"
            f"{'near body %':>12}{'gate refused %':>15}" + "".join(f"{k:>14}" for k in CALM_KEYS),
        ]
        for t in self.trials:
            m = t.measures
            noise = (f"{t.correlation:>6g}" if t.correlation is not None else f"{'-':>6}") + (
                f"{format_per_joint(t.burst):>8}" if t.burst is not None else f"{'-':>8}"
            )
            lines.append(
                f"{t.setting:<21}{noise}{format_per_joint(t.value):>8}"
                f"{'*' if self._chosen(t) else ' '} "
                f"{t.group:<6}"
                + "".join(
                    f"{m[k]:>{w}.2f}" if k in m else f"{'-':>{w}}"
                    for k, w in (("H speed", 8), ("H accel", 8), ("std ratio", 9), ("tail", 6))
                )
                + (f"{score(m):>7.2f}" if "std ratio" in m else f"{'-':>7}")
                + (f"{m['speech/pause speed']:>13.2f}" if "speech/pause speed" in m else "")
                + (f"{'':>13}" if "near body %" in m or "gate refused %" in m else "")
                + (f"{m['near body %']:>12.1f}" if "near body %" in m else f"{'':>12}")
                + (f"{m['gate refused %']:>15.2f}" if "gate refused %" in m else "")
                + "".join(f"{m[k]:>14.1f}" for k in CALM_KEYS if k in m)
            )
        return "\n".join(lines)


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


@dataclass(frozen=True)
class _Evidence:
    """One validation clip of a fold, with what every setting's samples are compared against.

    Attributes:
        checkpoint: the fold's model (trained without the clip).
        frames: the clip's normalised features (or its paused audio's).
        speech: speech activity per frame (energy VAD).
        known: per observed group, its (frames, joints) mask.
        real: per observed group, the real motion's segment statistics (not for paused audio).
        style: the recording source whose style the clip shows (:func:`choose_sampling`'s
            ``style_of``); "" without one.

    """

    checkpoint: Checkpoint
    frames: np.ndarray
    speech: np.ndarray
    known: dict[str, np.ndarray]
    real: dict[str, metrics.MotionSegments]
    style: str = ""


def _evidence(
    folds: Sequence[Fold],
    robot: RobotDescription,
    paused: bool,
    body_audio: Sequence[np.ndarray] = (),
    style_of: Callable[[Clip], str] | None = None,
) -> list[_Evidence]:
    """Every fold's clips, features and real motion computed once for all settings.

    ``body_audio`` (16 kHz utterances) adds items without motion to compare: their samples
    count for the body budget only, sampled by the first fold's model. ``style_of`` names
    each clip's style (:attr:`_Evidence.style`).
    """
    from audio2pose_ros.learning.quality import with_pause
    from audio2pose_ros.offline.synthesis import normalized_features

    out = []
    if folds:
        first = folds[0][0]
        for audio in body_audio:
            frames = normalized_features(first, audio)
            out.append(_Evidence(first, frames, metrics.energy_vad(audio, len(frames)), {}, {}))
    for checkpoint, clips in folds:
        groups = _observed(robot, clips)
        for clip in clips:
            audio = with_pause(clip.audio) if paused else clip.audio
            frames = normalized_features(checkpoint, audio)
            n = len(frames) if paused else min(len(frames), clip.n_frames)
            speech = metrics.energy_vad(audio, n)
            known, real = {}, {}
            for g in groups:
                joints = robot.group_mask(g)
                mask = np.ones((n, int(joints.sum())), bool) if paused else clip.mask[:n, joints]
                if not mask.any():
                    continue
                known[g] = mask
                if not paused:
                    true = np.nan_to_num(clip.angles_rad[:n, joints])
                    real[g] = metrics.segment_statistics(true, mask, speech, FRAME_RATE_HZ)
            style = style_of(clip) if style_of is not None else ""
            out.append(_Evidence(checkpoint, frames, speech, known, real, style))
    return out


def _measures(
    evidence: Sequence[_Evidence],
    settings: Mapping[str, Setting],
    robot: RobotDescription,
    n_seeds: int,
    paused: bool,
    body: BodyModel | None = None,
    tails: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
    calm: Mapping[str, float] | None = None,
) -> tuple[dict[str, dict[str, float]], _Calm | None]:
    """Group -> measures of the samples (``n_seeds`` per clip) with ``settings``, pooled.

    With ``body``, the arms' measures also hold ``near body %``: the share of sampled frames
    (every :data:`BODY_CHECK_EVERY`-th, on every clip's audio) closer to the body than
    :data:`BODY_MARGIN_M`. A group of ``tails`` (group -> reference speed and acceleration
    percentiles) also has ``tail``: :func:`tail_distance` of its samples. With ``body`` and a
    ``calm`` reference (:func:`calm_reference`), the arms' calm figures are returned beside,
    not yet measured (:class:`_Calm`: every sample of every item as the motion filter commands
    it, the worst sample's figures, put into the arms' measures once measured); else None.
    """
    from audio2pose_ros.offline.synthesis import sample_normalized, to_angles

    tails = tails or {}  # paused audio is never given tails: it has no real motion

    near = [0, 0]  # frames closer than the margin, frames checked
    jumps: dict[str, list[int]] = {}  # group -> [raw steps the filter's gate refuses, steps]
    gate_bound = None
    # (group, style) -> segments; only the groups of TAIL_GROUPS are told apart by style
    real: dict[tuple[str, str], list[metrics.MotionSegments]] = {}
    generated: dict[tuple[str, str], list[metrics.MotionSegments]] = {}
    motions: dict[str, list[realism.Motion]] = {}  # groups of ``tails``: the sampled motion
    candidates: dict[int, Checkpoint] = {}
    # per sample drawn (calm): every item's sample as the inference node sends it
    sent: list[list[np.ndarray]] = [[] for _ in range(n_seeds)]
    for item in evidence:
        checkpoint = item.checkpoint
        if id(checkpoint) not in candidates:
            model = cast(LiveGroups, checkpoint.model)  # choose_sampling keeps live_groups only
            candidates[id(checkpoint)] = replace(checkpoint, model=model.with_sampling(**settings))
        candidate = candidates[id(checkpoint)]
        n = len(item.speech)
        raw = sample_normalized(candidate, item.frames, n_seeds)
        samples = [to_angles(candidate, poses)[:n] for poses in raw]
        if gate_bound is None:
            gate_bound = _gate_bound(candidate)
        steps = np.abs(np.diff(candidate.robot.denormalize(raw[:, :n]), axis=1)) > gate_bound
        if body is not None and calm is not None:
            for drawn, poses in zip(sent, raw, strict=True):
                drawn.append(to_angles(candidate, poses[:n], smooth=False))
        if body is not None:
            checked = np.concatenate([m[::BODY_CHECK_EVERY] for m in samples])
            near[0] += int(np.count_nonzero(body.clearance(checked) < BODY_MARGIN_M))
            near[1] += len(checked)
        for g in GROUPS:
            if not robot.group_mask(g).any():
                continue
            count = jumps.setdefault(g, [0, 0])
            count[0] += int(steps[..., robot.group_mask(g)].any(axis=-1).sum())
            count[1] += steps.shape[0] * steps.shape[1]
        for g, known in item.known.items():
            joints = robot.group_mask(g)
            key = (g, item.style if g in TAIL_GROUPS and not paused else "")
            generated.setdefault(key, []).append(
                metrics.sum_segments(
                    [
                        metrics.segment_statistics(m[:, joints], known, item.speech, FRAME_RATE_HZ)
                        for m in samples
                    ]
                )
            )
            if not paused:
                real.setdefault(key, []).append(item.real[g])
            if g in tails:
                motions.setdefault(g, []).extend((m[:, joints], known) for m in samples)
    out: dict[str, dict[str, float]] = {}
    styles: dict[str, list[dict[str, float]]] = {}  # group -> its measures per style
    for (g, style), parts in generated.items():
        gen = metrics.concat_segments(parts)
        if paused:
            ratio = metrics.distribution_measures(gen, gen)["speech/silence speed"]
            out[g] = {"speech/pause speed": ratio}
        else:
            measured = metrics.distribution_measures(metrics.concat_segments(real[(g, style)]), gen)
            styles.setdefault(g, []).append(measured)
    for g, per_style in styles.items():
        out[g] = between_styles(per_style)
    for g, motion in motions.items():
        out[g]["tail"] = tail_distance(motion, tails[g])
    if body is not None and "arms" in out and near[1]:
        out["arms"]["near body %"] = 100.0 * near[0] / near[1]
    pending = None
    if body is not None and calm is not None and "arms" in out and sent[0]:
        pending = _Calm(robot, body, sent, out["arms"])
    for g, (refused, total) in jumps.items():
        if g in out and total and not paused:
            out[g]["gate refused %"] = 100.0 * refused / total
    return out, pending


@dataclass
class _Calm:
    """One arm trial's calm figures, measured only when the choice needs them.

    Commanding every sample through the motion filter costs more than sampling it, and most
    settings lose on their score or the other budgets whatever their calm figures
    (:func:`_best`).

    Attributes:
        robot: joint order and limits.
        body: the robot's collision shapes.
        sent: per sample drawn, its unsmoothed poses on every item (dropped once measured).
        arms: the trial's arm measures, which receive the figures (:data:`CALM_KEYS`).

    """

    robot: RobotDescription
    body: BodyModel
    sent: list[list[np.ndarray]]
    arms: dict[str, float]

    def overrun(self, budget: Mapping[str, float]) -> float:
        """Percentage points over ``budget``, summed over its keys (measured on first use)."""
        from audio2pose_ros.learning.command_path import commanded

        if self.sent:
            drawn = [commanded(self.robot, motions) for motions in self.sent]
            self.arms |= worst_calm(self.robot, self.body, drawn)
            self.sent = []
        return sum(max(0.0, self.arms.get(k, 0.0) - v) for k, v in budget.items())


@dataclass(frozen=True)
class _Scored:
    """One part's trial as the choice ranks it.

    Attributes:
        over: percentage points over the body and gate budgets.
        total: the part's score (:func:`score`, weighted over its groups).
        correlation: the noise correlation tried.
        burst: the burstiness tried.
        value: the temperature tried.
        calm: the arms' calm figures, measured on demand; None for a part without arms.

    """

    over: float
    total: float
    correlation: float
    burst: Burst
    value: Setting
    calm: _Calm | None = None


def _best(tried: Sequence[_Scored], budget: Mapping[str, float]) -> _Scored:
    """The trial least over its budgets, then of the lowest score, then the first tried.

    The calm budget's overrun (:meth:`_Calm.overrun`) only adds to a trial's ``over``, so the
    trials are visited by (``over``, score, order), and the visit stops at the first whose
    key without the calm overrun is not below the best full key found: every later trial's
    full key is at least as high. The choice is the one measuring every trial would make;
    the trials never visited keep no calm figures.
    """
    order = sorted(range(len(tried)), key=lambda i: (tried[i].over, tried[i].total, i))
    best: tuple[float, float, int] | None = None
    for i in order:
        t = tried[i]
        if best is not None and (t.over, t.total, i) >= best:
            break
        extra = t.calm.overrun(budget) if t.calm is not None else 0.0
        key = (t.over + extra, t.total, i)
        if best is None or key < best:
            best = key
    if best is None:
        raise ValueError("no trial to choose from")
    return tried[best[2]]


def between_styles(per_style: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """One group's measures against several styles of real motion, as one set.

    The distances are averaged and the std ratio is the geometric mean of the per-style
    ratios, so the size term ``|ln(std ratio)|`` of :func:`score` is least for motion sized
    at the geometric mean of the styles' sizes: between a calm reader and an animated
    addresser, not at either. A single style's measures are returned as they are.
    """
    if len(per_style) == 1:
        return dict(per_style[0])
    out = {k: float(np.mean([m[k] for m in per_style])) for k in per_style[0]}
    ratios = np.array([m["std ratio"] for m in per_style])
    with np.errstate(divide="ignore", invalid="ignore"):
        out["std ratio"] = float(np.exp(np.mean(np.log(ratios))))
    return out


def _gate_bound(checkpoint: Checkpoint) -> np.ndarray:
    """Per joint, the largest step between consecutive raw poses the filter's gate accepts.

    The gate (:class:`~audio2pose_ros.motion.gate.TrackGate`, default filter settings) takes
    the poses of a message one filter period apart and accepts a step of at most the joint's
    velocity limit times that period plus its tolerance.
    """
    settings = MotionFilterSettings()
    return checkpoint.robot.max_velocity_rad_s / settings.rate_hz + settings.outlier_tolerance_rad


def reference_percentiles(
    clips: Sequence[Clip],
    robot: RobotDescription,
    style_of: Callable[[Clip], str] | None = None,
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per group of :data:`TAIL_GROUPS` that ``clips`` observe: its real motion's percentiles.

    With ``style_of``, the percentiles of each style's clips, and their geometric mean over
    the styles (between them, as :func:`between_styles`).
    """
    out = {}
    for g in TAIL_GROUPS:
        groups: dict[str, list[Clip]] = {}
        for clip in clips:
            groups.setdefault(style_of(clip) if style_of is not None else "", []).append(clip)
        each = []
        for members in groups.values():
            observed = realism.clip_motions(members, robot.group_mask(g))
            if observed:
                each.append(realism.speed_percentiles(observed, FRAME_RATE_HZ))
        if each:
            speed = np.exp(np.mean([np.log(np.maximum(e[0], 1e-4)) for e in each], axis=0))
            accel = np.exp(np.mean([np.log(np.maximum(e[1], 1e-4)) for e in each], axis=0))
            out[g] = (speed, accel)
    return out


def calm_measures(
    robot: RobotDescription, body: BodyModel, commands: Sequence[realism.Motion | np.ndarray]
) -> dict[str, float]:
    """The calm figures (:data:`~audio2pose_ros.learning.arm_calm.CALM_KEYS`) of arm motion.

    The share of arm joint-frames at the acceleration limit, and of frames with a wrist above
    its shoulder and well above it (%), of motion already commanded.
    """
    return figures(arm_calm("", robot, body, commands))


def worst_calm(
    robot: RobotDescription, body: BodyModel, drawn: Sequence[Sequence[np.ndarray]]
) -> dict[str, float]:
    """Per calm figure, the highest of :func:`calm_measures` over the samples ``drawn``.

    ``drawn`` holds, per sample (one seed of the sampler), its motion on every item, already
    commanded. Each sample is measured over all the items together and the worst sample's
    figure is kept: a robot runs with whatever seed its user gives it, and a setting whose
    arm noise makes rare long raised-arm bursts shows them in some samples only (the shipped
    arms were calm at seeds 0 and 1 and raised a wrist above the shoulder at seeds 2 and 3,
    which a choice on the first sample never saw).
    """
    each = [calm_measures(robot, body, motions) for motions in drawn if motions]
    return {k: max(m[k] for m in each) for k in CALM_KEYS if each}


def calm_reference(
    clips: Sequence[Clip], robot: RobotDescription, body: BodyModel
) -> dict[str, float]:
    """:func:`calm_measures` of the real arm motion of ``clips`` through the motion filter.

    Empty when no clip observes the arms. Only the frames where the arms are observed count.
    """
    from audio2pose_ros.learning.command_path import commanded

    arms = robot.group_mask("arms")
    seen = [c for c in clips if c.mask[:, arms].any()]
    if not seen:
        return {}
    moved = commanded(robot, [c.angles_rad for c in seen])
    return calm_measures(robot, body, [(m, c.mask) for m, c in zip(moved, seen, strict=True)])


def _with_group(value: Setting, in_group: np.ndarray, temperature: float) -> Setting:
    """A part's temperature with the joints ``in_group`` at ``temperature``, one per joint.

    All joints equal gives one number (the form the shared grid tried).
    """
    values = np.broadcast_to(np.asarray(value, dtype=np.float64), in_group.shape).copy()
    values[in_group] = temperature
    return float(values[0]) if (values == values[0]).all() else tuple(map(float, values))


def _part_evidence(evidence: Sequence[_Evidence], groups: Sequence[str]) -> list[_Evidence]:
    """The items that observe one of ``groups``, and the body budget's speech if they hold the arms.

    A trial of one part samples only these: the other items tell nothing about that part.
    """
    return [
        item
        for item in evidence
        if set(item.known) & set(groups) or (not item.known and "arms" in groups)
    ]


def _per_joint_parts(model: LiveGroups, parts: Mapping[str, list[str]]) -> dict[str, int]:
    """Parts whose burstiness is also tried per joint: part setting -> its joint count.

    Those of at most :data:`PER_JOINT_MAX` joints whose groups are all :data:`TAIL_GROUPS`
    (the head: people turn their heads in rarer, quicker bursts than they nod).
    """
    return {
        s: len(joints)
        for s, joints in zip(_PART_SETTINGS, model.groups, strict=True)
        if s in parts
        and 1 < len(joints) <= PER_JOINT_MAX
        and all(g in TAIL_GROUPS for g in parts[s])
    }


def choose_sampling(
    folds: Sequence[Fold],
    robot: RobotDescription,
    n_seeds: int = N_SEEDS,
    body_audio: Sequence[np.ndarray] = (),
    reference: Sequence[Clip] = (),
    style_of: Callable[[Clip], str] | None = None,
) -> SamplingChoice:
    """Choose the sampling settings on the folds' clips (see the module docstring).

    Args:
        folds: trained ``live_groups`` checkpoints, each with clips it was not trained on;
            folds of other models are ignored.
        robot: joint order and groups.
        n_seeds: samples per clip and setting.
        body_audio: more 16 kHz utterances for the arms' body budget only (speech whose arm
            motion the models did not learn; never the clips the model is scored on).
        reference: real motion whose speed and acceleration percentiles the groups of
            :data:`TAIL_GROUPS` should have (the ``tail`` term of :func:`score`), pooled over
            these clips where they observe the group; never the clips the model is scored on.
            Its arm motion through the motion filter also sets the arms' calm budget
            (:func:`calm_reference`).
        style_of: the style (recording source) of a clip: the groups of :data:`TAIL_GROUPS`
            are then measured against each style apart and aim between them
            (:func:`between_styles`, :func:`reference_percentiles`); None = one style.

    """
    folds = [(c, v) for c, v in folds if isinstance(c.model, LiveGroups) and v]
    tails = reference_percentiles(reference, robot, style_of)
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
    weights = {s: [int(robot.group_mask(g).sum()) for g in part] for s, part in parts.items()}
    body = BodyModel.load(robot) if any("arms" in part for part in parts.values()) else None
    calm = calm_reference(reference, robot, body) if body is not None else {}
    evidence = _evidence(folds, robot, False, body_audio if body is not None else (), style_of)
    trials: list[Trial] = []
    # per part: every combination tried, with its overrun of the budgets and its score; the
    # lowest wins (_best), so a setting within the budgets beats any other
    scored: dict[str, list[_Scored]] = {s: [] for s in parts}
    fixed: dict[str, Setting] = {"velocity_limit": VELOCITY_LIMIT}
    if body is not None:
        fixed |= {"body_margin_m": BODY_MARGIN_M, "body_band_m": BODY_BAND_M}

    def trial(
        noise: Mapping[str, tuple[float, Burst, Setting]], items: Sequence[_Evidence]
    ) -> None:
        """Sample with part -> (correlation, burst, temperature) and score those parts."""
        settings: dict[str, Setting] = dict(fixed)
        for s, (correlation, burst, value) in noise.items():
            settings |= {s: value, _PART_BURSTS[s]: burst, _PART_CORRELATIONS[s]: correlation}
        arms = any("arms" in parts[s] for s in noise)
        measured, pending = _measures(
            items, settings, robot, n_seeds, False, body if arms else None, tails, calm or None
        )
        for s, (correlation, burst, value) in noise.items():
            part = parts[s]
            trials.extend(Trial(s, value, g, measured[g], correlation, burst) for g in part)
            total = float(np.average([score(measured[g]) for g in part], weights=weights[s]))
            near = measured["arms"].get("near body %", 0.0) if "arms" in part else 0.0
            refused = sum(measured[g].get("gate refused %", 0.0) for g in part)
            over = max(0.0, near - BODY_BUDGET_PCT) + max(0.0, refused - GATE_BUDGET_PCT)
            checked = pending if "arms" in part else None
            scored[s].append(_Scored(over, total, correlation, burst, value, checked))

    for correlation in CORRELATIONS:
        for shared in BURSTS:
            for value in TEMPERATURES:
                trial(dict.fromkeys(parts, (correlation, shared, value)), evidence)
    for s, n_joints in _per_joint_parts(first, parts).items():
        grid_best = _best(scored[s], calm)
        correlation, on_grid = grid_best.correlation, grid_best.value
        at = TEMPERATURES.index(cast(float, on_grid))  # only the grid was tried so far
        head_items = _part_evidence(evidence, parts[s])
        for per_joint in itertools.product(BURSTS, repeat=n_joints):
            if len(set(per_joint)) > 1:  # equal values were tried above
                for t in TEMPERATURES[max(at - 1, 0) : at + 2]:
                    trial({s: (correlation, per_joint, t)}, head_items)
    for s, part_groups in parts.items():
        # the largest group set the grid's choice (the score weighs groups by joint count);
        # each other group tries every temperature, the rest of the part at its best so far
        part_joints = first.groups[_PART_SETTINGS.index(s)]
        smaller = sorted(part_groups, key=lambda g: -int(robot.group_mask(g).sum()))[1:]
        part_items = _part_evidence(evidence, part_groups) if smaller else []
        for g in smaller:
            so_far = _best(scored[s], calm)
            correlation, burst, best = so_far.correlation, so_far.burst, so_far.value
            for t in TEMPERATURES:
                varied = _with_group(best, robot.group_mask(g)[part_joints], t)
                if isinstance(varied, tuple) and varied != best:  # one value: tried on the grid
                    trial({s: (correlation, burst, varied)}, part_items)
    chosen: dict[str, Setting] = dict(fixed)
    for s in parts:
        won = _best(scored[s], calm)
        chosen[s] = won.value
        chosen[_PART_BURSTS[s]] = won.burst
        chosen[_PART_CORRELATIONS[s]] = won.correlation
    paused = _evidence(folds, robot, paused=True)
    for rest in SILENCE_TEMPERATURES:
        settings = {**chosen, "silence_temperature": rest}
        ratios, _ = _measures(paused, settings, robot, n_seeds, True)
        trials += [Trial("silence_temperature", rest, g, ratios[g]) for g in groups]
        chosen["silence_temperature"] = rest
        if all(ratios[g]["speech/pause speed"] >= PAUSE_MARGIN * PAUSE_TARGETS[g] for g in groups):
            break
    body_seconds = sum(len(a) for a in body_audio) / SAMPLE_RATE_HZ if body is not None else 0.0
    return SamplingChoice(chosen, tuple(trials), names, seconds, len(folds), body_seconds, calm)


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
