"""A causal speech gate on normalised audio features (numpy only, no torch).

Used by the ``live_groups`` model (:mod:`audio2pose_ros.models.live_groups`) to scale its
sampling noise: people keep still when they stop talking. The frame's mean z-normalised log
filter-bank energy e_t is compared with a slowly decaying peak of recent energy,
peak_t = max(e_t, peak_(t-1) - :data:`PEAK_DECAY_PER_S` / rate); activity
v_t = sigmoid((e_t - peak_t + margin) / width) is smoothed with a first-order low-pass of time
constant :data:`GATE_TAU_S`, s_t, and the factor is rest + (1 - rest) s_t. Relative to the
recent peak, it does not depend on the recording level. Torch-free, so the numpy runtime
(:mod:`audio2pose_ros.checkpoints.numpy_runtime`) can use it too.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.timebase import FRAME_PERIOD_S

if TYPE_CHECKING:
    from audio2pose_ros.models.body_noise import BodyNoise
    from audio2pose_ros.robot.description import RobotDescription

GATE_TAU_S = 0.3  # smoothing of the speech gate
PEAK_DECAY_PER_S = 0.3  # z-units per second the energy peak forgets
PART_CORRELATION_KEYS = ("first_correlation", "second_correlation")  # of the two parts, in order
PART_BURST_KEYS = ("first_burst", "second_burst")  # likewise
PART_TEMPERATURE_KEYS = ("first_temperature", "second_temperature")  # likewise

Factor = float | np.ndarray  # a part's temperature factor: one, or (J,) one per joint of the part


def part_correlations(config: Mapping[str, Any]) -> tuple[float, float]:
    """Each part's noise correlation: its own key where the config sets one, else the shared one.

    ``config`` is a grouped sampler's configuration (``noise_correlation`` and, optionally,
    :data:`PART_CORRELATION_KEYS`; a key that is absent or None takes ``noise_correlation``).
    """
    shared = float(config["noise_correlation"])
    first, second = (
        shared if config.get(key) is None else float(config[key]) for key in PART_CORRELATION_KEYS
    )
    return first, second


def part_bursts(config: Mapping[str, Any]) -> tuple[object, object]:
    """Each part's noise burstiness (:data:`PART_BURST_KEYS`) as given; absent is 0.

    Older checkpoints lack the keys. A part's value is a number, or one number per joint of
    the part; :func:`~audio2pose_ros.models.sampling_noise.check_burst` checks it against the
    part's joints.
    """
    first, second = (config.get(key, 0.0) for key in PART_BURST_KEYS)
    return first, second


def part_factor(value: float | Sequence[float]) -> Factor:
    """A part's temperature as a sampler multiplies it: a number, or an array of one per joint."""
    return np.array(value, dtype=np.float64) if isinstance(value, Sequence) else float(value)


def check_velocity_limit(value: object) -> float:
    """A velocity limit factor in [0, 1] (0 = off).

    Raises:
        ConfigurationError: not a number, or outside [0, 1] (NaN included).

    """
    if (
        not isinstance(value, int | float)
        or isinstance(value, bool)
        or not (math.isfinite(value) and 0.0 <= value <= 1.0)
    ):
        raise ConfigurationError(f"velocity_limit must be in [0, 1], got {value!r}")
    return float(value)


def part_step_limits(
    robot: RobotDescription | None,
    groups: Sequence[np.ndarray],
    velocity_limit: float,
    frame_period_s: float = FRAME_PERIOD_S,
) -> tuple[np.ndarray, ...] | None:
    """Per part, the largest step per frame of each of its joints, in normalised pose units.

    ``velocity_limit`` times the joint's velocity limit times the frame period, over the
    joint's range (poses are normalised to [0, 1] by the range: seed 003 eq. 3.14): a sampled
    pose then never moves a joint faster than the robot can, so the motion filter's input gate
    (:mod:`audio2pose_ros.motion.gate`) never drops one, and the sampler is fed back the pose
    the robot can follow. None (no limit) without a robot or with a factor of 0.
    """
    if robot is None or not velocity_limit:
        return None
    step = velocity_limit * robot.max_velocity_rad_s * frame_period_s
    unit = step / (robot.upper_rad - robot.lower_rad)
    return tuple(unit[joints] for joints in groups)


def nonzero(factor: Factor) -> bool:
    """``np.any(factor)`` without its wrapper (a frame's work is mostly numpy's call overhead)."""
    return bool(factor.any()) if isinstance(factor, np.ndarray) else bool(factor)


