"""Cross-validation inside one recording: what a learned style is expected to gain, part by part.

A few seconds of one person say little about their next few, so a style chosen on the same
seconds it was fitted to can make the robot less like the person than the default is (a man
enrolled from 9 s of a TV interview got arms 0.4 times his size where the default had his
size). :func:`~audio2pose_ros.style.personal.fit_personal` therefore fits on part of the
recording and scores on the rest, over several folds (:func:`folds`), and keeps, part by part,
the default wherever the learned style does not beat it there (:func:`choose`).

Per part and fold the score is :func:`part_measures` of the held-out stretch: the Hellinger
distances of joint speed and acceleration (the bins of :mod:`~audio2pose_ros.learning.metrics`,
joints pooled) and the absolute log of the size ratio, the measures the held-out evaluation
(``make evaluate-style``) reports. A learned style is tried at several strengths between the
default (0) and the full fit (1, :data:`STRENGTHS`; :func:`toward`); :func:`choose` takes the
strength and way of fitting with the largest mean gain over the folds among those not worse
than the default on any measure, then pulls it further toward the default by how little data
there is and how much the folds disagree (:func:`pull`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace

import numpy as np

from audio2pose_ros.motion.style import IDENTITY, StyleSettings
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.style.figures import MIN_PART_S, Motion, _derivatives, measure_part
from audio2pose_ros.timebase import FRAME_RATE_HZ

MAX_FOLDS = 4
FOLD_MIN_S = 2.5  # each fold's held-out stretch and training part hold at least this much
STRENGTHS = (0.25, 0.5, 0.75, 1.0)  # how far from the default toward the full fit is tried
MEASURE_TOLERANCE = 0.01  # a measure worse than the default's by more than this rules a fit out
DATA_PRIOR_S = MIN_PART_S  # the pull toward the default halves its strength at this much data
MIN_STRENGTH = 0.05  # a pulled strength below this keeps the default
MEASURES = ("H speed", "H accel", "size")

Piece = tuple[int, int, int]  # (clip index, first frame, frame after the last)


@dataclass(frozen=True)
class Measures:
    """How far a part's motion is from the person's: H speed, H accel, log size ratio (absolute)."""

    h_speed: float
    h_accel: float
    log_size: float

    @property
    def total(self) -> float:
        """Their sum (what the choice minimises)."""
        return self.h_speed + self.h_accel + self.log_size

    def values(self) -> tuple[float, float, float]:
        """The three measures in the order of :data:`MEASURES`."""
        return self.h_speed, self.h_accel, self.log_size


def folds(lengths: Sequence[int], k_max: int = MAX_FOLDS) -> list[tuple[list[Piece], list[Piece]]]:
    """(training, held-out) pieces of the clips' frames: ``k`` contiguous stretches in turn.

    The clips are taken end to end and cut into ``k`` stretches of equal length, each held out
    once; ``k`` is the largest up to ``k_max`` whose stretches hold :data:`FOLD_MIN_S`. Fewer
    than 2 such stretches: no fold.
    """
    total = sum(lengths)
    k = min(k_max, int(total // round(FOLD_MIN_S * FRAME_RATE_HZ)))
    if k < 2:
        return []
    bounds = [round(total * i / k) for i in range(k + 1)]
    starts = np.cumsum([0, *lengths])

    def pieces(low: int, high: int) -> list[Piece]:
        out = []
        for c, length in enumerate(lengths):
            a, b = max(low - int(starts[c]), 0), min(high - int(starts[c]), length)
            if a < b:
                out.append((c, a, b))
        return out

    return [
        (pieces(0, bounds[i]) + pieces(bounds[i + 1], total), pieces(bounds[i], bounds[i + 1]))
        for i in range(k)
    ]


def cut(motions: Sequence[Motion], pieces: Sequence[Piece]) -> list[Motion]:
    """The ``pieces`` of per-clip ``motions``."""
    return [(motions[c][0][a:b], motions[c][1][a:b]) for c, a, b in pieces]


def part_measures(
    real: Sequence[Motion], model: Sequence[Motion], robot: RobotDescription, part: str
) -> Measures:
    """:class:`Measures` of ``model``'s ``part`` against ``real`` over the frames ``real`` knows.

    ``model`` carries the same masks and lengths. A size that cannot be measured counts as
    infinitely far.
    """
    from audio2pose_ros.learning.metrics import (
        ACCELERATION_BINS_RAD_S2,
        SPEED_BINS_RAD_S,
        hellinger,
    )

    joints = [int(j) for j in np.flatnonzero(robot.group_mask(part))]
    distances = []
    for order, bins in ((1, SPEED_BINS_RAD_S), (2, ACCELERATION_BINS_RAD_S2)):
        counts = []
        for motions in (real, model):
            values = [_derivatives(motions, j, order, FRAME_RATE_HZ) for j in joints]
            counts.append(np.histogram(np.concatenate(values), bins)[0])
        distances.append(hellinger(counts[0], counts[1]))
    sizes = [measure_part(m, robot, part, min_seconds=0.0) for m in (real, model)]
    if sizes[0] is None or sizes[1] is None:
        return Measures(distances[0], distances[1], math.inf)
    return Measures(distances[0], distances[1], abs(math.log(sizes[1].std_rad / sizes[0].std_rad)))


def part_fields(part: str) -> tuple[str, ...]:
    """The style parameters of ``part`` (``head_gain``, ``arms_rest_pitch_rad``, ...)."""
    return tuple(f.name for f in fields(StyleSettings) if f.name.split("_")[0] == part)


def toward(
    learned: StyleSettings, strength: float, part: str, raise_from: float | None = None
) -> StyleSettings:
    """The default style with ``part``'s parameters moved ``strength`` of the way to ``learned``.

    Sizes and tempos move geometrically (a size of 0.5 at strength 0.5 is 0.71), offsets
    linearly. The arms' height limit moves linearly from ``raise_from`` (where the model's own
    arms rise to, at which a limit starts to act; the joint's limit, off, when None) and is off
    at strength 0. The other parts keep the default.
    """
    if strength <= 0.0:
        return IDENTITY
    values = {}
    for name in part_fields(part):
        start, end = float(getattr(IDENTITY, name)), float(getattr(learned, name))
        if name == "arms_raise_limit_rad" and raise_from is not None:
            start = min(max(raise_from, start), end)
        if name.endswith(("_gain", "_tempo")):
            value = math.exp(strength * math.log(max(end, 1e-3) / start)) * start
        else:
            value = start + strength * (end - start)
        values[name] = round(value, 4)
    return replace(IDENTITY, **values)


def merged(parts: Mapping[str, StyleSettings]) -> StyleSettings:
    """One style of each part's parameters taken from its own settings."""
    values = {}
    for part, settings in parts.items():
        values.update({name: getattr(settings, name) for name in part_fields(part)})
    return replace(IDENTITY, **values)


