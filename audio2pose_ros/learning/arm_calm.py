"""How calm the commanded arms are: acceleration at the limiter, hands above the shoulders (ours).

Two questions the distribution measures of :mod:`audio2pose_ros.learning.evaluation` answer only
indirectly, asked of what the motion filter commands
(:func:`~audio2pose_ros.learning.command_path.commanded`, the node's own core):

- **Bang-bang.** The share of arm joint-frames whose commanded acceleration (second difference
  at the filter's rate) lies within :data:`AT_LIMIT_FRACTION` of the joint's acceleration limit:
  motion that asks for more than the robot can give is braked and launched at the limit in every
  frame, which looks like a machine, not like a person.
- **Hands up high.** The share of frames in which a wrist
  (:meth:`~audio2pose_ros.robot.body.BodyModel.wrist_heights`) is above the height of its
  shoulder joint, and more than :data:`HIGH_ABOVE_M` above it. People talking raise a hand above
  the shoulder now and then; a lecturer writing on a board keeps it there.

Beside them, the speed and acceleration percentiles (p50 / p90 / p99) of the shoulder-pitch and
elbow-yaw joints (left and right pooled), as people's are reported. The real people's motion is
measured through the same filter, so the robot's limits cost both alike.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.robot.body import BodyModel
from audio2pose_ros.robot.description import RobotDescription
from audio2pose_ros.timebase import FRAME_RATE_HZ

AT_LIMIT_FRACTION = 0.98  # |accel| at least this share of the joint's limit: "at the limit"
HIGH_ABOVE_M = 0.10  # a wrist this far above its shoulder: "well above"
PAIRED_JOINTS = ("ShoulderPitch", "ElbowYaw")  # their percentiles are tabled, L and R pooled
WRIST_EVERY = 2  # frames: wrist heights are measured on every 2nd frame (forward kinematics)

CALM_KEYS = ("at limit %", "wrist up %", "wrist high %")  # the figures, as budgets name them
PEOPLE_INFO_KEY = "arms_calm_people"  # checkpoint info: the people's figures, JSON by CALM_KEYS
PEOPLE = "people: lecturer talking (train + validation)"

Motion = tuple[np.ndarray, np.ndarray]  # (T, J) angles (rad) and (T, J) known mask


@dataclass(frozen=True)
class ArmCalm:
    """One motion's calm figures (see the module text).

    Attributes:
        method: what moved.
        seconds: motion measured (NaN: not known).
        at_limit_pct: arm joint-frames with the acceleration at the limit (%).
        above_pct: frames with a wrist above its shoulder's height (%).
        high_pct: frames with a wrist more than :data:`HIGH_ABOVE_M` above it (%).
        speed: per joint of :data:`PAIRED_JOINTS`, speed p50 / p90 / p99 (rad/s); may be
            empty (figures given without them).
        accel: per joint of :data:`PAIRED_JOINTS`, acceleration p50 / p90 / p99 (rad/s^2).

    """

    method: str
    seconds: float
    at_limit_pct: float
    above_pct: float
    high_pct: float
    speed: dict[str, tuple[float, float, float]]
    accel: dict[str, tuple[float, float, float]]


def _known(motion: Motion | np.ndarray) -> Motion:
    if isinstance(motion, tuple):
        return motion
    return motion, np.ones(motion.shape, bool)


def _differences(angles: np.ndarray, known: np.ndarray, order: int) -> tuple[np.ndarray, ...]:
    """|order-th difference| * rate^order and where its whole stencil is known, (T - order, J)."""
    value = np.abs(np.diff(angles, order, axis=0)) * FRAME_RATE_HZ**order
    valid = known[order:].copy()
    for k in range(1, order + 1):
        valid &= known[order - k : angles.shape[0] - k]
    return value, valid


def at_limit_pct(robot: RobotDescription, motions: Sequence[Motion | np.ndarray]) -> float:
    """Share (%) of known arm joint-frames whose acceleration is at the joint's limit."""
    arms = robot.group_mask("arms")
    limit = AT_LIMIT_FRACTION * np.asarray(robot.max_acceleration_rad_s2)[arms]
    hits = total = 0
    for motion in motions:
        angles, known = _known(motion)
        accel, valid = _differences(angles[:, arms], known[:, arms], 2)
        hits += int(np.count_nonzero((accel >= limit) & valid))
        total += int(np.count_nonzero(valid))
    return 100.0 * hits / total if total else float("nan")


