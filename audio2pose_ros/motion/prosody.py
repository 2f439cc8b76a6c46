"""A transparent, hand-written prosody-to-gesture rule (not learned from human motion).

It is the fallback where no recorded motion of a speaker's arms exists (the default model's
arms are learned from a lecture recording; ``dataset build-default --arms prosody`` uses this
rule instead), and a baseline the arm evaluation compares with. It gives motion that
follows the voice and says openly what it is: loudness raises the forearms and nods the head,
the spectral balance (bright against dark voice) turns head and hip and makes the gesture
asymmetric. Its output is a (n_frames, n_joints) trajectory at the feature rate, clamped to the
joint limits; a frame-wise model can be trained to imitate it (``audio2pose distill-prosody``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from audio2pose_ros.motion.smoothing import butterworth_zero_phase
from audio2pose_ros.robot.description import RobotDescription


@dataclass(frozen=True)
class ProsodyRule:
    """Gesture amplitudes (rad) per joint at full loudness, and the loudness range used.

    ``loudness`` is the frame's log energy mapped linearly from its ``quiet_percentile`` (0) to its
    ``loud_percentile`` (1) within the utterance, clipped to [0, 1]. ``balance`` is tanh of the
    z-scored difference between the upper and lower halves of the log mel bands.
    """

    quiet_percentile: float = 20.0
    loud_percentile: float = 95.0
    head_pitch_rad: float = 0.12  # positive pitch bends the head down: a nod on stressed syllables
    head_yaw_rad: float = 0.30  # times balance
    shoulder_pitch_rad: float = 0.55  # forearms rise (pitch falls from pi/2)
    shoulder_roll_rad: float = 0.15  # elbows move away from the body
    elbow_roll_rad: float = 0.45  # elbows bend
    elbow_yaw_rad: float = 0.25  # palms turn up
    asymmetry: float = 0.35  # left/right amplitude difference, times balance
    hip_roll_rad: float = 0.04  # times balance

    def offsets(self, loudness: np.ndarray, balance: np.ndarray) -> dict[str, np.ndarray]:
        """Per-joint offsets from the neutral pose (rad) for each frame."""
        left = loudness * (1.0 + self.asymmetry * balance)
        right = loudness * (1.0 - self.asymmetry * balance)
        return {
            "HeadPitch": self.head_pitch_rad * loudness,
            "HeadYaw": self.head_yaw_rad * balance * loudness,
            "LShoulderPitch": -self.shoulder_pitch_rad * left,
            "RShoulderPitch": -self.shoulder_pitch_rad * right,
            "LShoulderRoll": self.shoulder_roll_rad * left,
            "RShoulderRoll": -self.shoulder_roll_rad * right,
            "LElbowRoll": -self.elbow_roll_rad * left,
            "RElbowRoll": self.elbow_roll_rad * right,
            "LElbowYaw": -self.elbow_yaw_rad * left,
            "RElbowYaw": self.elbow_yaw_rad * right,
            "HipRoll": self.hip_roll_rad * balance * loudness,
        }


def prosody_trajectory(
    log_filterbank: np.ndarray,
    robot: RobotDescription,
    rule: ProsodyRule | None = None,
    rate_hz: float = 100.0,
) -> np.ndarray:
    """Turn an utterance's LogFB frames into a smoothed joint trajectory by :class:`ProsodyRule`.

    Args:
        log_filterbank: (n_frames, n_bands) log mel filter-bank energies (seed 003 section 3.2).
        robot: joint order, neutral pose and limits.
        rule: amplitudes; ``None`` uses the defaults.
        rate_hz: frame rate of the features and of the result (100 Hz).

    Returns:
        (n_frames, n_joints) angles in radians, smoothed with the seed's 4 Hz Butterworth low-pass
        (seed 003 section 4.2.3) and clamped to the joint limits. Joints the rule does not name
        stay at neutral.

    """
    rule = rule or ProsodyRule()
    bands = np.asarray(log_filterbank, dtype=np.float64)
    energy = np.log(np.sum(np.exp(bands - bands.max()), axis=1)) + bands.max()
    quiet, loud = np.percentile(energy, [rule.quiet_percentile, rule.loud_percentile])
    loudness = np.clip((energy - quiet) / max(loud - quiet, 1e-9), 0.0, 1.0)  # flat input -> 0
    half = bands.shape[1] // 2
    tilt = bands[:, half:].mean(axis=1) - bands[:, :half].mean(axis=1)
    balance = np.tanh((tilt - tilt.mean()) / max(float(tilt.std()), 1e-9))

    trajectory = np.tile(robot.neutral_rad, (bands.shape[0], 1))
    for name, offset in rule.offsets(loudness, balance).items():
        if name in robot.names:
            trajectory[:, robot.names.index(name)] += offset
    smoothed = butterworth_zero_phase(trajectory, rate_hz=rate_hz)
    return np.clip(smoothed, robot.lower_rad, robot.upper_rad)
