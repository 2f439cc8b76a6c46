"""Compare trained models and baselines on a data set split (``audio2pose evaluate``).

Every model is evaluated after the seed's post-processing (seed 003 section 4.3.3: predictions
mapped back with nu^-1, smoothed by the zero-phase 4 Hz Butterworth filter, clamped to the limits:
:func:`audio2pose_ros.offline.synthesis.synthesize`); samplers are evaluated on one sample with a
fixed seed, and their diversity on ``n_samples`` samples. The baselines are those of the field: the
static neutral pose, the mean training motion (the mean pose of the training clips, held still) and
real motion from a different utterance of the same speaker (cut or repeated to the clip's length).
Metrics: :mod:`audio2pose_ros.learning.metrics` (seed 003 section 3.4 and GENEA's Hellinger
distances), averaged over clips. One PNG per clip shows the audio waveform and, for every joint,
the ground truth and each model's prediction. The samples that the pooled measures of
:mod:`audio2pose_ros.learning.quality` score (leave-one-speaker-out folds, checkpoints on held-out
clips, with and without an inserted pause) are made here too.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.audio.features import FeatureSpec, extract_features
from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip, Dataset
from audio2pose_ros.learning import metrics
from audio2pose_ros.learning.quality import (
    EvaluationError,
    Predictions,
    fit_length,
    save_figure,
    with_pause,
)
from audio2pose_ros.learning.training import TrainSettings
from audio2pose_ros.offline.synthesis import synthesize_samples
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLE_RATE_HZ

if TYPE_CHECKING:
    pass

NEUTRAL = "neutral pose"
MEAN_MOTION = "mean training motion"
OTHER_UTTERANCE = "other utterance, same speaker"
COLUMNS = (
    ("L", "{:.4f}"),
    ("RMSE deg", "{:.2f}"),
    ("LCCA_Theta", "{:.3f}"),
    ("Delta LCCA", "{:.3f}"),
    ("J 1e3 rad2/s5", "{:.2f}"),
    ("Delta J 1e3", "{:.2f}"),
    ("H speed", "{:.3f}"),
    ("H accel", "{:.3f}"),
    ("diversity deg", "{:.2f}"),
)


@dataclass
class MethodResult:
    """Metrics of one model or baseline, per clip; :meth:`row` averages them."""

    name: str
    per_clip: list[dict[str, float]] = field(default_factory=list)

    def row(self) -> dict[str, float]:
        """Mean of each metric over the clips where it is defined."""
        out = {}
        for column, _ in COLUMNS:
            values = [c[column] for c in self.per_clip if not math.isnan(c.get(column, math.nan))]
            out[column] = float(np.mean(values)) if values else math.nan
        return out


def clip_metrics(
    features: np.ndarray,
    true_rad: np.ndarray,
    pred_rad: np.ndarray,
    mask: np.ndarray,
    robot: RobotDescription,
    rate_hz: float = FRAME_RATE_HZ,
) -> dict[str, float]:
    """All seed 003 section 3.4 metrics and GENEA Hellinger distances of one clip."""
    return {
        "L": metrics.loss_l(robot.normalize(true_rad), robot.normalize(pred_rad), mask),
        "RMSE deg": metrics.rmse_deg(true_rad, pred_rad, mask),
        "LCCA_Theta": metrics.lcca_theta(true_rad, pred_rad, rate_hz, mask),
        "Delta LCCA": metrics.delta_lcca(features, true_rad, pred_rad, rate_hz, mask),
        "J 1e3 rad2/s5": metrics.jerk(pred_rad, rate_hz, mask) / 1e3,
        "Delta J 1e3": metrics.delta_jerk(true_rad, pred_rad, rate_hz, mask) / 1e3,
        "H speed": metrics.hellinger_speed(true_rad, pred_rad, rate_hz, mask),
        "H accel": metrics.hellinger_acceleration(true_rad, pred_rad, rate_hz, mask),
    }


def _mean_training_pose(dataset: Dataset, robot: RobotDescription) -> np.ndarray:
    total, count = np.zeros(robot.n_joints), np.zeros(robot.n_joints)
    for clip in dataset.iter_split("train"):
        total += np.where(clip.mask, np.nan_to_num(clip.angles_rad), 0.0).sum(axis=0)
        count += clip.mask.sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), robot.neutral_rad)


def _other_utterance(dataset: Dataset, clip: Clip) -> Clip | None:
    """Another clip of the same speaker: the next one in index order, wrapping around."""
    same = [c for c in dataset.clips if c.speaker == clip.info.speaker]
    if len(same) < 2:
        return None
    index = next(i for i, c in enumerate(same) if c.clip_id == clip.info.clip_id)
    return dataset.load(same[(index + 1) % len(same)].clip_id)


def _model_label(checkpoint: Checkpoint, path: Path) -> str:
    return f"{checkpoint.model.name} ({path.stem})"


@dataclass
class Evaluation:
    """Results of :func:`evaluate`: one entry per method, in table order, and the PNGs."""

    methods: list[MethodResult]
    clips: list[str]
    figures: list[Path] = field(default_factory=list)

    def table(self) -> str:
        """A plain-text table: one row per method, one column per metric (means over clips)."""
        width = max(len(m.name) for m in self.methods) + 2
        header = f"{'method':<{width}}" + "".join(f"{c:>15}" for c, _ in COLUMNS)
        lines = [f"{len(self.clips)} clips", header]
        for method in self.methods:
            row = method.row()
            cells = "".join(
                f"{'-' if math.isnan(row[c]) else fmt.format(row[c]):>15}" for c, fmt in COLUMNS
            )
            lines.append(f"{method.name:<{width}}{cells}")
        return "\n".join(lines)


def evaluate(
    checkpoints: Sequence[tuple[Path, Checkpoint]],
    dataset: Dataset,
    robot: RobotDescription,
    split: str = "test",
    out_dir: Path | None = None,
    n_samples: int = 3,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Evaluation:
    """Evaluate models and baselines on every clip of ``split``.

    Args:
        checkpoints: (path, loaded checkpoint) pairs; all must be made for ``robot``.
        dataset: the data set.
        robot: joint order and ranges.
        split: 'train', 'validation' or 'test'.
        out_dir: write one PNG per clip here; None = no figures.
        n_samples: samples per clip for the diversity of samplers.
        seed: seed of the samplers' noise.
        progress: called with each clip id before it is evaluated.

    Raises:
        EvaluationError: no clips in the split.

    """
    clips = list(dataset.iter_split(split))
    if not clips:
        raise EvaluationError(f"{dataset.root}: no clips in split {split!r}")
    mean_pose = _mean_training_pose(dataset, robot)
    methods = [MethodResult(NEUTRAL), MethodResult(MEAN_MOTION), MethodResult(OTHER_UTTERANCE)]
    methods += [MethodResult(_model_label(ckpt, path)) for path, ckpt in checkpoints]
    evaluation = Evaluation(methods, [c.info.clip_id for c in clips])
    for clip in clips:
        if progress is not None:
            progress(clip.info.clip_id)
        features = extract_features(clip.audio, FeatureSpec())
        drawn = [  # seed, seed + 1, ...: the first is the prediction, all give the diversity
            synthesize_samples(
                ckpt,
                clip.audio,
                range(seed, seed + (n_samples if ckpt.model.stochastic and n_samples >= 2 else 1)),
            )
            for _, ckpt in checkpoints
        ]
        predictions = {
            _model_label(ckpt, path): samples[0]
            for (path, ckpt), samples in zip(checkpoints, drawn, strict=True)
        }
        n = min(clip.n_frames, features.shape[0], *(p.shape[0] for p in predictions.values()))
        true, mask = clip.angles_rad[:n], clip.mask[:n]
        true = np.where(mask, np.nan_to_num(true), robot.neutral_rad)
        candidates = {
            NEUTRAL: np.broadcast_to(robot.neutral_rad, true.shape),
            MEAN_MOTION: np.broadcast_to(mean_pose, true.shape),
        }
        other = _other_utterance(dataset, clip)
        if other is not None:
            candidates[OTHER_UTTERANCE] = fit_length(
                np.where(other.mask, np.nan_to_num(other.angles_rad), mean_pose), n
            )
        candidates |= {name: pred[:n] for name, pred in predictions.items()}
        for method in methods:
            if method.name not in candidates:
                method.per_clip.append({})
                continue
            method.per_clip.append(
                clip_metrics(features[:n], true, candidates[method.name], mask, robot)
            )
        for samples, method in zip(drawn, methods[3:], strict=True):
            if len(samples) >= 2:
                stacked = np.stack([sample[:n] for sample in samples])
                method.per_clip[-1]["diversity deg"] = metrics.diversity_deg(stacked)
        if out_dir is not None:
            evaluation.figures.append(
                plot_clip(out_dir / f"{clip.info.clip_id}.png", clip, true, predictions, robot)
            )
    return evaluation


def plot_clip(
    path: Path,
    clip: Clip,
    true_rad: np.ndarray,
    predictions: dict[str, np.ndarray],
    robot: RobotDescription,
) -> Path:
    """One PNG: the waveform on top, then every joint's ground truth and predictions (degrees)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    n = true_rad.shape[0]
    times_s = np.arange(n) / FRAME_RATE_HZ
    fig, axes = plt.subplots(
        robot.n_joints + 1, 1, figsize=(10, 2 + 1.3 * robot.n_joints), sharex=True
    )
    audio_times_s = np.arange(clip.audio.shape[0]) / SAMPLE_RATE_HZ
    axes[0].plot(audio_times_s, clip.audio, color="0.5", linewidth=0.3)
    axes[0].set_ylabel("audio")
    axes[0].set_title(f"{clip.info.clip_id} ({clip.info.speaker})")
    for j, ax in enumerate(axes[1:]):
        ax.plot(times_s, np.degrees(true_rad[:, j]), color="black", linewidth=1.2, label="truth")
        for name, pred in predictions.items():
            ax.plot(times_s, np.degrees(pred[:n, j]), linewidth=0.9, label=name)
        ax.set_ylabel(f"{robot.names[j]}\n(deg)", fontsize=7)
    axes[1].legend(fontsize=6, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    return save_figure(fig, path, dpi=70)


# --- Distribution evaluation per joint group ------------------------------------------------


def _loso_fold(
    training: list[Clip],
    held_out: list[Clip],
    robot: RobotDescription,
    model_names: Sequence[str],
    settings: TrainSettings,
    n_samples: int,
    tune: Callable[[Checkpoint, list[Clip]], Checkpoint] | None,
    progress: Callable[[str], None] | None,
    title: str,
) -> tuple[Predictions, Predictions, str | None]:
    """One leave-one-speaker-out fold: train each model, tune it, sample the held-out clips.

    Returns the fold's samples and paused samples per model label, and the tuned checkpoint's
    ``sampling_choice`` note (None without one).
    """
    from audio2pose_ros.learning.training import train_on_clips

    predictions: Predictions = {}
    paused: Predictions = {}
    note = None
    for name in model_names:
        if progress is not None:
            progress(f"{title}: training {name}")
        checkpoint, _ = train_on_clips(name, training, robot, settings)
        if tune is not None:
            checkpoint = tune(checkpoint, training)
            note = checkpoint.info.get("sampling_choice", note)
        label = f"{name} (LOSO)"
        samples, pauses = checkpoint_predictions(
            [(Path(label), checkpoint)], held_out, n_samples, settings.seed
        )
        predictions[label] = next(iter(samples.values()))
        paused[label] = next(iter(pauses.values()))
    return predictions, paused, note


def loso_predictions(
    dataset: Dataset,
    robot: RobotDescription,
    model_names: Sequence[str],
    settings: TrainSettings,
    n_samples: int = 3,
    progress: Callable[[str], None] | None = None,
    tune: Callable[[Checkpoint, list[Clip]], Checkpoint] | None = None,
    workers: int = 1,
    choices: dict[str, str] | None = None,
) -> tuple[list[Clip], Predictions, Predictions]:
    """Leave one speaker out: for each speaker, train each model on the others, predict it.

    Every clip of the data set is held out exactly once (in its speaker's fold), whatever its
    split label; validation for early stopping holds out further speakers of the training side
    (:func:`~audio2pose_ros.learning.training.train_on_clips`). ``tune`` (e.g. the choice of a
    sampler's settings, :class:`~audio2pose_ros.learning.sampling_folds.FoldTuner`) receives
    each fold's trained checkpoint and that fold's training clips, never the held-out
    speaker's, and returns the checkpoint that predicts the held-out speaker.

    Args:
        dataset: the clips, with their speakers.
        robot: joint order and ranges.
        model_names: the models to train in every fold.
        settings: training settings.
        n_samples: samples per clip of a sampler.
        progress: receives one line per training (with ``workers`` > 1 the workers print
            them to standard error instead).
        tune: see above; must be picklable when ``workers`` > 1.
        workers: folds trained side by side (:func:`~audio2pose_ros.learning.parallel.run_tasks`).
        choices: filled with speaker -> the tuned checkpoint's ``sampling_choice`` note.

    Returns:
        All clips; per model label (``"<name> (LOSO)"``) and clip id the synthesized samples
        (seeds ``settings.seed`` + 0 .. n_samples - 1; one for deterministic models); and the
        same for the clips' audio with a pause (:func:`with_pause`).

    Raises:
        EvaluationError: fewer than two speakers.

    """
    from audio2pose_ros.learning.parallel import report, run_tasks

    clips = [dataset.load(c.clip_id) for c in dataset.clips]
    speakers = sorted({c.info.speaker for c in clips})
    if len(speakers) < 2:
        raise EvaluationError(f"{dataset.root}: leave-one-speaker-out needs two speakers")
    step = progress if workers == 1 or progress is None else report
    tasks = [
        partial(
            _loso_fold,
            [c for c in clips if c.info.speaker != speaker],
            [c for c in clips if c.info.speaker == speaker],
            robot,
            model_names,
            settings,
            n_samples,
            tune,
            step,
            f"fold {k + 1}/{len(speakers)} ({speaker} held out)",
        )
        for k, speaker in enumerate(speakers)
    ]
    predictions: Predictions = {f"{m} (LOSO)": {} for m in model_names}
    paused: Predictions = {f"{m} (LOSO)": {} for m in model_names}
    for speaker, (samples, pauses, note) in zip(speakers, run_tasks(tasks, workers), strict=True):
        for label in predictions:
            predictions[label] |= samples[label]
            paused[label] |= pauses[label]
        if choices is not None and note is not None:
            choices[speaker] = note
    return clips, predictions, paused


def checkpoint_predictions(
    checkpoints: Sequence[tuple[Path, Checkpoint]],
    clips: Sequence[Clip],
    n_samples: int = 3,
    seed: int = 0,
) -> tuple[Predictions, Predictions]:
    """Synthesized samples of checkpoints on clips, and on their audio with a pause.

    Returns:
        method -> clip id -> samples (seeds seed .. seed + n - 1; one for deterministic
        models), and method -> clip id -> the samples with the same seeds on
        ``with_pause(clip.audio)``.
    """
    samples: Predictions = {}
    paused: Predictions = {}
    for path, ckpt in checkpoints:
        draws = n_samples if ckpt.model.stochastic else 1
        label = _model_label(ckpt, path)
        seeds = range(seed, seed + draws)
        samples[label] = {c.info.clip_id: synthesize_samples(ckpt, c.audio, seeds) for c in clips}
        paused[label] = {
            c.info.clip_id: synthesize_samples(ckpt, with_pause(c.audio), seeds) for c in clips
        }
    return samples, paused
