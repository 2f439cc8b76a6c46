"""Where the arms are relative to the body: the guard's share and wrist positions (ours).

Two questions the joint-space measures of :mod:`audio2pose_ros.learning.evaluation` do not
answer, asked of every method's motion on held-out clips:

- How often does the motion need the self-collision guard? The share of frames that bring an
  arm link closer than the guard's margin to the robot's body, and of frames more than 1 cm
  inside it, as ``audio2pose check-body`` counts them
  (:func:`~audio2pose_ros.offline.body_check.check_trajectory`, before any guard).
- Are the hands where a speaker's are? Each wrist's position in the torso frame
  (:meth:`~audio2pose_ros.robot.body.BodyModel.wrist_positions`; the right wrist mirrored onto
  the left, so both count), and per axis the Hellinger distance between its histogram and the
  real motion's (:data:`WRIST_BINS` bins spanning both).

Baselines are rows like the model's: the static neutral pose and real motion of other clips; the
floor is the real motion's first half against its second half.

The arms learned from one lecturer, so the first question is also asked on speech of other
speakers that no step of the build saw (:func:`speech_body_rows`): per clip, over several seeds,
the share of frames the guard would act on, pooled and at the worst seed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning import metrics
from audio2pose_ros.offline.body_check import check_trajectory
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.timebase import SAMPLE_RATE_HZ

WRIST_BINS = 20
AXES = ("x (forward)", "y (outward)", "z (up)")
REAL_HALVES = "real (split half)"


@dataclass(frozen=True)
class BodyRow:
    """One method's motion against the body and the real wrists.

    Attributes:
        method: the method's name.
        frames: frames measured (first sample of every clip, arm angles known).
        near_pct: frames closer than the margin to the body (%).
        inside_pct: frames with an arm link more than 1 cm inside it (%).
        wrist_h: per axis of :data:`AXES`, the Hellinger distance to the real wrists.

    """

    method: str
    frames: int
    near_pct: float
    inside_pct: float
    wrist_h: tuple[float, float, float]


def _wrists(body: BodyModel, angles: np.ndarray) -> np.ndarray:
    """(2 N, 3) wrist positions, the right wrist mirrored (y negated) onto the left."""
    both = body.wrist_positions(angles)
    right = both[:, 1] * np.array([1.0, -1.0, 1.0])
    return np.concatenate([both[:, 0], right])


def wrist_hellinger(real: np.ndarray, generated: np.ndarray) -> tuple[float, float, float]:
    """Per axis, the Hellinger distance of two (N, 3) wrist-position histograms."""
    out = []
    for axis in range(3):
        a, b = real[:, axis], generated[:, axis]
        low, high = min(a.min(), b.min()), max(a.max(), b.max())
        edges = np.linspace(low, max(high, low + 1e-6), WRIST_BINS + 1)
        out.append(metrics.hellinger(np.histogram(a, edges)[0], np.histogram(b, edges)[0]))
    return out[0], out[1], out[2]


def _arm_frames(angles: np.ndarray, arms: np.ndarray) -> np.ndarray:
    """Rows whose arm angles (``arms``: joint mask) are all known (finite)."""
    return np.isfinite(angles[:, arms]).all(axis=1)


def body_realism(
    clips: Sequence[Clip],
    predictions: Mapping[str, Mapping[str, Sequence[np.ndarray]]],
    body: BodyModel,
    margin_m: float,
) -> list[BodyRow]:
    """The floor row, then one row per method (see the module text).

    Args:
        clips: held-out clips with real arm motion.
        predictions: method -> clip id -> sampled motions (N, J) in radians (the first is used);
            NaN where a baseline does not know an angle.
        body: the robot's collision model.
        margin_m: the guard's margin (m).

    Returns:
        Rows in the order: :data:`REAL_HALVES`, then ``predictions``' methods.

    """
    robot = body.robot
    arms = robot.group_mask("arms")
    real_parts = [np.where(c.mask, c.angles_rad, np.nan) for c in clips]
    real = np.concatenate(real_parts)
    real = real[_arm_frames(real, arms)]
    real = np.where(np.isfinite(real), real, robot.neutral_rad)
    if not len(real):
        return []
    real_wrists = _wrists(body, real)

    def row(method: str, angles: np.ndarray, reference: np.ndarray) -> BodyRow:
        report = check_trajectory(body, angles, margin_m)
        return BodyRow(
            method,
            report.frames,
            report.within_margin_pct,
            report.inside_pct,
            wrist_hellinger(reference, _wrists(body, angles)),
        )

    half = len(real) // 2
    rows = [row(REAL_HALVES, real[half:], _wrists(body, real[:half]))]
    for method, by_clip in predictions.items():
        parts = [np.asarray(by_clip[c.info.clip_id][0])[: c.n_frames] for c in clips]
        angles = np.concatenate(parts)
        angles = angles[_arm_frames(angles, arms)]
        angles = np.where(np.isfinite(angles), angles, robot.neutral_rad)
        if len(angles):
            rows.append(row(method, angles, real_wrists))
    return rows


def body_table(rows: Sequence[BodyRow], margin_m: float) -> str:
    """Plain text: one line per row."""
    lines = [
        f"{'method':<44}{'frames':>7}{f'< {margin_m * 100:g} cm %':>10}{'inside %':>10}"
        + "".join(f"{'wrist H ' + axis.split()[0]:>11}" for axis in AXES)
    ]
    for r in rows:
        lines.append(
            f"{r.method[:43]:<44}{r.frames:>7}{r.near_pct:>10.1f}{r.inside_pct:>10.1f}"
            + "".join(f"{h:>11.2f}" for h in r.wrist_h)
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class SpeechBodyRow:
    """One utterance's sampled motion against the body, over several seeds.

    Attributes:
        clip: the utterance's name.
        seconds: its length.
        seeds: how many seeds sampled it.
        near_pct: frames closer than the margin to the body, pooled over the seeds (%).
        worst_near_pct: the same at the worst seed (%).
        worst_inside_pct: frames with an arm link more than 1 cm inside the body, worst seed (%).

    """

    clip: str
    seconds: float
    seeds: int
    near_pct: float
    worst_near_pct: float
    worst_inside_pct: float


def speech_body_rows(
    checkpoint: Checkpoint,
    body: BodyModel,
    speech: Mapping[str, np.ndarray],
    seeds: Sequence[int],
    margin_m: float,
) -> list[SpeechBodyRow]:
    """Per utterance (16 kHz), the model's raw motion at every seed against the body."""
    from audio2pose_ros.offline.synthesis import synthesize_samples

    rows = []
    for name, audio in speech.items():
        reports = [
            check_trajectory(body, angles, margin_m)
            for angles in synthesize_samples(checkpoint, audio, seeds)
        ]
        frames = sum(r.frames for r in reports)
        near = sum(r.within_margin_pct * r.frames for r in reports) / max(frames, 1)
        rows.append(
            SpeechBodyRow(
                name,
                len(audio) / SAMPLE_RATE_HZ,
                len(reports),
                near,
                max((r.within_margin_pct for r in reports), default=0.0),
                max((r.inside_pct for r in reports), default=0.0),
            )
        )
    return rows


def speech_body_table(rows: Sequence[SpeechBodyRow], margin_m: float) -> str:
    """Plain text: one line per utterance, then all of them pooled."""
    lines = [
        f"{'clip':<44}{'seconds':>8}{'seeds':>6}{f'< {margin_m * 100:g} cm %':>10}"
        f"{'worst seed %':>13}{'worst inside %':>15}"
    ]
    for r in rows:
        lines.append(
            f"{r.clip[:43]:<44}{r.seconds:>8.1f}{r.seeds:>6}{r.near_pct:>10.1f}"
            f"{r.worst_near_pct:>13.1f}{r.worst_inside_pct:>15.1f}"
        )
    if rows:
        seconds = sum(r.seconds for r in rows)
        pooled = sum(r.near_pct * r.seconds for r in rows) / seconds
        lines.append(f"{'all':<44}{seconds:>8.1f}{rows[0].seeds:>6}{pooled:>10.1f}")
    return "\n".join(lines)
