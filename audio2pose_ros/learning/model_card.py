"""MODEL_CARD.md of the default model rebuilt by :mod:`audio2pose_ros.learning.default_model`.

The card of the model learned from people (``--arms learned``), evaluated on sources held out
whole: its checks, tables and figures. :mod:`audio2pose_ros.learning.talking_heads_card`
writes the card of a model trained on the talking heads alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.learning import realism
from audio2pose_ros.learning.quality import GroupRow, QualityEvaluation, save_figure
from audio2pose_ros.learning.sampler_selection import (
    BURSTS,
    CORRELATIONS,
    GATE_BUDGET_PCT,
    N_SEEDS,
    PAUSE_MARGIN,
    SILENCE_TEMPERATURES,
    TEMPERATURES,
    VELOCITY_LIMIT,
    SamplingChoice,
)
from audio2pose_ros.learning.style_card import with_style_section
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.models.sampling_noise import PerJoint, format_per_joint
from audio2pose_ros.robot.description import RobotDescription

if TYPE_CHECKING:
    from audio2pose_ros.learning.source_holdout import HoldoutResult


@dataclass(frozen=True)
class SourceReport:
    """The evaluation of one held-out recording source.

    Attributes:
        source: the source (GRID, Obama, lecture).
        groups: what it scores ("head", "arms and hip").
        clips: its held-out clips.
        quality: the measures (:func:`~audio2pose_ros.learning.quality.quality_evaluation`).
        choice: the sampling settings of the model scored (chosen without these clips).

    """

    source: str
    groups: str
    clips: Sequence[Clip]
    quality: QualityEvaluation
    choice: SamplingChoice

    @property
    def seconds(self) -> float:
        """Length of the held-out clips."""
        return sum(c.n_frames for c in self.clips) / 100.0

    def heading(self) -> str:
        """One line: the source, its clips, speakers and length."""
        speakers = len({c.info.speaker for c in self.clips})
        return (
            f"{self.source} held out ({self.groups}): {len(self.clips)} clips, {speakers} "
            f"speaker(s), {self.seconds:.0f} s"
        )

    def model(self) -> str:
        """The scored model's method name (the one starting with ``live_groups``)."""
        return next(r.method for r in self.quality.rows if r.method.startswith("live_groups"))


Check = tuple[str, str, str, str, bool]  # group, measure, target, measured, met


def _interval_check(row: GroupRow, measure: str, target: str, ok: Callable[[float], bool]) -> Check:
    value, low, high = row.measures[measure]
    shown = f"{value:.2f} [{low:.2f}, {high:.2f}]"
    if measure in row.plug_in:
        shown += f" (plug-in {row.plug_in[measure]:.2f})"
    return row.group, measure, target, shown, bool(value == value and ok(value))


def _percentile_check(row: GroupRow, real: GroupRow, names: Sequence[str]) -> Check:
    """How many speed and acceleration percentiles lie within 25 % of real."""
    levels = "/".join(f"p{p}" for p in realism.PERCENTILES)
    measure = f"speed, accel {levels} of {', '.join(names)}"
    if row.percentiles is None or real.percentiles is None:
        return row.group, measure, "within 25 % of real", "-", False
    agree = realism.percentile_agreement(row.percentiles, real.percentiles)
    shown = (
        f"{agree.inside} of {agree.total} (model / real {agree.lowest:.2f} to {agree.highest:.2f})"
    )
    return row.group, measure, "within 25 % of real", shown, agree.inside == agree.total


def _beat_check(row: GroupRow, real: GroupRow) -> list[Check]:
    bc, shuffled, truth, truth_shuffled = (
        row.realism["BC"],
        row.realism["BC shuffled"],
        real.realism["BC"],
        real.realism["BC shuffled"],
    )
    return [
        (
            row.group,
            "beat consistency",
            "within 0.05 of real",
            f"{bc:.3f} (real {truth:.3f})",
            abs(bc - truth) <= BEAT_TOLERANCE,
        ),
        (
            row.group,
            "beat consistency",
            f"above shuffled audio by {BEAT_MARGIN:g}",
            f"{bc:.3f} (shuffled {shuffled:.3f}; real {truth:.3f}, shuffled {truth_shuffled:.3f})",
            bc >= shuffled + BEAT_MARGIN,
        ),
    ]


