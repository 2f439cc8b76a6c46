"""MODEL_CARD.md of the default model rebuilt by :mod:`audio2pose_ros.learning.default_model`."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import cast

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.learning.evaluation import Evaluation, GroupRow, QualityEvaluation
from audio2pose_ros.learning.sampler_selection import (
    BURSTS,
    CORRELATIONS,
    INNER_FOLDS,
    N_SEEDS,
    PAUSE_MARGIN,
    SILENCE_TEMPERATURES,
    TEMPERATURES,
    SamplingChoice,
)
from audio2pose_ros.learning.train_state import TrainReport
from audio2pose_ros.models.live_groups import LiveGroups
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

_ARMS_TEXT = {
    "prosody": (
        "**Arms and hip are not learned from people.** No clip shows them, so in the training "
        "copy of the data their angles come from the hand-written prosody rule "
        "(`audio2pose_ros.motion.prosody.ProsodyRule`: loudness raises the forearms, the "
        "spectral balance of the voice sways the hip and makes the arms asymmetric). The model "
        "imitates that rule for these joints: a labelled procedural layer, not learned gesture. "
        "Keep the arms still with `arms_gain: 0.0` and `hip_gain: 0.0` (motion_filter_node), "
        "or rebuild with `--arms neutral`."
    ),
    "neutral": (
        "**Arms and hip stay at the neutral pose.** No clip shows them; the model was trained to "
        "hold them still."
    ),
}


def _clip_rows(dataset: Dataset) -> str:
    rows = []
    for info in dataset.clips:
        seconds = dataset.load(info.clip_id).audio.size / SAMPLE_RATE_HZ
        rows.append(f"| {info.clip_id} | {info.speaker} | {info.split} | {seconds:.1f} |")
    return "\n".join(rows)


# metric, True when lower is better
_COMPARED = (("RMSE deg", True), ("LCCA_Theta", False), ("H speed", True), ("H accel", True))


def _verdicts(evaluation: Evaluation) -> str:
    """One line per baseline: the metrics where the model (last method) is better or worse."""
    rows = {m.name: m.row() for m in evaluation.methods}
    model_name = evaluation.methods[-1].name
    model = rows.pop(model_name)
    lines = []
    for baseline, row in rows.items():
        better: list[str] = []
        worse: list[str] = []
        for metric, lower in _COMPARED:
            if row[metric] != row[metric] or model[metric] == row[metric]:  # NaN or tie
                continue
            wins = model[metric] < row[metric] if lower else model[metric] > row[metric]
            cell = f"{metric} {model[metric]:.3f} vs {row[metric]:.3f}"
            (better if wins else worse).append(cell)
        lines.append(
            f"- against *{baseline}*: better in {', '.join(better) or 'nothing'}; "
            f"worse in {', '.join(worse) or 'nothing'}."
        )
    return "\n".join(lines)


def write_default_model_card(
    out_dir: Path,
    checkpoint: Checkpoint,
    report: TrainReport,
    dataset: Dataset,
    evaluation: Evaluation,
    arms: str,
) -> Path:
    """Write ``out_dir/MODEL_CARD.md``: data, licences, split, metrics, limits."""
    n_params = sum(p.numel() for p in checkpoint.model.parameters())
    card = f"""# Model card: default model (`default.safetensors`)

## What it is
A frame-wise MLP (seed 003 section 4.3.3; config `{checkpoint.model.config_dict()}`,
{n_params} parameters) from {checkpoint.features.label} audio features to
Pepper's {checkpoint.robot.n_joints} joints. It streams (no state), so `inference_node` runs it.
Rebuild it with `audio2pose dataset build-default` (see README); training stopped at epoch
{report.best_epoch} (validation loss {report.best_val_loss:.5f}).

## What it learned from people, and what it did not
- **HeadYaw and HeadPitch are learned from real people**: head rotation measured with MediaPipe
  FaceMesh in 13 real talking-head videos (`audio2pose dataset import-video`: rigid fit of the
  canonical face model, unwrapped, outliers rejected, 4 Hz Butterworth, 100 Hz). Each clip's
  median head pose is mapped to the robot's neutral pose, so the model learns motion around
  neutral, not where a camera stood. Head roll was measured and is kept in the data set's
  extras; Pepper has no roll joint and the model does not output it.
- {_ARMS_TEXT[arms]}

## Data and licences (attribution required)
- 8 clips of the **GRID audio-visual sentence corpus** (Cooke, Barker, Cunningham and Shao, 2006,
  "An audio-visual corpus for speech perception and automatic speech recognition", JASA
  120(5)), **CC BY 4.0**: this attribution must accompany the model and anything derived from it.
