"""What the robot is commanded: samples through the motion filter, scored against real motion.

The realism tables of the model card score the offline synthesis (``audio2pose synth``: the raw
samples through the seed's zero-phase 4 Hz Butterworth, seed 003 section 4.4.1). On the robot,
``motion_filter_node`` moves the joints instead: a causal smoother (by default a 3 Hz,
2nd-order Butterworth run forwards; the seed's 4 Hz, 5th order run forwards, or its Kalman
filter of seed 003 section 4.4.2, on request), the velocity and acceleration limits and the
self-collision guard. This module runs that core
(:func:`~audio2pose_ros.motion.filter.online_filter`, the node's own code without ROS) over
the model's raw samples, one 10 ms tick per frame, with each smoother of :data:`SMOOTHERS`;
and over the real motion of the same clips, whose distances to itself are then what the
robot's limits alone cost: no model's commanded motion can be expected closer to the real
than that ceiling.

Each trajectory starts the filter at rest in its first pose (as a robot that waits there), so
its first fraction of a second includes the approach to a moving track.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.data.dataset import Clip
from audio2pose_ros.learning.quality import Predictions, quality_evaluation
from audio2pose_ros.motion.filter import MotionFilter, delay_s, online_filter
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.smoothing import SEED_CUTOFF_HZ, SEED_ORDER
from audio2pose_ros.robot.description import RobotDescription

SHIPPED = MotionFilterSettings()  # the node's defaults (config/pepper.yaml)


def smoother_name(settings: MotionFilterSettings) -> str:
    """How a table names a smoother: ``lowpass 3 Hz order 2``, ``kalman`` or ``none``."""
    if settings.smoothing == "lowpass":
        return f"lowpass {settings.lowpass_cutoff_hz:g} Hz order {settings.lowpass_order}"
    return settings.smoothing


# scored side by side: the shipped smoother, the seed's Butterworth run forwards, its Kalman
# filter (each once, should the shipped one be one of the others)
SMOOTHERS = tuple(
    {
        smoother_name(settings): settings
        for settings in (
            SHIPPED,
            replace(
                SHIPPED,
                smoothing="lowpass",
                lowpass_cutoff_hz=SEED_CUTOFF_HZ,
                lowpass_order=SEED_ORDER,
            ),
            replace(SHIPPED, smoothing="kalman"),
        )
    }.values()
)
REAL_LABEL = f"real, commanded ({smoother_name(SHIPPED)})"


def commanded_label(name: str, settings: MotionFilterSettings) -> str:
    """The row of model ``name``'s motion as the filter with ``settings`` commands it."""
    return f"{name}, commanded ({smoother_name(settings)})"


def commanded(
    robot: RobotDescription,
    motions: Sequence[np.ndarray],
    settings: MotionFilterSettings = SHIPPED,
) -> list[np.ndarray]:
    """Each (T, J) trajectory in radians as the motion filter commands it: (T, J) each.

    The filter has ``settings`` and starts at rest in the first pose.
    """
    return [
        online_filter(MotionFilter(robot, settings, start_pose_rad=m[0]), m, tail_s=0.0)
        for m in motions
    ]


def command_path_predictions(
    robot: RobotDescription,
    clips: Sequence[Clip],
    label: str,
    raw: dict[str, list[np.ndarray]],
) -> Predictions:
    """Method -> clip id -> commanded motion: the model's per smoother, and the real motion's.

    ``raw`` holds the model's samples of each clip unsmoothed, as the inference node sends them
    (:func:`~audio2pose_ros.offline.synthesis.synthesize_samples` with ``smooth=False``);
    ``label`` names the model; its rows are :func:`commanded_label`, the real motion's
    :data:`REAL_LABEL`.
    """
    rows: Predictions = {
        commanded_label(label, settings): {
            clip_id: commanded(robot, motions, settings) for clip_id, motions in raw.items()
        }
        for settings in SMOOTHERS
    }
    rows[REAL_LABEL] = {c.info.clip_id: commanded(robot, [c.angles_rad]) for c in clips}
    return rows


def command_path_table(
    checkpoint: Checkpoint,
    clips: Sequence[Clip],
    offline: dict[str, list[np.ndarray]],
    raw: dict[str, list[np.ndarray]],
    name: str,
    seeds: range,
    where: str,
) -> str:
    """The realism table of the commanded motion on ``clips``, with its heading.

    Rows: the model's commanded motion per smoother (:func:`command_path_predictions` of its
    ``raw`` samples, the model named ``name``), the real motion's (:data:`REAL_LABEL`) and, for
    reference, the model's ``offline`` synthesis of the same seeds (clip id -> samples); the
    evaluation adds its baselines. The heading gives each smoother's delay behind the offline
    synthesis (:func:`~audio2pose_ros.motion.filter.delay_s`, median over joints and samples).
    """
    rows = command_path_predictions(checkpoint.robot, clips, name, raw)
    quality = quality_evaluation(
        clips, {f"{name}, offline synthesis": offline} | rows, checkpoint.robot
    )
    references = [m for c in clips for m in offline[c.info.clip_id]]
    delays = []
    for settings in SMOOTHERS:
        motions = [m for c in clips for m in rows[commanded_label(name, settings)][c.info.clip_id]]
        delays.append(f"{smoother_name(settings)} {delay_s(references, motions):.2f} s")
    return (
        f"what the robot is commanded, {where}: the raw samples (seeds {seeds.start}.."
        f"{seeds.stop - 1}) through the motion filter at its shipped settings (smoothing "
        f"{smoother_name(SMOOTHERS[0])}; and with "
        f"{', '.join(smoother_name(s) for s in SMOOTHERS[1:])}), the real motion through the "
        "shipped filter (what the robot's limits alone cost), the offline synthesis for "
        f"reference; delay behind the offline synthesis: {', '.join(delays)}\n" + quality.table()
    )