BEAT_TOLERANCE = 0.05
BEAT_MARGIN = 0.02  # "clearly above" the model's own motion paired with other clips' audio


def _within(low: float, high: float) -> Callable[[float], bool]:
    return lambda v: low <= v <= high


def source_checks(report: SourceReport) -> list[Check]:
    """The goals for one held-out source, met or not, with the measured values."""
    from audio2pose_ros.learning.quality import PROSODY_RULE, REAL_FLOOR, STATIC

    quality, model = report.quality, report.model()
    checks: list[Check] = []
    groups = ("head",) if report.groups == "head" else ("arms", "hip")
    for group in groups:
        row, real = quality.row(group, model), quality.row(group, REAL_FLOOR)
        if row is None or real is None:
            continue
        aim = "" if group == "head" else " (aim)"
        pause = 2.0 if group == "head" else 1.5
        checks += [
            _interval_check(row, "H speed", "<= 0.15" + aim, _within(0.0, 0.15)),
            _interval_check(row, "H accel", "<= 0.15", _within(0.0, 0.15)),
            _interval_check(row, "std ratio", "0.7 to 1.4", _within(0.7, 1.4)),
            _interval_check(row, "speech/pause speed", f">= {pause:g}", _within(pause, math.inf)),
        ]
        if group == "head":
            checks.append(_percentile_check(row, real, quality.joint_names[group]))
            checks += _beat_check(row, real)
        for baseline in (STATIC, PROSODY_RULE) if group == "arms" else ():
            base = quality.row(group, baseline)
            if base is None:
                continue
            for measure in ("H speed", "H accel"):
                bound = min(base.measures[measure][:2])
                checks.append(
                    _interval_check(
                        row, measure, f"below the {baseline}'s interval", _within(-1.0, bound)
                    )
                )
    return checks


def _checks_table(reports: Sequence[SourceReport]) -> str:
    lines = []
    for report in reports:
        for group, measure, target, shown, met in source_checks(report):
            verdict = "met" if met else "**not met**"
            lines.append(
                f"| {report.source} | {group} | {measure} | {target} | {shown} | {verdict} |"
            )
    return "\n".join(lines)


def plot_summary(path: Path, reports: Sequence[SourceReport]) -> Path:
    """One PNG: H speed and H accel (bias-corrected, 95 % interval) per source and method.

    One panel per held-out source and joint group; each method a point with its interval, the
    real split-half floor among them, the goal (0.15) a dashed line.
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    panels = [
        (report, group)
        for report in reports
        for group in (("head",) if report.groups == "head" else ("arms", "hip"))
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), squeeze=False)
    for ax, (report, group) in zip(axes[0], panels, strict=True):
        rows = [r for r in [*report.quality.rows, *report.quality.floors] if r.group == group]
        for k, measure in enumerate(("H speed", "H accel")):
            for i, row in enumerate(rows):
                value, low, high = row.measures[measure]
                x = i + (k - 0.5) * 0.25
                ax.errorbar(
                    x,
                    value,
                    yerr=[[max(value - low, 0.0)], [max(high - value, 0.0)]],
                    fmt="o" if k == 0 else "s",
                    color=f"C{k}",
                    label=measure if i == 0 else None,
                )
        ax.axhline(0.15, color="0.4", linestyle="--", linewidth=0.8, label="goal 0.15")
        ax.set_xticks(range(len(rows)))
        ax.set_xticklabels([r.method for r in rows], rotation=35, ha="right", fontsize=7)
        ax.set_ylim(0.0, 1.0)
        ax.set_title(f"{report.source} held out: {group}", fontsize=9)
        ax.set_ylabel("Hellinger distance to real", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    return save_figure(fig, path)


def plot_percentiles(path: Path, reports: Sequence[SourceReport]) -> Path:
    """One PNG: head speed and acceleration percentiles, model against real, per source."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    from audio2pose_ros.learning.quality import REAL_FLOOR

    heads = [r for r in reports if r.groups == "head"]
    fig, axes = plt.subplots(len(heads), 2, figsize=(10, 3.2 * len(heads)), squeeze=False)
    for r, report in enumerate(heads):
        model = report.quality.row("head", report.model())
        real = report.quality.row("head", REAL_FLOOR)
        if model is None or real is None or model.percentiles is None:
            continue
        assert real.percentiles is not None
        names = report.quality.joint_names["head"]
        for c, unit in enumerate(("speed (rad/s)", "acceleration (rad/s^2)")):
            ax = axes[r, c]
            for j, name in enumerate(names):
                ax.plot(
                    realism.PERCENTILES,
                    real.percentiles[c][j],
                    "o-",
                    color=f"C{j}",
                    label=f"real {name}",
                )
                ax.plot(
                    realism.PERCENTILES,
                    model.percentiles[c][j],
                    "s--",
                    color=f"C{j}",
                    label=f"model {name}",
                )
            ax.set_yscale("log")
            ax.set_xticks(realism.PERCENTILES)
            ax.set_xlabel("percentile", fontsize=8)
            ax.set_title(f"{report.source} held out: head {unit}", fontsize=9)
    axes[0, 0].legend(fontsize=7)
    return save_figure(fig, path)