class SpeechGate:
    """Causal speech activity in [0, 1] from normalised features (see the module docstring)."""

    def __init__(self, rest: float, margin: float, width: float, rate_hz: float = 100.0) -> None:
        """Start silent, with the peak at the training audio's mean energy (0).

        Args:
            rest: factor in silence (1 = no gate).
            margin: how far (z-units) below the recent peak the energy may fall and count as
                speech.
            width: softness of that threshold (z-units).
            rate_hz: frame rate.

        """
        self.rest, self.margin, self.width = rest, margin, width
        self.smoothing = float(np.exp(-1.0 / (GATE_TAU_S * rate_hz)))
        self.decay = PEAK_DECAY_PER_S / rate_hz
        self.reset()

    def reset(self) -> None:
        """Forget the peak and the smoothed activity."""
        self.peak, self.level = 0.0, 0.0

    def step(self, features: np.ndarray) -> float:
        """Temperature factor of one frame: rest + (1 - rest) * smoothed activity."""
        if self.rest >= 1.0:
            return 1.0
        energy = float(np.add.reduce(features) / features.shape[-1])  # np.mean, without its checks
        self.peak = max(energy, self.peak - self.decay)
        active = 1.0 / (1.0 + np.exp(-(energy - self.peak + self.margin) / self.width))
        self.level = self.smoothing * self.level + (1.0 - self.smoothing) * active
        return self.rest + (1.0 - self.rest) * self.level

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(T, F) frames of one utterance -> (T,) factors, from a fresh state."""
        self.reset()
        return np.array([self.step(frame) for frame in frames])


class SamplerPart(Protocol):
    """One part of a grouped sampler: a seeded per-frame sampler with a settable temperature."""

    temperature: Factor
    max_step: np.ndarray | None

    def reset(self, seed: int) -> None:
        """Forget the state and restart the noise from ``seed``."""

    def step(self, features: np.ndarray) -> np.ndarray:
        """Sample the part's joints for one frame."""


class GroupedSampler:
    """Parts sampling disjoint joint groups, their noise scaled by one :class:`SpeechGate`.

    Shared by the torch model's predictor and the numpy runtime's kernel of ``live_groups``.
    A subclass sets ``_groups`` (joint indices per part), ``_parts``, ``_factors`` (each part's
    own temperature, :func:`part_factor`), ``_gate``, ``_n_joints``, ``seed`` and
    ``temperature``, and may set ``_body_noise``, ``_body_part`` and ``_max_steps``
    (:func:`part_step_limits`). Per frame part k samples at temperature * its factor *
    the gate's factor (0 at temperature 0) with seed ``seed + k``, the part ``_body_part`` also
    times the body-aware factor of the previous pose (:mod:`audio2pose_ros.models.body_noise`),
    each joint's step bounded by ``_max_steps`` when sampling (temperature > 0), and its pose
    is scattered into the robot's joint order.
    """

    _groups: Sequence[np.ndarray]
    _parts: Sequence[SamplerPart]
    _factors: Sequence[Factor]
    _gate: SpeechGate
    _n_joints: int
    seed: int
    temperature: float

    _body_noise: BodyNoise | None = None  # with the index of the part it scales
    _body_part: int = -1
    _max_steps: Sequence[np.ndarray] | None = None
    _previous: np.ndarray | None = None

    def reset(self, seed: int | None = None) -> None:
        """Forget the state; optionally change the seed."""
        if seed is not None:
            self.seed = seed
        self._gate.reset()
        for k, part in enumerate(self._parts):
            part.reset(self.seed + k)
        self._previous = None
        if self._body_noise is not None:
            self._body_noise.reset()

    def step(self, features: np.ndarray) -> np.ndarray:
        """Sample the pose of one (n_features,) frame: (n_joints,) in [0, 1]."""
        return self._sample(features, np.empty(self._n_joints))

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames in order -> (N, n_joints) sampled poses (one new array)."""
        poses = np.empty((len(frames), self._n_joints))
        for t in range(len(frames)):  # (indexing: quicker than iterating over the arrays)
            self._sample(frames[t], poses[t])
        if len(poses):
            self._previous = poses[-1].copy()  # the caller's to change
        return poses

    def _sample(self, features: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """:meth:`step` into ``pose``, which stays the previous pose until the next frame."""
        scale = self._gate.step(features) if self.temperature else 0.0
        limits = self._max_steps if self.temperature else None
        for k, (joints, part, factor) in enumerate(
            zip(self._groups, self._parts, self._factors, strict=True)
        ):
            part.temperature = self.temperature * factor * scale
            body = self._body_noise if k == self._body_part else None
            if body is not None and self._previous is not None and nonzero(part.temperature):
                part.temperature *= body.factor(self._previous)
            part.max_step = None if limits is None else limits[k]
            pose[joints] = part.step(features)
        self._previous = pose
        return pose
