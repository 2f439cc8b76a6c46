"""How realistic a joint group's motion is, pooled over held-out clips (the model card's tables).

Per method (a model, a baseline, real motion of another clip) and joint group (head, arms, hip):
GENEA-style Hellinger distances of speed and acceleration (:mod:`audio2pose_ros.learning.metrics`),
the motion's standard deviation against real, the speed in speech against silence and against an
inserted pause (:func:`with_pause`), Fréchet distance on motion windows, diversity, jerk, beat
consistency and speed percentiles (:mod:`audio2pose_ros.learning.realism`), with bootstrap
intervals and the real split-half floor; the tables and histograms of the model card.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.errors import InputError
from audio2pose_ros.learning import metrics, realism
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ, SAMPLE_RATE_HZ

if TYPE_CHECKING:
    from matplotlib.figure import Figure


class EvaluationError(InputError):
    """Nothing to evaluate: an empty split, or checkpoints made for another robot."""


def fit_length(motion: np.ndarray, n_frames: int) -> np.ndarray:
    """Cut ``motion`` to ``n_frames`` frames, or lengthen it by playing it back and forth.

    Back and forth rather than over again, so that the joins do not jump.
    """
    if motion.shape[0] >= n_frames or motion.shape[0] < 2:
        return np.resize(motion, (n_frames, motion.shape[1]))
    cycle = np.concatenate([motion, motion[-2:0:-1]])
    return np.resize(cycle, (n_frames, motion.shape[1]))


_JOIN_FRAMES = 3  # frames each side of a turn of :func:`fit_length` that count as unknown


def fit_mask(mask: np.ndarray, n_frames: int) -> np.ndarray:
    """The mask of :func:`fit_length`'s motion, unknown around its turns (velocity flips)."""
    fitted = fit_length(mask, n_frames)
    period = mask.shape[0] - 1
    if mask.shape[0] < n_frames and period > 0:
        for turn in range(period, n_frames, period):
            fitted[max(0, turn - _JOIN_FRAMES) : turn + _JOIN_FRAMES + 1] = False
    return fitted


STATIC = "static pose"
PROSODY_RULE = "prosody rule"  # the hand-written arm rule, a baseline of the arm evaluation
MISMATCHED = "mismatched real motion"
QUALITY_MEASURES = ("H speed", "H accel", "std ratio", "speech/silence speed", "speech/pause speed")
Predictions = dict[str, dict[str, list[np.ndarray]]]  # method -> clip id -> samples (N, J) rad


@dataclass
class GroupRow:
    """Measures of one method on one joint group, pooled over the held-out clips.

    Attributes:
        method: model or baseline name.
        group: joint group ('head', 'arms', 'hip').
        measures: :data:`QUALITY_MEASURES` -> (bias-corrected value, 2.5 %, 97.5 % bounds:
            :func:`metrics.bias_corrected`).
        rmse_deg: mean over clips of the RMSE (seed 003 eq. 3.12) on the group's joints.
        lcca: mean over clips of LCCA_Theta (seed 003 eq. 3.19, Table 5.1).
        diversity_deg: mean pairwise RMS distance of samples with different seeds (NaN when the
            method is deterministic).
        plug_in: :data:`QUALITY_MEASURES` -> the value on all segments, not bias-corrected.
        realism: :data:`REALISM_MEASURES` -> value (:mod:`audio2pose_ros.learning.realism`, of
            the first sample).
        percentiles: ((J, 3) speed, (J, 3) acceleration) percentiles p50 / p90 / p99 per
            joint of the group, pooled over the samples.

    """

    method: str
    group: str
    measures: dict[str, tuple[float, float, float]]
    rmse_deg: float
    lcca: float
    diversity_deg: float
    plug_in: dict[str, float] = field(default_factory=dict)
    realism: dict[str, float] = field(default_factory=dict)
    percentiles: tuple[np.ndarray, np.ndarray] | None = None