def _learned_from(checkpoint: Checkpoint, clips: Sequence[Clip]) -> str:
    """Markdown table: speakers and minutes each joint group learned from (training + validation).

    Counted over the frames where the group's joints are labelled, in the clips the shipped
    model trained and stopped early on.
    """
    used = set(checkpoint.info.get("train_clips", [])) | set(
        checkpoint.info.get("validation_clips", [])
    )
    robot = checkpoint.robot
    lines = ["| joint group | speakers | minutes | clips |", "|---|---|---|---|"]
    for group in ("head", "arms", "hip"):
        joints = robot.group_mask(group)
        chosen = [c for c in clips if c.info.clip_id in used and c.mask[:, joints].any()]
        frames = sum(int(c.mask[:, joints].any(axis=1).sum()) for c in chosen)
        speakers = len({c.info.speaker for c in chosen})
        lines.append(f"| {group} | {speakers} | {frames / 6000.0:.1f} | {len(chosen)} |")
    return "\n".join(lines)


def _started_from(results: Sequence[HoldoutResult]) -> str:
    """Markdown: which trainings started from a pretrained checkpoint, and whose data it held.

    Empty when every training started from new weights.
    """
    started = [r for r in results if "started_from" in r.checkpoint.info]
    if not started:
        return ""
    speakers = sorted(
        {str(s) for r in started for s in r.checkpoint.info["started_from"].get("speakers", [])}
    )
    fresh = [r.name for r in results if "started_from" not in r.checkpoint.info]
    names = ", ".join(r.name for r in started)
    listed = ", ".join(speakers[:8]) + (", ..." if len(speakers) > 8 else "")
    text = (
        f"\nPretrained: {names} started from a checkpoint (`build-default --start`) that "
        f"learned from {len(speakers)} speaker(s) ({listed}), not counted in the table; the "
        "licences of its data apply to this model too."
    )
    if fresh:
        text += (
            f" {', '.join(fresh)} started from new weights: each holds out a source the "
            "checkpoint learned from."
        )
    return text + "\n"