- 5 sentences of the **US President's weekly addresses** (Obama), works of the US federal
  government, **public domain**.

Split by clip: test holds one GRID speaker never seen in training and one Obama clip; validation
one of each; the rest trains. {len(dataset.clips)} clips:

| clip | speaker | split | seconds |
|---|---|---|---|
{_clip_rows(dataset)}

## Metrics on the held-out (test) clips
Computed by `audio2pose_ros.learning.evaluation.evaluate` (the code of `audio2pose evaluate`) after
the
seed's post-processing. Only the head joints have ground truth, so every number is over
HeadYaw and HeadPitch. Baselines: static neutral pose, mean training pose, and real head motion
of another utterance of the same speaker (the GRID test speaker has no other utterance, so that
baseline covers only the Obama clip).

```
{evaluation.table()}
```

Where the model ({evaluation.methods[-1].name}) beats the baselines and where it does not
(RMSE, Hellinger distances of speed and acceleration: lower is better; LCCA_Theta: higher is
better):

{_verdicts(evaluation)}

How to read it: 2 test clips (about 10 s of speech), so the numbers are indicative only. The
head moves little in these clips, and each clip's median head pose is the neutral pose, so the
static baselines are strong on RMSE and the mean training pose equals the neutral pose. RMSE
rewards holding still; LCCA_Theta, the Hellinger distances and jerk say whether the motion
resembles real head motion.

## What it does not cover
- 13 short clips (under a minute of speech), 9 speakers, English, front-facing read or
  addressed speech: expect little head motion and little generalisation to other voices,
  languages or conversational styles. Train a speaker-dependent model on your own recordings for
  more (seed 003 found those clearly better).
- No arm, hand or hip motion of people was seen (see above). No gaze, no translation, no roll.
- FaceMesh's pose estimate has errors of a few degrees; the targets inherit them.
"""
    path = out_dir / "MODEL_CARD.md"
    path.write_text(card, encoding="utf-8")
    return path


def _row(evaluation: QualityEvaluation, group: str, method: str) -> GroupRow | None:
    return next((r for r in evaluation.rows if r.group == group and r.method == method), None)


def _targets(head: QualityEvaluation, arms: QualityEvaluation, model: str) -> str:
    """The realism targets for the model's head and arms, met or not, with the measured values.

    The arms' Hellinger distances are also compared with the static pose's and the prosody
    rule's on the same clips (the model must be clearly better than those baselines): met when
    the model's value lies below the baseline's whole bootstrap interval.
    """
    from audio2pose_ros.learning.default_model import PROSODY_RULE
    from audio2pose_ros.learning.evaluation import STATIC

    def within(low: float, high: float) -> Callable[[float], bool]:
        return lambda v: low <= v <= high

    def below(baseline: str, measure: str) -> Callable[[float], bool]:
        row = _row(arms, "arms", baseline)
        return lambda v: row is not None and v < min(row.measures[measure][:2])

    loso = "live_groups (LOSO)"
    checks = [
        ("head", head, loso, "H speed", "<= 0.15", within(0.0, 0.15)),
        ("head", head, loso, "H accel", "<= 0.15", within(0.0, 0.15)),
        ("head", head, loso, "std ratio", "0.7 to 1.4", within(0.7, 1.4)),
        ("head", head, loso, "speech/pause speed", ">= 2", within(2.0, math.inf)),
        ("arms", arms, model, "std ratio", "0.7 to 1.4", within(0.7, 1.4)),
        ("arms", arms, model, "speech/pause speed", ">= 1.5", within(1.5, math.inf)),
    ]
    for measure in ("H speed", "H accel"):
        checks.append(("arms", arms, model, measure, "<= 0.15 (aim)", within(0.0, 0.15)))
        for baseline in (STATIC, PROSODY_RULE):
            target = f"below the {baseline}'s interval"
            checks.append(("arms", arms, model, measure, target, below(baseline, measure)))
    # HipRoll (the trunk's lean), held to the arms' aims
    checks += [
        ("hip", arms, model, "H speed", "<= 0.15 (aim)", within(0.0, 0.15)),
        ("hip", arms, model, "H accel", "<= 0.15 (aim)", within(0.0, 0.15)),
        ("hip", arms, model, "std ratio", "0.7 to 1.4 (aim)", within(0.7, 1.4)),
        ("hip", arms, model, "speech/pause speed", ">= 1.5", within(1.5, math.inf)),
    ]
    lines = []
    for group, evaluation, method, measure, target, ok in checks:
        row = _row(evaluation, group, method)
        if row is None:
            continue
        value, low, high = row.measures[measure]
        verdict = "met" if value == value and ok(value) else "**not met**"
        lines.append(
            f"| {group} | {measure} | {target} | {value:.2f} [{low:.2f}, {high:.2f}] | {verdict} |"
        )
    return "\n".join(lines)


def _selection(choice: SamplingChoice, folds: dict[str, str]) -> str:
    """The card's account of how the sampling settings were chosen, with every trial."""
    fold_lines = "\n".join(f"{speaker} held out: {note}" for speaker, note in folds.items())
    temperatures = ", ".join(f"{t:g}" for t in TEMPERATURES)
    bursts = ", ".join(f"{t:g}" for t in BURSTS)
    correlations = ", ".join(f"{t:g}" for t in CORRELATIONS)
    rests = ", ".join(f"{t:g}" for t in SILENCE_TEMPERATURES)
    return f"""## How the sampling settings were chosen (validation, not test)
The noise's correlation, the part temperatures and burstiness, and the gate's rest level in
silence act only when sampling, so `make default-model` chooses them after training
(`audio2pose_ros/learning/sampler_selection.py`), never on a clip reported below. Evidence: for
the head, {INNER_FOLDS}-fold cross-validation over the talking-head speakers (every speaker's
clips sampled by a model trained without that speaker); for the arms and hip, the shipped model
on its validation stretch of the lecture. Every combination of a correlation of {correlations},
a burstiness of {bursts} and a temperature of {temperatures} is sampled ({N_SEEDS} samples per
clip) and scored per joint group by mean(H speed, H accel) + |ln(std ratio)|; each part keeps
its best burstiness and temperature, and the shared correlation is the one whose parts' best
scores sum lowest. Then the highest rest level of {rests} whose speech/pause speed ratio is at
least {PAUSE_MARGIN:g} times the target (head 2, arms and hip 1.5). Every
leave-one-speaker-out fold below chooses its own in the same way by cross-validation over its
own training speakers only (never the held-out one), so the head numbers measure the whole
procedure. Fixed, not chosen per build (set in an earlier session while the lecture's test
stretch was in view): the noise's order (2), the gate's margin (1), width (0.2) and time
constants, the burst envelope's time constant (0.5 s).

Shipped model:

```
{choice.table()}
```

Leave-one-speaker-out folds (head part; their arm part is untrained):

```
{fold_lines}
```

"""