def wrist_heights(body: BodyModel, motions: Sequence[Motion | np.ndarray]) -> np.ndarray:
    """(N,) the higher wrist's height above the shoulders (m), every :data:`WRIST_EVERY` frame.

    Only frames where every arm joint is known count.
    """
    arms = body.robot.group_mask("arms")
    out = []
    for motion in motions:
        angles, known = _known(motion)
        rows = np.flatnonzero(known[:, arms].all(axis=1))[::WRIST_EVERY]
        if rows.size:
            poses = np.nan_to_num(angles[rows])
            out.append(body.wrist_heights(poses).max(axis=1))
    return np.concatenate(out) if out else np.empty(0)


def arm_calm(
    method: str,
    robot: RobotDescription,
    body: BodyModel,
    motions: Sequence[Motion | np.ndarray],
) -> ArmCalm:
    """The calm figures of ``motions`` (arrays, or (angles, known) pairs), already commanded."""
    pairs = [_known(m) for m in motions]
    heights = wrist_heights(body, pairs)
    speed: dict[str, tuple[float, float, float]] = {}
    accel: dict[str, tuple[float, float, float]] = {}
    for joint in PAIRED_JOINTS:
        columns = [robot.names.index(f"{side}{joint}") for side in "LR"]
        for order, out in ((1, speed), (2, accel)):
            values = [
                value[valid]
                for angles, known in pairs
                for value, valid in [_differences(angles[:, columns], known[:, columns], order)]
            ]
            pooled = np.concatenate(values) if values else np.empty(0)
            p50, p90, p99 = np.percentile(pooled, (50, 90, 99)) if pooled.size else (np.nan,) * 3
            out[joint] = (float(p50), float(p90), float(p99))
    return ArmCalm(
        method,
        sum(len(a) for a, _ in pairs) / FRAME_RATE_HZ,
        at_limit_pct(robot, pairs),
        100.0 * float(np.mean(heights > 0.0)) if heights.size else float("nan"),
        100.0 * float(np.mean(heights > HIGH_ABOVE_M)) if heights.size else float("nan"),
        speed,
        accel,
    )


def arm_calm_table(rows: Sequence[ArmCalm]) -> str:
    """Plain text, one line per motion."""
    head = f"{'method':<52}{'seconds':>8}{'at limit %':>11}{'wrist up %':>11}{'>10 cm %':>9}"
    for joint in PAIRED_JOINTS:
        head += f"  {joint + ' speed / accel p50/p90/p99':<44}"
    lines = [head]
    for r in rows:
        line = (
            f"{r.method[:51]:<52}{r.seconds:>8.1f}{r.at_limit_pct:>11.1f}{r.above_pct:>11.1f}"
            f"{r.high_pct:>9.1f}"
        )
        for joint in PAIRED_JOINTS:
            figures = "-"
            if joint in r.speed:
                s, a = r.speed[joint], r.accel[joint]
                figures = f"{s[0]:.2f}/{s[1]:.2f}/{s[2]:.2f} / {a[0]:.1f}/{a[1]:.1f}/{a[2]:.1f}"
            line += f"  {figures:<44}"
        lines.append(line.rstrip())
    return "\n".join(lines)


def figures(row: ArmCalm) -> dict[str, float]:
    """The row's :data:`CALM_KEYS` figures."""
    return dict(zip(CALM_KEYS, (row.at_limit_pct, row.above_pct, row.high_pct), strict=True))


def people_row(checkpoint: Checkpoint) -> ArmCalm | None:
    """The people's figures a default model's arms were chosen within (its info), or None."""
    text = checkpoint.info.get(PEOPLE_INFO_KEY)
    if not isinstance(text, str):
        return None
    values = json.loads(text)
    if not values:
        return None
    at_limit, above, high = (float(values[k]) for k in CALM_KEYS)
    return ArmCalm(PEOPLE, math.nan, at_limit, above, high, {}, {})


def model_calm(
    checkpoint: Checkpoint,
    speech: Mapping[str, np.ndarray],
    seeds: Sequence[int],
    label: str,
) -> ArmCalm:
    """The model's raw samples of each 16 kHz utterance at ``seeds``, commanded, measured."""
    from audio2pose_ros.learning.command_path import commanded
    from audio2pose_ros.offline.synthesis import synthesize_samples

    robot = checkpoint.robot
    motions = [
        m
        for audio in speech.values()
        for m in commanded(robot, synthesize_samples(checkpoint, audio, seeds, smooth=False))
    ]
    return arm_calm(label, robot, BodyModel.load(robot), motions)