def _selection(results: Sequence[HoldoutResult]) -> str:
    """The card's account of how the sampling settings were chosen."""
    temperatures = ", ".join(f"{t:g}" for t in TEMPERATURES)
    bursts = ", ".join(f"{t:g}" for t in BURSTS)
    correlations = ", ".join(f"{t:g}" for t in CORRELATIONS)
    rests = ", ".join(f"{t:g}" for t in SILENCE_TEMPERATURES)
    chosen = "\n".join(f"- {r.name}: {r.choice.summary()}" for r in results)
    return f"""## How the sampling settings were chosen (never on a scored clip)
The noise's correlation, the part temperatures and burstiness, and the gate's rest level in
silence act only when sampling, so every model of the rebuild chooses them after training
(`audio2pose_ros/learning/sampler_selection.py`) on its own validation clips, which come from
its training sources only: the model that holds GRID out chooses on an Obama clip and a
lecture stretch, the one that holds Obama out on a GRID clip and a lecture stretch, so the
head's settings are never chosen on the source they are scored on. (The arms have one source,
the lecture: their settings are chosen on a training stretch of it, and scored on its held-out
stretch.) The head aims between GRID's readers and Obama addressing his audience, who moves
his head four to five times more: no model can guess a new speaker's style from the voice.
Its measures are taken against each source's validation clips apart and combined, the std
ratio as the geometric mean of the per-source ratios, so the size term is least at the
geometric mean of the sources' sizes (the shipped model chooses on a GRID and an Obama clip;
a model that holds one source out aims at the other). Every combination
of a correlation of {correlations}, a burstiness of {bursts} and a temperature of
{temperatures} is sampled ({N_SEEDS} samples per clip) and scored per joint group by
mean(H speed, H accel) + |ln(std ratio)|, plus, for the head, the mean |ln| of the ratios of
its speed and acceleration percentiles (p50, p90, p99) to the geometric mean over the sources
of their real motion's, each pooled over all its training and validation clips (the "tail"
column: a clip of a few
seconds holds too few quick nods to judge them, and the Hellinger distance on 0.1 rad/s bins
does not see them). The head's burstiness is then also tried per joint (HeadPitch, HeadYaw:
each pair of two different values of the list), at the best correlation and at the best
temperature and the ones beside it: people turn their heads in rarer, quicker bursts than they
nod (in Obama's addresses the p99/p50 ratio of yaw speed is about 8, of pitch about 6),
which one burstiness for both joints cannot give. The arm part then tries the hip at every
temperature of the list, the arms at the part's best: at the temperature that sizes the
arms' motion the hip sways more than the lecturer's. Every setting samples within the
joints' velocity limits (`velocity_limit` {VELOCITY_LIMIT:g}: a step is clamped to what the
joint can move in 10 ms, and the sampler reads the clamped pose back), so the motion filter's
input gate refuses none of its raw steps. Each part keeps its best correlation,
burstiness and temperature (the head and the arms each have their own noise correlation),
among those whose raw steps the motion filter's input gate would refuse, as faster than the
robot can move, in at most {GATE_BUDGET_PCT:g} % of frames, and, for the arms, within the
body budget and the calm budget: every sample drawn ({N_SEEDS}), on every arm clip and on the
speech without arms, through the motion filter as shipped, has its arm accelerations at the
limiter, and a wrist above the shoulder and more than 10 cm above it, no more often than the
lecturer's training and validation stretches through the same filter (each sample measured
over all that speech, the worst sample's figure counts, its overrun in percentage points like
the body budget's: the robot runs with any seed, and rare long raised-arm bursts show in some
samples only). Then
the highest rest level of {rests} whose speech/pause speed ratio is at least {PAUSE_MARGIN:g}
times the target (head 2, arms and hip 1.5). Fixed, not chosen per build: the noise's order
(2), the gate's margin (1), width (0.2) and time constants, the burst envelope's time constant
(0.5 s). Chosen (every trial is listed in `metrics.txt`):

{chosen}

"""


WHAT_BEGIN = "<!-- begin: what it is (generated from the checkpoint; do not edit by hand) -->"
WHAT_END = "<!-- end: what it is -->"