@dataclass
class QualityEvaluation:
    """Result of :func:`quality_evaluation`: rows per method and group, histograms, seconds."""

    rows: list[GroupRow]
    histograms: dict[
        tuple[str, str], tuple[np.ndarray, np.ndarray]
    ]  # (method, group) -> (speed, accel)
    seconds: float
    silence_seconds: float
    figure: Path | None = None
    floors: list[GroupRow] = field(default_factory=list)
    joint_names: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def row(self, group: str, method: str) -> GroupRow | None:
        """The row of ``method`` on ``group`` (or of the real split-half floor), if any."""
        return next(
            (r for r in [*self.rows, *self.floors] if r.group == group and r.method == method),
            None,
        )

    def table(self) -> str:
        """Plain text: the histogram measures, the realism measures and the percentiles."""
        names = _method_width([*self.rows, *self.floors])
        lines = [
            f"{self.seconds:.0f} s of held-out motion ({self.silence_seconds:.0f} s in silences "
            f">= {metrics.SILENCE_MIN_S:.0f} s); bias-corrected [95 % bootstrap interval over "
            "1 s segments]",
            f"{'group':<6}{'method':<{names}}{'H speed':>20}{'H accel':>20}{'std/real':>20}"
            f"{'speech/silence':>20}{'speech/pause':>20}{'RMSE deg':>10}{'LCCA':>7}{'div deg':>9}",
        ]
        for row in [*self.rows, *self.floors]:
            cells = ""
            for key in QUALITY_MEASURES:
                value, low, high = row.measures.get(key, (math.nan, math.nan, math.nan))
                cells += f"{_ci(value, low, high):>20}"
            lines.append(
                f"{row.group:<6}{row.method:<{names}}{cells}{_num(row.rmse_deg, 2):>10}"
                f"{_num(row.lcca, 2):>7}{_num(row.diversity_deg, 2):>9}"
            )
        lines += ["", _realism_table([*self.rows, *self.floors]), "", _percentile_table(self)]
        return "\n".join(lines)


REALISM_MEASURES = (
    "H speed plug-in",
    "H accel plug-in",
    "FD windows",
    "L1div ratio",
    "jerk ratio",
    "BC",
    "BC shuffled",
)


def _method_width(rows: Sequence[GroupRow]) -> int:
    """Width of a table's method column: 34 characters, or the longest name's and a space."""
    return max([34, *(len(row.method) + 1 for row in rows)])


def _realism_table(rows: Sequence[GroupRow]) -> str:
    """Plain text: the :data:`REALISM_MEASURES` of every row."""
    width = 16
    names = _method_width(rows)
    lines = [
        "plug-in Hellinger (not bias-corrected); Frechet distance of 1 s angle windows, half "
        "against half; L1 diversity and jerk relative to real; beat consistency (BC) with the "
        "clip's audio and with another clip's (shuffled)",
        f"{'group':<6}{'method':<{names}}" + "".join(f"{m:>{width}}" for m in REALISM_MEASURES),
    ]
    for row in rows:
        cells = "".join(
            f"{_num(row.realism.get(m, math.nan), 3):>{width}}" for m in REALISM_MEASURES
        )
        lines.append(f"{row.group:<6}{row.method:<{names}}{cells}")
    return "\n".join(lines)


def _percentile_table(result: QualityEvaluation) -> str:
    """Plain text: speed and acceleration percentiles per joint of every row that has them."""
    levels = "/".join(f"p{p}" for p in realism.PERCENTILES)
    lines = [f"head joint speed (rad/s) and acceleration (rad/s^2), {levels}"]
    names = _method_width([*result.floors, *result.rows])
    for row in [*result.floors, *result.rows]:
        if row.percentiles is None or row.group != "head":  # the head's goals are on them
            continue
        speed, accel = row.percentiles
        for j, name in enumerate(result.joint_names.get(row.group, ())):
            cells = "   ".join(
                "/".join(_num(v, 2) for v in values) for values in (speed[j], accel[j])
            )
            lines.append(f"{row.group:<6}{row.method:<{names}}{name:<16}{cells}")
    return "\n".join(lines)


def _num(value: float, digits: int) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


def _ci(value: float, low: float, high: float) -> str:
    if not math.isfinite(value):
        return "-"
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{value:.2f}"
    return f"{value:.2f} [{low:.2f},{high:.2f}]"


def real_motion_of(clips: Sequence[Clip], others: Sequence[Clip]) -> dict[str, list[np.ndarray]]:
    """A baseline: each clip gets the real motion of one of ``others`` (NaN where unknown).

    Clip i gets ``others[i % len(others)]``'s motion, cut or played back and forth to its
    length; its unknown angles stay NaN, which :func:`quality_evaluation` leaves out.
    """
    out = {}
    for i, clip in enumerate(clips):
        other = others[i % len(others)]
        angles = np.where(other.mask, other.angles_rad, np.nan)
        fitted = fit_length(angles, clip.n_frames)
        fitted[~fit_mask(other.mask, clip.n_frames)] = np.nan
        out[clip.info.clip_id] = [fitted]
    return out


