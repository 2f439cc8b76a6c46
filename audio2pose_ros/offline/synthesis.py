"""Offline synthesis: a whole utterance in, joint angles at 100 Hz out (seed 003 section 4.4.1).

Features of the whole signal are z-normalised with the checkpoint's statistics, the model predicts
range-normalised poses, nu^-1 maps them back to radians (eq. 3.14), the seed's zero-phase
5th-order 4 Hz Butterworth filter smooths them, the result is clamped to the joint limits and,
last, the self-collision guard of the live filter keeps every arm clear of the body
(:func:`~audio2pose_ros.motion.body_guard.guard_trajectory`), so offline motion obeys the same
margin as the commands of ``motion_filter_node``.
Every model works here, offline-only ones included; samplers (``model.stochastic``) draw one
motion with a given seed and temperature, so a synthesis is reproducible. Streaming models start
settled, as online (:mod:`audio2pose_ros.models.warm_start`).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from audio2pose_ros.audio.features import extract_features
from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.models.warm_start import WARM_START_FRAMES, with_warm_start
from audio2pose_ros.motion.body_guard import BodyGuard, guard_trajectory
from audio2pose_ros.motion.filter_settings import MotionFilterSettings
from audio2pose_ros.motion.smoothing import butterworth_zero_phase
from audio2pose_ros.motion.style import StyleSettings, style_trajectory
from audio2pose_ros.robot.body import BodyModel


def normalized_features(checkpoint: Checkpoint, signal_16k: np.ndarray) -> np.ndarray:
    """The checkpoint's features of an utterance, z-normalised: (n_frames, n_features)."""
    return checkpoint.normalizer.apply(extract_features(signal_16k, checkpoint.features))


def sample_normalized(
    checkpoint: Checkpoint,
    frames: np.ndarray,
    n_samples: int = 1,
    seed: int = 0,
    temperature: float = 1.0,
) -> np.ndarray:
    """Model output for one utterance's normalised features: (n_samples, n_frames, n_joints).

    Streaming models start settled (:mod:`audio2pose_ros.models.warm_start`; samplers keep
    their noise out of the warm-up, as online). Samplers draw
    ``n_samples`` motions from a generator seeded with ``seed`` (sample 0 is the motion of
    ``seed``); deterministic models, and temperature 0, repeat their one motion.
    """
    model = checkpoint.model
    warm_up = WARM_START_FRAMES if model.streaming and len(frames) else 0
    if warm_up:
        frames = with_warm_start(frames, warm_up)
    normalized = torch.tensor(frames[None], dtype=torch.float32)
    with torch.no_grad():
        if model.stochastic and temperature > 0:
            generator = torch.Generator().manual_seed(seed)
            poses = model.sample(normalized, n_samples, generator, temperature, warm_up)[:, 0]
        else:
            poses = model(normalized).expand(n_samples, -1, -1)
    return poses.numpy()[:, warm_up:]


def predict_normalized(
    checkpoint: Checkpoint, signal_16k: np.ndarray, seed: int = 0, temperature: float = 1.0
) -> np.ndarray:
    """Raw model output for a whole utterance: (n_frames, n_joints) in [0, 1].

    Args:
        checkpoint: loaded model with its features and normalisation.
        signal_16k: float samples at 16 kHz.
        seed: seed of a sampler's noise (ignored by deterministic models).
        temperature: a sampler's noise scale; 0 gives its most likely motion.

    """
    frames = normalized_features(checkpoint, signal_16k)
    return sample_normalized(checkpoint, frames, 1, seed, temperature)[0]


def to_angles(checkpoint: Checkpoint, poses: np.ndarray, smooth: bool = True) -> np.ndarray:
    """(n_frames, n_joints) poses in [0, 1] -> radians, smoothed, within the limits.

    nu^-1 (eq. 3.14), then the seed's zero-phase 4 Hz Butterworth low-pass along the frames
    (``smooth``), then the joint limits.
    """
    robot = checkpoint.robot
    angles = robot.denormalize(poses)
    if smooth:
        angles = butterworth_zero_phase(angles, rate_hz=1.0 / checkpoint.features.step_s)
    return np.clip(angles, robot.lower_rad, robot.upper_rad)


def synthesize_samples(
    checkpoint: Checkpoint, signal_16k: np.ndarray, seeds: Sequence[int], smooth: bool = True
) -> list[np.ndarray]:
    """One utterance's angles for each seed, its features extracted once.

    Element i equals ``synthesize(checkpoint, signal_16k, smooth, seeds[i],
    body_margin_m=None)[1]`` (temperature 1, before the body guard); unsmoothed, they are the
    poses the inference node sends.
    """
    return [
        to_angles(checkpoint, poses, smooth)
        for poses in sample_poses(checkpoint, signal_16k, seeds)
    ]


def sample_poses(
    checkpoint: Checkpoint, signal_16k: np.ndarray, seeds: Sequence[int]
) -> list[np.ndarray]:
    """One utterance's model output for each seed, (n_frames, n_joints) in [0, 1].

    The features are extracted once. :func:`to_angles` turns an element into the offline
    synthesis (smoothed) or into the poses the inference node sends (unsmoothed), so a caller
    that needs both samples once.
    """
    frames = normalized_features(checkpoint, signal_16k)
    return [sample_normalized(checkpoint, frames, 1, s)[0] for s in seeds]


def synthesize(
    checkpoint: Checkpoint,
    signal_16k: np.ndarray,
    smooth: bool = True,
    seed: int = 0,
    temperature: float = 1.0,
    body_margin_m: float | None = MotionFilterSettings.body_margin_m,
    style: StyleSettings | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Synthesize joint angles for a whole 16 kHz mono utterance.

    Args:
        checkpoint: loaded model with its features, normalisation and robot.
        signal_16k: float samples at 16 kHz in [-1, 1].
        smooth: apply the seed's zero-phase 4 Hz Butterworth low-pass.
        seed: seed of a sampler's noise (ignored by deterministic models).
        temperature: a sampler's noise scale; 0 gives its most likely motion.
        body_margin_m: clearance kept between the arms and the body (m), as the live filter's
            parameter of that name; None returns the model's motion unguarded (for measuring
            how often the guard is needed).
        style: the speaker's style, applied as the live filter applies it
            (:mod:`~audio2pose_ros.motion.style`), before the body guard; None: as generated.

    Returns:
        ``(times_s, angles_rad)``: (n_frames,) frame times from 0 at the feature step, and
        (n_frames, n_joints) angles within the joint limits, in the robot's joint order.

    """
    angles = to_angles(
        checkpoint, predict_normalized(checkpoint, signal_16k, seed, temperature), smooth
    )
    if style is not None:
        angles = style_trajectory(checkpoint.robot, style, angles, 1.0 / checkpoint.features.step_s)
    if body_margin_m is not None:
        guard = BodyGuard(BodyModel.load(checkpoint.robot), body_margin_m)
        angles = guard_trajectory(guard, angles, 1.0 / checkpoint.features.step_s)
    return np.arange(angles.shape[0]) / (1.0 / checkpoint.features.step_s), angles


def write_trajectory_csv(
    path: str | Path, times_s: np.ndarray, angles_rad: np.ndarray, joint_names: tuple[str, ...]
) -> Path:
    """Write ``time_s`` and one column per joint (radians) to a CSV file."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.open("w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(["time_s", *joint_names])
        for t, row in zip(times_s, angles_rad, strict=True):
            writer.writerow([f"{t:.3f}", *(f"{v:.6f}" for v in row)])
    return out