def noise_at(factor: float, strength: float, factors: Sequence[float]) -> float:
    """The factor of ``factors`` nearest (in log) to ``factor`` ** ``strength``."""
    target = strength * math.log(factor)
    return min(factors, key=lambda f: abs(math.log(f) - target))


@dataclass(frozen=True)
class PartVerdict:
    """What cross-validation decided for one part.

    Attributes:
        part: head, arms or hip.
        fit: the way of fitting chosen ("style", "noise + rest", "noise + style"), or
            "default" when the default was kept.
        strength: how far from the default toward the full fit the result goes (0: default).
        gain: mean over the folds of the default's total distance minus the learned one's on
            held-out stretches, at the strength chosen before the pull (positive: closer).
        spread: the standard deviation of that gain over the folds.
        measure_gains: the mean gain of each of :data:`MEASURES`.
        n_folds: the folds it was measured on.
        reason: why the default was kept ("" when it was not).
    """

    part: str
    fit: str
    strength: float
    gain: float
    spread: float
    measure_gains: tuple[float, float, float]
    n_folds: int
    reason: str = ""

    @property
    def kept_default(self) -> bool:
        """Whether the part keeps the default model's motion."""
        return self.strength == 0.0

    def line(self) -> str:
        """One sentence: the expected gain with its spread, or why it kept the default."""
        if self.kept_default:
            return f"{self.part}: kept the default ({self.reason})"
        each = ", ".join(f"{m} {g:+.3f}" for m, g in zip(MEASURES, self.measure_gains, strict=True))
        return (
            f"{self.part}: learned ({self.fit}, {self.strength:.0%} of the way from the default), "
            f"expected to come {self.gain:.3f} ± {self.spread:.3f} closer to the person than the "
            f"default on speech it did not learn from ({self.n_folds} folds; {each})"
        )