def mismatched_order(speakers: Sequence[str]) -> list[int]:
    """A cyclic shift of the clips pairing each with another speaker's where possible.

    Every clip's motion is used exactly once, so the mismatched baseline's motion has the same
    overall distribution as the real motion; of the shifts, the one with the fewest same-speaker
    pairs is taken (ties: the shift closest to half the clips).
    """
    n = len(speakers)
    if n < 2:
        return list(range(n))

    def cost(shift: int) -> tuple[int, float]:
        same = sum(speakers[i] == speakers[(i + shift) % n] for i in range(n))
        return same, abs(shift - n / 2)

    best = min(range(1, n), key=cost)
    return [(i + best) % n for i in range(n)]


PAUSE_S = 1.5  # silence inserted into held-out audio for the speech / silence speed ratio
_PAUSE_LEVEL = 3e-4  # RMS of the inserted room noise (about -70 dBFS)


def with_pause(audio: np.ndarray, seed: int = 0) -> np.ndarray:
    """The clip's audio with :data:`PAUSE_S` of quiet room noise inserted in the middle."""
    noise = _PAUSE_LEVEL * np.random.default_rng(seed).standard_normal(
        int(PAUSE_S * SAMPLE_RATE_HZ)
    )
    middle = audio.size // 2
    return np.concatenate([audio[:middle], noise, audio[middle:]]).astype(np.float32)