def what_it_is(checkpoint: Checkpoint) -> str:
    """The card's "What it is" section (its markers are :data:`WHAT_BEGIN`, :data:`WHAT_END`).

    Everything it states (configuration, sampling temperatures, training epoch, validation
    clips) is read from ``checkpoint``, so a later step that changes the shipped checkpoint
    (:mod:`audio2pose_ros.style.population` sets the head's temperature) rewrites it and the
    card cannot describe another model than the one it ships with.
    """
    n_params = sum(p.numel() for p in checkpoint.model.parameters())
    model = cast(LiveGroups, checkpoint.model)  # the learned default is live_groups
    config = model.config
    correlations = model.part_correlations()
    head_burst = format_per_joint(config.first_burst)
    if isinstance(config.first_burst, tuple):
        head_burst += f" ({'/'.join(checkpoint.robot.names[j] for j in model.groups[0])})"
    validation = sorted(checkpoint.info.get("validation_clips", []))
    head_chosen = (
        'chosen over people, see "The head over people" below'
        if "head_temperature_chosen_on" in checkpoint.info
        else "chosen on validation clips, see below"
    )
    return f"""## What it is
`live_groups` (this package's own, `audio2pose_ros/models/live_groups.py`): two causal,
autoregressive GRU samplers side by side, one for HeadPitch and HeadYaw, one for the arms and
HipRoll (config `{checkpoint.model.config_dict()}`, {n_params} parameters). At every 10 ms
frame each reads the {checkpoint.features.label} audio features and its
own previous pose and samples the next pose from a Gaussian, with smooth, time-correlated
noise (correlation {correlations[0]:g} and burstiness {head_burst} for the head,
{correlations[1]:g} and {format_per_joint(config.second_burst)} for the arms:
`audio2pose_ros/models/sampling_noise.py`): it samples
motion instead of regressing to the mean, so it moves like a person rather than like the average
of people. Every utterance starts settled: the model first runs 1 s of the utterance's first
audio frame, discarded, so the first pose does not jump from the network's zero state
(`audio2pose_ros/models/warm_start.py`; offline and online alike). A causal speech gate
(mean filter-bank energy against its recent peak) scales the sampling noise down to
{config.silence_temperature:g} of itself in silence, so the robot comes to rest when nobody
speaks; the head part samples at temperature
{_part_temperature(config.first_temperature, model.groups[0], checkpoint.robot)} ({head_chosen}),
the arm part at {_part_temperature(config.second_temperature, model.groups[1], checkpoint.robot)}
(chosen on validation clips, see below){_velocity_limit(config.velocity_limit)}. It streams
(two GRU cell steps per frame, about 0.1 ms), so `inference_node` runs it. Same seed, same
motion; another seed, another motion on the same audio (`streaming_predictor(seed=N)` online,
`audio2pose_ros.offline.synthesis.synthesize(..., seed=N)` offline; the default seed is 0).
Training kept epoch {checkpoint.info.get("best_epoch", "?")} (validation loss
{float(checkpoint.info.get("best_validation_loss", math.nan)):.5f}; validation clips
{", ".join(validation)}). Rebuild it with `make default-model`."""


def _part_temperature(value: PerJoint, joints: np.ndarray, robot: RobotDescription) -> str:
    """``3``, or one per joint group: ``4 (arms), 1.5 (hip)``."""
    if not isinstance(value, tuple):
        return f"{value:g}"
    groups: dict[str, set[float]] = {}
    for j, v in zip(joints, value, strict=True):
        groups.setdefault(robot.joints[j].group, set()).add(v)
    if any(len(values) > 1 for values in groups.values()):
        return format_per_joint(value)
    return ", ".join(f"{values.pop():g} ({group})" for group, values in groups.items())


def _velocity_limit(share: float) -> str:
    """The sentence part on the sampler's velocity limit, or nothing when it is off."""
    if not share:
        return ""
    limit = "its velocity limit" if share == 1 else f"{share:g} of its velocity limit"
    return (
        f"; no sampled step moves a joint faster than {limit}, so the motion filter's input "
        "gate drops none (`velocity_limit`)"
    )


