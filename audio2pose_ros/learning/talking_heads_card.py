"""MODEL_CARD.md of a model trained on the talking heads alone.

``audio2pose dataset build-default --arms prosody|neutral``
(:func:`~audio2pose_ros.learning.default_model.build_default_model`): data, licences, split,
metrics against the baselines, limits.
"""

from __future__ import annotations

from pathlib import Path

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Dataset
from audio2pose_ros.learning.evaluation import Evaluation
from audio2pose_ros.learning.style_card import with_style_section
from audio2pose_ros.learning.train_state import TrainReport
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
Rebuild it with `audio2pose dataset build-default` (see doc/training.md); training stopped at epoch
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
    path.write_text(with_style_section(path, card), encoding="utf-8")
    return path