def write_learned_model_card(
    out_dir: Path,
    checkpoint: Checkpoint,
    report: TrainReport,
    heads: Dataset,
    lecture: Dataset,
    head: QualityEvaluation,
    arms: QualityEvaluation,
    choice: SamplingChoice,
    fold_choices: dict[str, str],
) -> Path:
    """Write ``out_dir/MODEL_CARD.md`` of the learned default model (``live_groups``)."""
    from audio2pose_ros.data.importers.lecture import LECTURE_LICENCE, TEST_SPAN_S

    n_params = sum(p.numel() for p in checkpoint.model.parameters())
    model_label = next(r.method for r in arms.rows if r.method.startswith("live_groups"))
    config = cast(LiveGroups, checkpoint.model).config  # the learned default is live_groups
    validation = sorted(checkpoint.info.get("validation_clips", []))
    lecture_seconds = {
        split: sum(
            lecture.load(c.clip_id).n_frames / 100.0 for c in lecture.clips if c.split == split
        )
        for split in ("train", "test")
    }
    card = f"""# Model card: default model (`default.safetensors`)

## What it is
`live_groups` (this package's own, `audio2pose_ros/models/live_groups.py`): two causal,
autoregressive GRU samplers side by side, one for HeadPitch and HeadYaw, one for the arms and
HipRoll (config `{checkpoint.model.config_dict()}`, {n_params} parameters). At every 10 ms
frame each reads the {checkpoint.features.label} audio features and its
own previous pose and samples the next pose from a Gaussian, with smooth, time-correlated
noise (correlation {config.noise_correlation:g}, burstiness {config.first_burst:g} for the head
and {config.second_burst:g} for the arms: `audio2pose_ros/models/sampling_noise.py`): it samples
motion instead of regressing to the mean, so it moves like a person rather than like the average
of people. Every utterance starts settled: the model first runs 1 s of the utterance's first
audio frame, discarded, so the first pose does not jump from the network's zero state
(`audio2pose_ros/models/warm_start.py`; offline and online alike). A causal speech gate
(mean filter-bank energy against its recent peak) scales the sampling noise down to
{config.silence_temperature:g} of itself in silence, so the robot comes to rest when nobody
speaks; the head part samples at temperature {config.first_temperature:g}, the arm part at
{config.second_temperature:g} (chosen on validation clips, see below). It streams
(two GRU cell steps per frame, about 0.1 ms), so `inference_node` runs it. Same seed, same
motion; another seed, another motion on the same audio (`streaming_predictor(seed=N)` online,
`audio2pose_ros.offline.synthesis.synthesize(..., seed=N)` offline; the default seed is 0).
Training kept epoch {report.best_epoch} (validation loss {report.best_val_loss:.5f};
validation clips {", ".join(validation)}). Rebuild it with `make default-model`.

## What it learned from people
- **HeadYaw and HeadPitch**: head rotation measured with MediaPipe FaceMesh in 13 real
  talking-head videos (rigid fit of the canonical face model, unwrapped, outliers rejected,
  4 Hz Butterworth, 100 Hz; each clip's median head pose mapped to the robot's neutral pose).
- **Arms (shoulder and elbow joints) and HipRoll**: upper-body pose of a lecturer measured
  with MediaPipe Pose (world landmarks) where both his arms are visible
  ({lecture_seconds["train"]:.0f} s of training stretches), retargeted to Pepper by inverting
  its kinematic chain (`audio2pose_ros/data/importers/upper_body.py`); frames without visible arms
  are masked out of training, not filled. The head is not labelled in the lecture, the arms
  not in the talking heads: each part of the model learns only from the clips that label its
  joints.
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
with both arms visible, {lecture_seconds["train"]:.0f} s for training and
{lecture_seconds["test"]:.0f} s held out (the stretch from {TEST_SPAN_S[0]:.0f} s to
{TEST_SPAN_S[1]:.0f} s, at the blackboard).

## How it does where it was not trained
Printed by `audio2pose evaluate` (`audio2pose_ros.learning.evaluation.quality_evaluation`); the same
table is in `metrics.txt`, the histograms in `head_distributions.png` and
`arms_distributions.png`. Per joint group: Hellinger distances between histograms of joint
speed and of acceleration, generated vs real, per joint and averaged over the group (0 = same
distribution); the standard deviation of the motion relative to real; the ratio of joint speed
during speech to that in silences of at least 1 s (energy VAD; "speech/pause": on the held-out
audio with 1.5 s of quiet inserted, since the clips hardly pause); RMSE and LCCA (seed 003
Table 5.1, of the sample with seed 0); diversity (mean RMS distance between samples with seeds
0, 1, 2). The distribution measures pool the three samples segment by segment, which averages
out part of the sampler's own randomness. Brackets: 95 % percentile bootstrap intervals over
1 s segments (a Hellinger distance between histograms of resampled, duplicated segments is
biased upwards, so a small value can sit below its interval); they cover the choice of
segments, not the sampler's randomness nor the training's. Baselines on the same clips: a
static pose (floor), real motion of another held-out clip of another speaker (ceiling) and, for
the arms, the hand-written prosody rule. The sampling settings were chosen on validation clips
(next section), not on these.

{_selection(choice, fold_choices)}## Held-out numbers

**Head, leave one speaker out** over the {len(heads.clips)} talking-head clips (each fold
trains `live_groups`, and the seed's `mlp` for comparison, on the other speakers):

```
{head.table()}
```

![head histograms](head_distributions.png)

**Arms and hip, held-out lecture stretch** (the model above, never trained on it):

```
{arms.table()}
```

![arm and hip histograms](arms_distributions.png)

Realism targets:

| group | measure | target | measured [95 % CI] | |
|---|---|---|---|---|
{_targets(head, arms, model_label)}

## What it does not cover
- The head learned from 13 short clips (under a minute of speech, 9 speakers, English,
  front-facing read speech); the arms from one lecturer (his style, often holding a ball or
  handling apparatus, 240p video at 15 fps: fast hand motion is blurred).
- The arm and hip measures come from a single speaker's held-out stretch of about
  {lecture_seconds["test"]:.0f} s: indicative, with wide intervals.
- Pepper's shoulder-roll and elbow-roll limits lie where a person's arm hangs against the
  body or straight: the retargeted lecturer sits at one of them in about half of his training
  frames, so the model's arms often rest at a joint limit too (the motion filter keeps its
  margin from the limits on the robot).
- No hands, gaze, translation or head roll. Pose estimates from video have errors of a few
  degrees (head) to tens of degrees (elbow yaw at low resolution); the targets inherit them.
"""
    path = out_dir / "MODEL_CARD.md"
    path.write_text(card, encoding="utf-8")
    return path
