"""Synthetic speech-like data in which motion is a known causal function of loudness.

Loudness is a smooth random envelope in [0, 1]; the motion of every joint is an exponentially
smoothed (causal, ~50 ms) copy of it with a joint-specific gain and sign. With ``offset_std``,
two joints also carry a random offset per clip that the audio does not reveal: the one-to-many
part of the mapping that only samplers can represent.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from audio2pose_ros.data.dataset import Clip, ClipInfo, Dataset
from audio2pose_ros.learning.batches import Utterance

N_JOINTS = 11
GAINS = np.array([0.5, -0.4, 0.3, -0.5, 0.4, -0.3, 0.5, -0.4, 0.3, -0.5, 0.2])
OFFSET_JOINTS = (0, 1)


def loudness_envelope(n_frames: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth random loudness in [0, 1] at 100 frames/s (about 2 Hz bandwidth)."""
    sos = signal.butter(2, 2.0, fs=100.0, output="sos")
    raw = signal.sosfiltfilt(sos, rng.normal(size=n_frames + 200))[100:-100]
    return 1.0 / (1.0 + np.exp(-raw / (raw.std() + 1e-9) * 2.0))


def motion_from_loudness(envelope: np.ndarray, offset: np.ndarray | None = None) -> np.ndarray:
    """(T,) loudness -> (T, 11) targets in [0, 1]: causal smoothing, per-joint gain, offset."""
    smoothed = signal.lfilter([0.2], [1.0, -0.8], envelope - 0.5)
    targets = 0.5 + np.outer(smoothed, GAINS)
    if offset is not None:
        targets[:, OFFSET_JOINTS] += offset
    return np.clip(targets, 0.0, 1.0)


def synthetic_utterances(
    n: int, frames: int, seed: int, n_features: int = 26, offset_std: float = 0.0
) -> list[Utterance]:
    """In-memory utterances: features are the loudness on a spectral profile, plus noise."""
    rng = np.random.default_rng(seed)
    profile = np.linspace(1.0, 0.5, n_features)
    out = []
    for i in range(n):
        envelope = loudness_envelope(frames, rng)
        feats = 3.0 * np.outer(envelope - 0.5, profile) + 0.3 * rng.normal(
            size=(frames, n_features)
        )
        offset = rng.normal(scale=offset_std, size=len(OFFSET_JOINTS)) if offset_std else None
        targets = motion_from_loudness(envelope, offset)
        out.append(Utterance(f"u{seed}_{i}", feats, targets, np.ones_like(targets, dtype=bool)))
    return out


def mean_baseline_mse(train: list[Utterance], val: list[Utterance]) -> float:
    """Loss L of predicting the mean training pose on the validation utterances."""
    mean = np.concatenate([u.targets for u in train]).mean(axis=0)
    return float(np.mean(np.concatenate([(u.targets - mean) ** 2 for u in val])))


def write_dataset(
    root, robot, clips_per_split: dict[str, int], seconds: float, seed: int
) -> Dataset:
    """A data set folder whose audio is noise with the loudness envelope (16 kHz)."""
    rng = np.random.default_rng(seed)
    dataset = Dataset.create(root, robot)
    for split, count in clips_per_split.items():
        for i in range(count):
            n_samples = int(seconds * 16000)
            n_frames = 1 + (n_samples - 400) // 160
            envelope = loudness_envelope(n_frames, rng)
            gain_db = -40.0 + 40.0 * envelope
            gain = np.interp(
                np.arange(n_samples), 160 * np.arange(n_frames) + 200, 10 ** (gain_db / 20)
            )
            audio = (0.5 * gain * rng.uniform(-1, 1, n_samples)).astype(np.float32)
            angles = robot.denormalize(motion_from_loudness(envelope))
            speaker = f"s{i % 2}"
            info = ClipInfo(f"{split}{i}", speaker, "synthetic", "CC0-1.0", split)
            dataset.add(Clip(info, audio, angles, np.ones_like(angles, dtype=bool)), robot)
    return dataset


def synthetic_clips(
    root, robot, clips_per_split: dict[str, int], seconds: float, seed: int
) -> list[Clip]:
    """The clips of a new :func:`write_dataset` folder, loaded in index order."""
    dataset = write_dataset(root, robot, clips_per_split, seconds, seed)
    return [dataset.load(c.clip_id) for c in dataset.clips]
