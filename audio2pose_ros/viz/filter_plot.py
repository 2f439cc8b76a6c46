"""Raw against filtered trajectories for one speech file, as a PNG (``audio2pose plot-filter``).

The raw trajectory is the model's per-frame output in radians; the online trajectory is what
``motion_filter_node`` would command with the given settings (one pose per 10 ms tick, then the
smoother and the limits); the offline trajectory is the seed's zero-phase 4 Hz Butterworth
(seed 003 section 4.4.1), shown for reference.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from audio2pose_ros.checkpoints.torch_io import Checkpoint
from audio2pose_ros.motion.filter import MotionFilter, delay_s, online_filter
from audio2pose_ros.motion.smoothing import butterworth_zero_phase
from audio2pose_ros.offline.synthesis import predict_normalized
from audio2pose_ros.timebase import SAMPLE_RATE_HZ


def plot_raw_vs_filtered(
    checkpoint: Checkpoint,
    filt: MotionFilter,
    signal_16k: np.ndarray,
    output: Path,
    title: str = "",
) -> dict[str, float]:
    """Draw waveform + one panel per joint (raw, online filter, offline Butterworth) to ``output``.

    Returns:
        Figures for the note: per-joint-mean RMS velocity (rad/s) of raw and online trajectories
        and the online filter's mean lag behind the offline reference (s, by cross-correlation).
    """
    robot = checkpoint.robot
    raw = robot.denormalize(predict_normalized(checkpoint, signal_16k))
    rate_hz = 1.0 / filt.period_s
    online = online_filter(filt, raw)
    offline = np.clip(
        butterworth_zero_phase(raw, rate_hz=rate_hz), robot.lower_rad, robot.upper_rad
    )
    t_raw = np.arange(len(raw)) / rate_hz
    t_online = np.arange(1, len(online) + 1) / rate_hz

    fig, axes = plt.subplots(
        robot.n_joints + 1, 1, figsize=(12, 2.0 + 1.3 * robot.n_joints), sharex=True
    )
    t_audio = np.arange(len(signal_16k)) / SAMPLE_RATE_HZ
    axes[0].plot(t_audio, signal_16k, color="0.5", linewidth=0.4)
    axes[0].set_ylabel("audio")
    axes[0].set_title(title or "raw model output vs motion filter")
    for j, name in enumerate(robot.names):
        ax = axes[j + 1]
        ax.plot(t_raw, np.degrees(raw[:, j]), color="tab:red", linewidth=0.7, label="raw model")
        ax.plot(
            t_raw,
            np.degrees(offline[:, j]),
            color="tab:green",
            linewidth=1.0,
            label="offline 4 Hz Butterworth",
        )
        ax.plot(
            t_online,
            np.degrees(online[:, j]),
            color="tab:blue",
            linewidth=1.2,
            label=f"online filter ({filt.settings.smoothing})",
        )
        ax.axhline(np.degrees(robot.neutral_rad[j]), color="0.8", linewidth=0.6, zorder=0)
        ax.set_ylabel(f"{name}\n(deg)", fontsize=8)
    axes[1].legend(loc="upper right", fontsize=7, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=90)
    plt.close(fig)

    def rms_speed(x: np.ndarray) -> float:
        return float(np.mean(np.sqrt(np.mean((np.diff(x, axis=0) * rate_hz) ** 2, axis=0))))

    n = len(raw)
    return {
        "raw_rms_speed_rad_s": rms_speed(raw),
        "online_rms_speed_rad_s": rms_speed(online[:n]),
        "online_lag_s": delay_s([offline], [online], rate_hz),
    }
