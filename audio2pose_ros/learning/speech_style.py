"""How a model's head moves on speech of speakers that no step of the build used (ours).

The held-out sources of :mod:`audio2pose_ros.learning.source_holdout` have real head motion to
compare with, but only two sources, which differ in style more than any model does: GRID's
readers barely move their heads, Obama moves his four to five times more. Speech without video
(the bundled LibriVox clips) says which of them a model's head resembles on a new voice. Per
joint, the speed and acceleration percentiles p50 / p90 / p99 (as
:func:`~audio2pose_ros.learning.realism.speed_percentiles`) and the standard deviation of the
angle per clip (averaged over clips), of the model's samples over several seeds, beside the real
motion of each talking-head source; and whether the head moves in time with the speech: EMAGE's
beat consistency (:func:`~audio2pose_ros.learning.realism.pooled_beat_consistency`) of each
utterance's onsets against the motion made on it, and against the motion made on the next
utterance (shuffled audio). Beats that land near onsets by chance score the shuffled value, so
only BC above it says the motion follows the speech.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning import realism
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ


@dataclass(frozen=True)
class StyleRow:
    """One motion's head statistics.

    Attributes:
        method: what moved (a model on the speech, or a real source).
        seconds: motion measured (summed over seeds).
        speed: (J, 3) speed percentiles per head joint (rad/s).
        accel: (J, 3) acceleration percentiles (rad/s^2).
        std_deg: (J,) standard deviation of the angle per clip, averaged over clips (degrees).
        bc: beat consistency with each clip's own audio (NaN without onsets).
        bc_shuffled: the same with the next clip's motion (NaN with fewer than two clips).
        source: the real source's name; empty for a model's row.

    """

    method: str
    seconds: float
    speed: np.ndarray
    accel: np.ndarray
    std_deg: np.ndarray
    bc: float = math.nan
    bc_shuffled: float = math.nan
    source: str = ""


def _beats(
    onsets: Sequence[np.ndarray], motions: Sequence[realism.Motion], groups: Sequence[range]
) -> tuple[float, float]:
    """BC with own audio, and with the next motion of the same group (seed) of clips.

    The shuffled BC is NaN when a group has no other motion to pair with.
    """
    own = realism.pooled_beat_consistency(onsets, motions, range(len(motions)))
    if any(len(group) < 2 for group in groups):
        return own, math.nan
    shuffled = [group[(i + 1) % len(group)] for group in groups for i in range(len(group))]
    return own, realism.pooled_beat_consistency(onsets, motions, shuffled)


def _row(
    method: str,
    motions: Sequence[realism.Motion],
    onsets: Sequence[np.ndarray],
    groups: Sequence[range],
    source: str = "",
) -> StyleRow:
    speed, accel = realism.speed_percentiles(motions, FRAME_RATE_HZ)
    stds = [
        [np.std(angles[known[:, j], j]) for j in range(angles.shape[1])]
        for angles, known in motions
        if known.all(axis=1).sum() > 1
    ]
    return StyleRow(
        method,
        sum(len(angles) for angles, _ in motions) / FRAME_RATE_HZ,
        speed,
        accel,
        np.degrees(np.mean(stds, axis=0)),
        *_beats(onsets, motions, groups),
        source,
    )


def head_style_rows(
    checkpoint: Checkpoint,
    robot: RobotDescription,
    speech: Mapping[str, np.ndarray],
    seeds: Sequence[int],
    real: Mapping[str, Sequence[Clip]],
    label: str,
) -> list[StyleRow]:
    """The model's row (``label``) on ``speech`` (16 kHz) at every seed, then one per real source.

    Args:
        checkpoint: the model.
        robot: joint order and groups.
        speech: name -> utterance, speech the model never trained on.
        seeds: sampling seeds.
        real: source name -> its clips (head motion where the mask says so).
        label: the model row's name.

    """
    from audio2pose_ros.offline.synthesis import synthesize_samples

    head = robot.group_mask("head")
    utterances = list(speech.values())
    onsets = [realism.audio_onsets(audio) for audio in utterances]
    samples = [synthesize_samples(checkpoint, audio, seeds) for audio in utterances]
    # grouped by seed, each group the utterances in order: shuffled pairs within a seed
    generated: list[realism.Motion] = [
        (per_utterance[k][:, head], np.ones((len(per_utterance[k]), int(head.sum())), bool))
        for k in range(len(seeds))
        for per_utterance in samples
    ]
    n = len(utterances)
    groups = [range(k * n, (k + 1) * n) for k in range(len(seeds))] if n else []
    rows = [_row(label, generated, onsets * len(seeds), groups)] if generated else []
    for source, clips in real.items():
        motions = realism.clip_motions(clips, head)
        if motions:
            observed = [c for c in clips if c.mask[:, head].any()]  # as clip_motions keeps
            clip_onsets = [realism.audio_onsets(c.audio) for c in observed]
            rows.append(
                _row(f"real, {source}", motions, clip_onsets, [range(len(motions))], source)
            )
    return rows


def head_style_table(rows: Sequence[StyleRow], joint_names: Sequence[str]) -> str:
    """Plain text: per row and head joint, the percentiles and the standard deviation.

    The row's beat consistency (own audio, shuffled) is on its first joint's line. Then, where
    there are both, how many of each model row's speed and acceleration percentiles lie within
    25 % of each real source's, with the range of model / real
    (:func:`~audio2pose_ros.learning.realism.percentile_agreement`).
    """
    levels = "/".join(f"p{p}" for p in realism.PERCENTILES)
    lines = [
        f"{'method':<40}{'seconds':>8}  {'joint':<11}{'speed ' + levels + ' rad/s':<26}"
        f"{'accel ' + levels + ' rad/s^2':<28}{'std deg':>8}{'BC':>7}{'shuffled':>9}"
    ]
    for row in rows:
        for j, name in enumerate(joint_names):
            speed = "/".join(f"{v:.2f}" for v in row.speed[j])
            accel = "/".join(f"{v:.1f}" for v in row.accel[j])
            beats = f"{_num(row.bc):>7}{_num(row.bc_shuffled):>9}" if j == 0 else ""
            lines.append(
                f"{row.method[:39]:<40}{row.seconds:>8.1f}  {name:<11}{speed:<26}{accel:<28}"
                f"{row.std_deg[j]:>8.2f}{beats}"
            )
    return "\n".join(lines + _tolerance_lines(rows))


def _tolerance_lines(rows: Sequence[StyleRow]) -> list[str]:
    """The model rows' percentiles within 25 % of each real source's (none without both)."""
    models = [row for row in rows if not row.source]
    real = [row for row in rows if row.source]
    if not models or not real:
        return []
    n = sum(np.size(p) for p in (real[0].speed, real[0].accel))
    percent = round(100 * realism.PERCENTILE_TOLERANCE)
    lines = [
        "",
        f"speed and acceleration percentiles within {percent} % of each real source's, of {n}"
        " (model / real, lowest to highest)",
        (f"{'method':<40}" + "".join(f"{row.source[:21]:<22}" for row in real)).rstrip(),
    ]
    for row in models:
        cells = []
        for truth in real:
            agree = realism.percentile_agreement((row.speed, row.accel), (truth.speed, truth.accel))
            spread = (  # a still real source gives no ratio
                "-" if math.isnan(agree.lowest) else f"{agree.lowest:.2f} to {agree.highest:.2f}"
            )
            cells.append(f"{agree.inside} ({spread})")
        lines.append((f"{row.method[:39]:<40}" + "".join(f"{c:<22}" for c in cells)).rstrip())
    return lines


def _num(value: float) -> str:
    return f"{value:.3f}" if math.isfinite(value) else "-"