def write_learned_model_card(
    out_dir: Path,
    checkpoint: Checkpoint,
    heads: Dataset,
    lecture: Dataset,
    reports: Sequence[SourceReport],
    results: Sequence[HoldoutResult],
    body: str,
    style: str,
    command: str,
    calm: str = "",
) -> Path:
    """Write ``out_dir/MODEL_CARD.md`` of the learned default model (``live_groups``).

    ``body`` is the table of :func:`~audio2pose_ros.learning.body_realism.body_table`,
    ``style`` that of :func:`~audio2pose_ros.learning.speech_style.head_style_table`,
    ``command`` the evaluation of the commanded motion
    (:mod:`~audio2pose_ros.learning.command_path`), ``calm`` the table of
    :func:`~audio2pose_ros.learning.arm_calm.arm_calm_table`.

    Also writes its figures: ``summary.png`` (:func:`plot_summary`), ``head_percentiles.png``
    (:func:`plot_percentiles`); the histograms come from the evaluation.
    """
    from audio2pose_ros.data.importers.lecture import BOARD_S, LECTURE_LICENCE, TEST_SPAN_S
    from audio2pose_ros.learning.arm_calm import AT_LIMIT_FRACTION, HIGH_ABOVE_M

    config = cast(LiveGroups, checkpoint.model).config  # the learned default is live_groups
    clips = [heads.load(c.clip_id) for c in heads.clips] + [
        lecture.load(c.clip_id) for c in lecture.clips
    ]
    plot_summary(out_dir / "summary.png", reports)
    plot_percentiles(out_dir / "head_percentiles.png", reports)
    held_out = "\n\n".join(
        f"**{r.heading()}**\n\n```\n{r.quality.table()}\n```\n\n"
        f"![{r.source} histograms]({r.quality.figure.name if r.quality.figure else ''})"
        for r in reports
    )
    card = f"""# Model card: default model (`default.safetensors`)

{WHAT_BEGIN}
{what_it_is(checkpoint)}
{WHAT_END}

## What it learned from people
{_learned_from(checkpoint, clips)}
{_started_from(results)}
- **HeadYaw and HeadPitch**: head rotation measured with MediaPipe FaceMesh in real
  talking-head videos (rigid fit of the canonical face model, unwrapped, outliers rejected,
  4 Hz Butterworth, 100 Hz; each clip's median head pose mapped to the robot's neutral pose).
- **Arms (shoulder and elbow joints) and HipRoll**: upper-body pose of a lecturer measured
  with MediaPipe Pose (world landmarks) where both his arms are visible, retargeted to Pepper
  by inverting its kinematic chain (`audio2pose_ros/data/importers/upper_body.py`); frames
  without visible arms are masked out of training, not filled, and so are his stretches at
  the board (a wrist held above the shoulder for {BOARD_S:g} s or more: writing or pointing,
  not gesturing while talking; `board_frames` in
  `audio2pose_ros/data/importers/lecture.py`). The head is not labelled in the
  lecture, the arms not in the talking heads: each part of the model learns only from the
  clips that label its joints.
- The hand-written prosody rule is **not** used; it remains available as the explicitly named
  option `audio2pose dataset build-default --arms prosody` (and the filter's `arms_gain` /
  `hip_gain`).

## Data and licences (attribution required)
- 8 clips of the **GRID audio-visual sentence corpus** (Cooke, Barker, Cunningham and Shao, 2006,
  "An audio-visual corpus for speech perception and automatic speech recognition", JASA
  120(5)), **CC BY 4.0**: this attribution must accompany the model and anything derived from it.
- 5 sentences of the **US President's weekly addresses** (Obama), works of the US federal
  government, **public domain**.
- {LECTURE_LICENCE}.

Talking-head clips: {len(heads.clips)} ({len(heads.speakers)} speakers). Lecture: the stretches
with both arms visible, not at the board; the stretch from {TEST_SPAN_S[0]:.0f} s to
{TEST_SPAN_S[1]:.0f} s (at the blackboard, gesturing between writing) is held out of every
training.

## How it was evaluated: whole recording sources held out
A score on speakers of the recordings a model trained on does not predict how it does on new
recordings, so `make default-model` trains, besides the shipped model, one model per
talking-head source held out whole (`audio2pose_ros/learning/source_holdout.py`): one without
any GRID clip, scored on all GRID clips; one without any Obama clip, scored on all Obama clips.
Each also learns the arms from the lecture, stops early and chooses its sampling settings on
validation clips of its own training sources. The lecture is the only recording that shows
arms: the arms and hip are scored on its held-out stretch with the shipped model.

Measures (`audio2pose_ros/learning/evaluation.py`, `metrics.py`, `realism.py`), per joint
group, generated against real motion of the held-out clips:
- Hellinger distances between histograms of joint speed and of acceleration (per joint,
  averaged), the standard deviation relative to real, the ratio of joint speed in speech to
  that in a pause (1.5 s of quiet inserted into the held-out audio). Estimates are
  **bias-corrected** and their intervals are 95 % bootstrap intervals over 1 s segments of the
  bias-corrected estimator (Efron and Tibshirani 1993, section 10.6; `metrics.bias_corrected`):
  a distance between histograms is biased upwards by sampling noise, more so in a bootstrap
  resample, so a plain percentile interval can lie wholly above its own value. The plug-in
  Hellinger values (not corrected, what a direct computation gives) are listed beside them.
  The intervals cover the choice of segments, not the sampler's randomness nor the training's.
- A floor, "real (split half)": the same distances between two halves of the real motion
  (alternate seconds), computed the same way. A model cannot be expected below it.
- The Fréchet distance of 1 s windows of joint angles (principal components of the real
  windows), half of the clips against the other half, with its real-vs-real floor; L1
  diversity and jerk relative to real; EMAGE's beat consistency (BC: audio onsets against
  minima of the group's angular speed, sigma 0.3 s) with the clip's own audio and with another
  clip's (shuffled audio); speed and acceleration percentiles p50 / p90 / p99 per joint.
- Baselines on the same clips: a static pose, real motion of another held-out clip of another
  speaker where there is one ("mismatched real motion": every clip's motion is used once, so
  its pooled histograms are the real ones and its Hellinger distances are about 0 by
  construction; it is a baseline for RMSE, LCCA and BC), real motion of the other talking-head
  source (head) or of the lecture's training stretches (arms), and for the arms the
  hand-written prosody rule.

Print it again: `make default-model` (it writes `metrics.txt`, the tables below).

![summary](summary.png)

![head percentiles](head_percentiles.png)

### Goals per held-out source

Scored on the offline synthesis (`audio2pose synth`). What the motion filter commands from the
same samples, against what Pepper's limits allow the real motion, is in the section "On the
robot" below: there the arms' accelerations are limited by the robot, not by the model.

| source | group | measure | goal | measured [95 % CI] | |
|---|---|---|---|---|---|
{_checks_table(reports)}

{_selection(results)}## Held-out numbers

{held_out}

## The head on new voices

The two talking-head sources differ in style more than any model does, so the held-out scores
above say as much about GRID and Obama as about the model. On speech of other speakers that no
step of the build used (the bundled LibriVox clips, no video), this is how the shipped model's
head moves, beside the real motion of each source
(`audio2pose_ros/learning/speech_style.py`): speed and acceleration percentiles, the
standard deviation of the angle per clip, and beat consistency (BC) with each clip's own audio
and with another clip's motion of the same seed or source (shuffled). BC is only evidence that
the head moves in time with the speech where it is above its shuffled value: on speech with
frequent onsets, any motion's turns land near some onset. Last, how many of the model's 12
percentiles lie within 25 % of each source's, as the goals above count them.

```
{style}
```

## On the robot: what the motion filter commands

Every table above scores the offline synthesis (`audio2pose synth`: the raw samples through
the seed's zero-phase 4 Hz Butterworth). On the robot, `motion_filter_node` moves the joints:
a causal smoother (by default a 3 Hz, 2nd-order Butterworth run forwards, `smoothing:
lowpass`), Pepper's velocity limits (half of them by default) and acceleration limits, and the
self-collision guard. Here the raw samples of each held-out source (the head: the model that
never saw that source; the arms and hip: the shipped model on the lecture's held-out stretch)
go through that filter's own code, one 10 ms tick per frame
(`audio2pose_ros/learning/command_path.py`), with the shipped smoother, with the seed's own
Butterworth (4 Hz, 5th order) run forwards and with the seed's Kalman filter (`smoothing:
kalman`, section 4.4.2); and the real motion goes through the filter as shipped. Each
heading gives how far each smoother's commands trail the offline synthesis. The shipped
smoother was chosen on the lecture's training and validation stretches, not on the held-out
one: of the Butterworth filters tried (2.5 to 4 Hz; orders 2, 3 and 5), the one with the least
delay whose commanded arms and hip were at least as close to the lecturer's (H speed and H
accel) as with the seed's: 0.13 s behind the offline synthesis there, against 0.19 s.
First-order filters delayed as little but raised the commanded jerk 1.4 to 2.4 times. The
real motion's distances to itself ("real, commanded") are what the robot's limits alone cost:
the lecturer's retargeted arms accelerate faster than Pepper's limits allow in many frames, so
no commanded motion can be expected closer to the real than that row.

```
{command}
```

## Calm arms: what a person talking does, through the same filter

A default model meets people it has never seen: its arms should move like someone in an
ordinary conversation, not like a lecturer at a board. Two figures say how far from that the
commanded arms are (`audio2pose_ros/learning/arm_calm.py`), for the model and for the real
people's motion through the same filter (the shipped `motion_filter_node` core; the robot's
limits cost both alike): the share of arm joint-frames whose commanded acceleration is at the
limiter (within {AT_LIMIT_FRACTION * 100:g} % of the joint's acceleration limit: braked and
launched at the limit, bang-bang), and the share of frames with a wrist above its shoulder's
height, and more than {HIGH_ABOVE_M * 100:g} cm above it. Beside them, the speed and
acceleration percentiles of the shoulder-pitch and elbow-yaw joints, left and right pooled.
The people's figures ("people") are the lecturer's talking stretches, those the arm part
trains and chooses its settings on (the board stretches masked): the arm part's sampling
settings are chosen within them (the calm budget of
`audio2pose_ros/learning/sampler_selection.py`, on every sample drawn, the worst counting: a
robot runs with any seed). Print it for any model and speech:
`audio2pose check-arms [--model M] FILE.wav ...`.

```
{calm}
```

## The arms and the body

Retargeted arms were moved clear of Pepper's body before training (the importers' last step,
`audio2pose_ros/data/importers/body_clearance.py`). The arm part samples with the body in mind
(`audio2pose_ros/models/body_noise.py`): its noise fades, over 0.2 s at least, as the previous
pose comes within {config.body_band_m * 100:g} cm of the guard's margin
({config.body_margin_m * 100:g} cm), so
near the body the pose is the network's mean, which learned from clear poses; the pose itself
is never moved. Its sampling settings keep it off the body on the validation clips and on the
speech of the talking-head clips it trained on, which label no arms ({N_SEEDS} samples each;
see above). On the
lecture's held-out stretch, the model's raw motion (before the robot's self-collision guard),
how often it comes closer to the body than the guard's margin or goes inside it, and how far
its wrists' positions in the torso frame are from the real ones (Hellinger distance per axis;
the right wrist mirrored onto the left; `audio2pose_ros/learning/body_realism.py`); the real
stretch's halves are the floor. Then the same share on speech of other speakers that no step
of the build used (the bundled LibriVox clips), at several seeds: the worst seed shows how far
one sample can stray; and the same again with the arm noise blind to the body.

```
{body}
```

## What it does not cover
- The head learned from short clips of read or addressed speech (GRID sentences read to a
  camera, Obama's weekly addresses): front-facing, English. GRID's readers hold their heads
  far stiller than Obama, so a model trained on one source and scored on the other shows how
  much the sources differ as much as how the model does. The shipped head's sampling settings
  aim between them (the geometric mean of their sizes and of their speed and acceleration
  percentiles), chosen on one validation clip of each; the motion filter's `head_gain` (0 to
  1) scales the head's motion down for a stiller robot.
- The arms learned from one lecturer (his style, often holding a ball or handling
  apparatus, 240p video at 15 fps: fast hand motion is blurred); they are scored on a held-out
  stretch of the same lecture, not on a new speaker.
- Pepper's shoulder-roll and elbow-roll limits lie where a person's arm hangs against the
  body or straight: the retargeted lecturer sits at one of them in about half of his training
  frames, so the model's arms often rest at a joint limit too (the motion filter keeps its
  margin from the limits on the robot).
- No hands, gaze, translation or head roll. Pose estimates from video have errors of a few
  degrees (head) to tens of degrees (elbow yaw at low resolution); the targets inherit them.
"""
    path = out_dir / "MODEL_CARD.md"
    path.write_text(with_style_section(path, card), encoding="utf-8")
    return path