def quality_evaluation(
    clips: Sequence[Clip],
    predictions: Predictions,
    robot: RobotDescription,
    out_figure: Path | None = None,
    n_resamples: int = 200,
    seed: int = 0,
    paused: Predictions | None = None,
) -> QualityEvaluation:
    """Compare generated with real motion per joint group, with baselines on the same clips.

    For every joint group with real (observed) motion in ``clips``: the Hellinger distances
    between histograms of joint speed and of acceleration, generated vs real, computed per joint
    and averaged over the group's joints (GENEA's numerical evaluation); the standard deviation
    of the clip-centred angles relative to real; the ratio of mean joint speed during speech to
    that during silences of at least 1 s (energy VAD, :func:`metrics.energy_vad`); each
    bias-corrected with a 95 % paired bootstrap interval over 1 s segments
    (:func:`metrics.bootstrap_measures`), and the Hellinger distances also as plug-in values.
    Beyond the histograms (:mod:`audio2pose_ros.learning.realism`): the Fréchet distance of
    motion windows, L1 diversity and jerk relative to real, beat consistency with the clip's
    own audio and with another clip's, and speed and acceleration percentiles per joint. Also
    the seed's RMSE and LCCA_Theta (seed 003 Table 5.1) and the diversity of samples with
    different seeds. Baselines: a static pose (the robot's neutral pose: the floor) and real
    motion of another held-out clip, of another speaker where there is one, cut or repeated to
    length (a cyclic shift, so every clip's motion is used once, :func:`mismatched_order`); and
    a floor row, "real (split half)": the Hellinger and Fréchet distances between two halves
    of the real motion (:func:`metrics.split_half_floor`, :func:`realism.frechet_windows`), its
    beat consistency and its percentiles. Held-out clips rarely hold a silence of a second or
    more, so ``paused`` gives each method's motion on the clips' audio with :data:`PAUSE_S` of
    quiet inserted (:func:`with_pause`): its speech / silence speed ratio is the
    "speech/pause speed" measure.

    Args:
        clips: held-out clips with real motion.
        predictions: method -> clip id -> one or more sampled motions (N, J) in radians; the
            distribution measures pool all samples segment by segment
            (:func:`metrics.sum_segments`, so sampling noise averages out and the bootstrap
            stays paired), RMSE, LCCA and the realism measures are those of the first sample,
            all of them give the diversity.
        robot: joint order and groups.
        out_figure: write the speed and acceleration histograms here (PNG); None = no figure.
        n_resamples: bootstrap resamples.
        seed: bootstrap seed.
        paused: method -> clip id -> motions on ``with_pause(clip.audio)`` (pooled like
            ``predictions``); None = no speech/pause measure.

    Raises:
        EvaluationError: no clips.

    """
    if not clips:
        raise EvaluationError("no held-out clips to evaluate")
    rate = FRAME_RATE_HZ
    methods = [STATIC, MISMATCHED, *predictions]
    motion: dict[str, list[tuple[list[np.ndarray], np.ndarray]]] = {m: [] for m in methods}
    real, speech_frames = [], []
    order = mismatched_order([c.info.speaker for c in clips])
    for i, clip in enumerate(clips):
        n = min([clip.n_frames, *(p[clip.info.clip_id][0].shape[0] for p in predictions.values())])
        true = np.where(clip.mask[:n], np.nan_to_num(clip.angles_rad[:n]), robot.neutral_rad)
        real.append((true, clip.mask[:n]))
        speech_frames.append(metrics.energy_vad(clip.audio, n))
        everywhere = np.ones_like(clip.mask[:n])
        other = clips[order[i]]
        motion[STATIC].append(([np.broadcast_to(robot.neutral_rad, true.shape)], everywhere))
        motion[MISMATCHED].append(
            ([fit_length(np.nan_to_num(other.angles_rad), n)], fit_mask(other.mask, n))
        )
        for name, per_clip in predictions.items():
            samples = per_clip[clip.info.clip_id]
            known = np.isfinite(samples[0][:n])  # a baseline of real motion has unknown frames
            motion[name].append(
                ([np.where(known, s[:n], robot.neutral_rad) for s in samples], known)
            )
    onsets = [realism.audio_onsets(c.audio) for c in clips]
    rows, floors, histograms = [], [], {}
    groups = [g for g in ("head", "arms", "hip") if robot.group_mask(g).any()]
    for group in groups:
        joints = robot.group_mask(group)
        if not any(mask[:, joints].any() for _, mask in real):
            continue
        group_real = [(t[:, joints], m[:, joints]) for t, m in real]
        real_segments = metrics.concat_segments(
            [
                metrics.segment_statistics(t, m, s, rate)
                for (t, m), s in zip(group_real, speech_frames, strict=True)
            ]
        )
        histograms[("real", group)] = _density(real_segments)
        floors.append(
            _floor_row(group, group_real, real_segments, onsets, order, n_resamples, seed)
        )
        for name in methods:
            gen = metrics.concat_segments(
                [
                    metrics.sum_segments(
                        [
                            metrics.segment_statistics(
                                p[:, joints], g[:, joints] & m[:, joints], s, rate
                            )
                            for p in samples
                        ]
                    )
                    for (samples, g), (_, m), s in zip(
                        motion[name], real, speech_frames, strict=True
                    )
                ]
            )
            # std, speed ratio: only where the real angle is known, so both sides match
            measures = metrics.bootstrap_measures(real_segments, gen, n_resamples, seed)
            measures["speech/pause speed"] = _pause_ratio(
                clips, (paused or {}).get(name), joints, n_resamples, seed
            )
            plug_in = metrics.distribution_measures(real_segments, gen)
            histograms[(name, group)] = _density(gen)
            rmse, lcca = [], []
            for (samples, _), (t, m) in zip(motion[name], real, strict=True):
                p = samples[0]
                if m[:, joints].any():
                    rmse.append(metrics.rmse_deg(t[:, joints], p[:, joints], m[:, joints]))
                if m[:, joints].all(axis=0).any():
                    lcca.append(metrics.lcca_theta(t[:, joints], p[:, joints], rate, m[:, joints]))
            diversity = [
                metrics.diversity_deg(np.stack([s[: t.shape[0], joints] for s in samples]))
                for samples, (t, _) in zip(
                    (
                        [predictions[name][c.info.clip_id] for c in clips]
                        if name in predictions
                        else []
                    ),
                    real,
                    strict=False,
                )
                if len(samples) >= 2
            ]
            first = [(samples[0][:, joints], g[:, joints]) for samples, g in motion[name]]
            pooled = [
                (s[:, joints], g[:, joints] & m)
                for (samples, g), (_, m) in zip(motion[name], group_real, strict=True)
                for s in samples
            ]
            rows.append(
                GroupRow(
                    name,
                    group,
                    measures,
                    float(np.mean(rmse)) if rmse else math.nan,
                    float(np.mean(lcca)) if lcca else math.nan,
                    float(np.mean(diversity)) if diversity else math.nan,
                    {k: plug_in[k] for k in ("H speed", "H accel")},
                    _realism_measures(group_real, first, onsets, order, plug_in),
                    realism.speed_percentiles(pooled, rate),
                )
            )
    seconds = sum(t.shape[0] for t, _ in real) / rate
    silence = sum(metrics.long_silences(s, rate).sum() for s in speech_frames) / rate
    names = {g: tuple(np.asarray(robot.names)[robot.group_mask(g)]) for g in groups}
    result = QualityEvaluation(rows, histograms, seconds, float(silence), None, floors, names)
    if out_figure is not None:
        result.figure = plot_histograms(out_figure, result, methods)
    return result


REAL_FLOOR = "real (split half)"