def kept(part: str, reason: str, n_folds: int = 0) -> PartVerdict:
    """The verdict of a part that keeps the default for ``reason``."""
    return PartVerdict(part, "default", 0.0, 0.0, 0.0, (0.0, 0.0, 0.0), n_folds, reason)


def pull(gains: Sequence[float], seconds: float) -> float:
    """The share of a chosen strength kept after the pull toward the default, in [0, 1].

    ``m^2 / (m^2 + se^2)`` for the folds' mean gain ``m`` and its standard error ``se`` (a
    gain the folds disagree on is trusted less), times ``seconds / (seconds + DATA_PRIOR_S)``
    (a short recording is trusted less).
    """
    values = np.asarray(gains, dtype=np.float64)
    mean = float(values.mean())
    se2 = float(values.var(ddof=1)) / len(values) if len(values) > 1 else math.inf
    agreement = mean**2 / (mean**2 + se2) if mean > 0 and math.isfinite(se2) else 0.0
    return agreement * seconds / (seconds + DATA_PRIOR_S)


def choose(
    part: str,
    default: Sequence[Measures],
    trials: Mapping[tuple[str, float], Sequence[Measures]],
    seconds: float,
) -> PartVerdict:
    """The fit and strength of ``part`` from the folds' held-out measures.

    Args:
        part: the part.
        default: per fold, the default's measures.
        trials: (way of fitting, strength) -> per fold, the measures of that fit.
        seconds: how much of the part the recording observed.

    Returns:
        Of the trials no worse than the default on any measure by more than
        :data:`MEASURE_TOLERANCE` (mean over the folds) and better in total, the one of the
        largest mean gain, its strength pulled toward the default (:func:`pull`); the default
        with the reason when none is, or the pulled strength is below :data:`MIN_STRENGTH`.
    """
    n = len(default)
    if n < 2:
        return kept(part, f"{seconds:.0f} s of it is too little to test a fit on unseen stretches")
    scored = []
    for (fit, strength), measures in trials.items():
        pairs = list(zip(default, measures, strict=True))
        gains = [d.total - m.total for d, m in pairs]
        diffs = np.array([np.subtract(d.values(), m.values()) for d, m in pairs])
        each = (
            float(diffs[:, 0].mean()),
            float(diffs[:, 1].mean()),
            float(diffs[:, 2].mean()),
        )
        finite = all(math.isfinite(g) for g in gains)
        scored.append((float(np.mean(gains)) if finite else -math.inf, fit, strength, gains, each))
    if not scored:
        return kept(part, "nothing to fit", n)
    good = [s for s in scored if s[0] > 0 and min(s[4]) >= -MEASURE_TOLERANCE]
    if not good:
        best = max(scored, key=lambda s: s[0])
        if best[0] <= 0:
            spread = float(np.std(best[3], ddof=1)) if math.isfinite(best[0]) else math.inf
            reason = (
                f"no learned fit came closer to the person on unseen stretches: the best, "
                f"{best[1]}, {best[0]:+.3f} ± {spread:.3f} over {n} folds"
            )
        else:
            worst = int(np.argmin(best[4]))
            reason = (
                f"the learned fit came closer in total ({best[0]:+.3f}) but further on "
                f"{MEASURES[worst]} ({best[4][worst]:+.3f}) on unseen stretches"
            )
        return kept(part, reason, n)
    gain, fit, strength, gains, each = max(good, key=lambda s: (s[0], -s[2]))
    share = pull(gains, seconds)
    spread = float(np.std(gains, ddof=1))
    if strength * share < MIN_STRENGTH:
        return kept(
            part,
            f"its gain on unseen stretches, {gain:+.3f} ± {spread:.3f} over {n} folds, is too "
            f"uncertain for {seconds:.0f} s",
            n,
        )
    return PartVerdict(part, fit, round(strength * share, 3), gain, spread, each, n)
