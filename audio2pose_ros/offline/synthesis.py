"""Offline synthesis: a whole utterance in, joint angles at 100 Hz out (seed 003 section 4.4.1).

Features of the whole signal are z-normalised with the checkpoint's statistics, the model predicts
range-normalised poses, nu^-1 maps them back to radians (eq. 3.14), the seed's zero-phase
5th-order 4 Hz Butterworth filter smooths them, and the result is clamped to the joint limits.
Every model works here, offline-only ones included; samplers (``model.stochastic``) draw one
motion with a given seed and temperature, so a synthesis is reproducible.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import torch

from audio2pose_ros.audio.features import extract_features
from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.motion.smoothing import butterworth_zero_phase


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
    features = extract_features(signal_16k, checkpoint.features)
    normalized = torch.tensor(checkpoint.normalizer.apply(features)[None], dtype=torch.float32)
    model = checkpoint.model
    with torch.no_grad():
        if model.stochastic and temperature > 0:
            generator = torch.Generator().manual_seed(seed)
            return model.sample(normalized, 1, generator, temperature)[0, 0].numpy()
        return model(normalized)[0].numpy()


def synthesize(
    checkpoint: Checkpoint,
    signal_16k: np.ndarray,
    smooth: bool = True,
    seed: int = 0,
    temperature: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Synthesize joint angles for a whole 16 kHz mono utterance.

    Args:
        checkpoint: loaded model with its features, normalisation and robot.
        signal_16k: float samples at 16 kHz in [-1, 1].
        smooth: apply the seed's zero-phase 4 Hz Butterworth low-pass.
        seed: seed of a sampler's noise (ignored by deterministic models).
        temperature: a sampler's noise scale; 0 gives its most likely motion.

    Returns:
        ``(times_s, angles_rad)``: (n_frames,) frame times from 0 at the feature step, and
        (n_frames, n_joints) angles within the joint limits, in the robot's joint order.

    """
    robot = checkpoint.robot
    angles = robot.denormalize(predict_normalized(checkpoint, signal_16k, seed, temperature))
    rate_hz = 1.0 / checkpoint.features.step_s
    if smooth:
        angles = butterworth_zero_phase(angles, rate_hz=rate_hz)
    angles = np.clip(angles, robot.lower_rad, robot.upper_rad)
    return np.arange(angles.shape[0]) / rate_hz, angles


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