def _realism_measures(
    real: Sequence[realism.Motion],
    generated: Sequence[realism.Motion],
    onsets: Sequence[np.ndarray],
    order: Sequence[int],
    plug_in: dict[str, float],
) -> dict[str, float]:
    """:data:`REALISM_MEASURES` of one method's first samples against the real motion."""
    motions = [(g, k & m) for (g, k), (_, m) in zip(generated, real, strict=True)]
    windows = realism.frechet_windows(real, [g for g, _ in motions])
    return {
        "H speed plug-in": plug_in["H speed"],
        "H accel plug-in": plug_in["H accel"],
        "FD windows": windows.generated,
        **realism.motion_ratios(real, motions),
        "BC": realism.pooled_beat_consistency(onsets, motions, range(len(motions))),
        "BC shuffled": realism.pooled_beat_consistency(onsets, motions, order),
    }


def _floor_row(
    group: str,
    real: Sequence[realism.Motion],
    segments: metrics.MotionSegments,
    onsets: Sequence[np.ndarray],
    order: Sequence[int],
    n_resamples: int,
    seed: int,
) -> GroupRow:
    """The real motion against itself: split-half distances, its BC and percentiles."""
    floor = metrics.split_half_floor(segments, n_resamples, seed)
    windows = realism.frechet_windows(real, [angles for angles, _ in real])
    measures = {
        "H speed plug-in": math.nan,
        "H accel plug-in": math.nan,
        "FD windows": windows.floor,
        "L1div ratio": 1.0,
        "jerk ratio": 1.0,
        "BC": realism.pooled_beat_consistency(onsets, real, range(len(real))),
        "BC shuffled": realism.pooled_beat_consistency(onsets, real, order),
    }
    return GroupRow(
        REAL_FLOOR,
        group,
        floor,
        math.nan,
        math.nan,
        math.nan,
        {},
        measures,
        realism.speed_percentiles(real),
    )


def _pause_ratio(
    clips: Sequence[Clip],
    motions: dict[str, list[np.ndarray]] | None,
    joints: np.ndarray,
    n_resamples: int,
    seed: int,
) -> tuple[float, float, float]:
    """Speech / silence speed ratio of motions generated on the clips' audio with a pause."""
    if not motions:
        return math.nan, math.nan, math.nan
    parts = []
    for clip in clips:
        samples = [m[:, joints] for m in motions[clip.info.clip_id]]
        speech = metrics.energy_vad(with_pause(clip.audio), samples[0].shape[0])
        everywhere = np.ones(samples[0].shape, bool)
        parts.append(
            metrics.sum_segments(
                [metrics.segment_statistics(m, everywhere, speech, FRAME_RATE_HZ) for m in samples]
            )
        )
    segments = metrics.concat_segments(parts)
    return metrics.bootstrap_measures(segments, segments, n_resamples, seed)["speech/silence speed"]


def _density(segments: metrics.MotionSegments) -> tuple[np.ndarray, np.ndarray]:
    """Pooled speed and acceleration histograms (all joints of the group), as fractions."""
    speed = segments.speed_counts.sum(axis=(0, 1))
    accel = segments.accel_counts.sum(axis=(0, 1))
    return speed / max(speed.sum(), 1.0), accel / max(accel.sum(), 1.0)


def plot_histograms(path: Path, result: QualityEvaluation, methods: Sequence[str]) -> Path:
    """One PNG of speed and acceleration histograms per joint group, generated vs real.

    Rows are joint groups, columns speed and acceleration; real motion is the grey area, each
    method a line (the static pose, all in the first bin, is left out).
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    groups = sorted({g for _, g in result.histograms}, key=("head", "arms", "hip").index)
    fig, axes = plt.subplots(len(groups), 2, figsize=(11, 3.2 * len(groups)), squeeze=False)
    edges = (metrics.SPEED_BINS_RAD_S[:-1], metrics.ACCELERATION_BINS_RAD_S2[:-1])
    limits = (3.0, 100.0)
    for r, group in enumerate(groups):
        for c, (label, unit) in enumerate((("speed", "rad/s"), ("acceleration", "rad/s^2"))):
            ax = axes[r, c]
            real = result.histograms[("real", group)][c]
            ax.fill_between(edges[c], real, step="post", color="0.8", label="real")
            for name in methods:
                if name == STATIC or (name, group) not in result.histograms:
                    continue
                ax.step(edges[c], result.histograms[(name, group)][c], where="post", label=name)
            ax.set_yscale("log")
            ax.set_xlim(0, limits[c])
            ax.set_title(f"{group}: joint {label} (held-out)", fontsize=9)
            ax.set_xlabel(unit, fontsize=8)
            ax.set_ylabel("fraction of frames", fontsize=8)
    axes[0, 0].legend(fontsize=7)
    return save_figure(fig, path)


def save_figure(fig: Figure, path: Path, dpi: int = 80) -> Path:
    """Lay out, write (creating the folder) and close a matplotlib figure; return its path."""
    from matplotlib import pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
