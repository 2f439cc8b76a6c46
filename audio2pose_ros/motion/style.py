"""A speaker's style applied to generated motion: per part a size and a tempo; arm rest, height.

The style is defined once here and applied identically by the live motion filter (each tick,
before its smoothing, limits and body guard: :class:`~audio2pose_ros.motion.filter.MotionFilter`)
and offline (``audio2pose synth`` / ``render``, the evaluations: :meth:`StyleTransform.run`).
Its settings (:class:`StyleSettings`) are node parameters of ``motion_filter_node``, settable
live; a style measured from a person (:mod:`audio2pose_ros.style.figures`) resolves into them.

Per joint group ("part": head, arms, hip), one pose step is, in this order:

1. **Tempo** ``<part>_tempo`` (t, 1 = as generated), causal and without look-ahead. Below 1 a
   critically damped second-order low-pass (two equal first-order stages with time constant
   ``TEMPO_TAU_S * (1/t - 1)``) slows the motion: its output stays inside the range of its input
   (no overshoot). Above 1 the motion's fast part is emphasised: ``x + (t - 1) (x - s)`` with
   ``s`` a first-order low-pass of ``TEMPO_TAU_S``. At t = 1 both are the identity. Tempo
   changes the motion's frequency (speed per unit of size) and, by the low-pass, also its size;
   a resolved style sets the size after the tempo (:func:`~audio2pose_ros.style.figures.resolve`).
2. **Size** ``<part>_gain`` (g): scale about the robot's neutral pose (0 = still at neutral,
   1 = as generated); the operator console's amplitude gains.
3. **Arm rest** ``arms_rest_pitch_rad`` added to both shoulder pitches (positive: hands lower)
   and ``arms_rest_bend_rad`` to both elbows' bend (positive: more bent).
4. **Arm height** ``arms_raise_limit_rad``: a soft lower limit of the shoulder pitch (Pepper's
   arm rises as its pitch falls): ``limit + w softplus((x - limit) / w)``, smooth and monotonic,
   equal to ``x`` within 1e-4 rad from ``limit + 10 w`` up (w = ``RAISE_SOFTNESS_RAD``); at the
   joint's lower limit (the default) it is off.

A live change never makes a jump: the effective settings move from the old to the new ones along
a minimum-jerk path of ``STYLE_BLEND_S`` (:meth:`StyleTransform.update`). Every value is finite
by construction (bounded settings, stable softplus); a non-finite input pose is refused by the
filter's gate before it gets here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from audio2pose_ros.errors import InputError
from audio2pose_ros.motion.approach import minimum_jerk
from audio2pose_ros.parameters import param, validate_settings
from audio2pose_ros.robot.description import JOINT_GROUPS, RobotDescription

TEMPO_TAU_S = 0.1  # time constant scale of the tempo filters (s)
MIN_TEMPO, MAX_TEMPO = 0.2, 3.0
MAX_GAIN = 2.0
MAX_REST_OFFSET_RAD = 0.6
RAISE_SOFTNESS_RAD = 0.08  # width w of the soft height limit
STYLE_BLEND_S = 1.0  # a live style change blends in over this long (minimum-jerk)


def _gain(part: str) -> dict[str, object]:
    return param(
        f"style: size of {part} motion, a scale about neutral (0 = still, 1 = as generated)",
        minimum=0.0,
        maximum=MAX_GAIN,
    )


def _tempo(part: str) -> dict[str, object]:
    return param(
        f"style: tempo of {part} motion (below 1 slower and smoother, 1 = as generated, "
        "above 1 livelier); causal, applied before the size",
        minimum=MIN_TEMPO,
        maximum=MAX_TEMPO,
    )


@dataclass(frozen=True)
class StyleSettings:
    """A style as the filter applies it (see the module docstring); all live parameters.

    The defaults are the identity: the model's motion as generated.

    Attributes:
        head_gain: size of the head's motion about neutral.
        arms_gain: size of the arms' motion about neutral.
        hip_gain: size of the hip's motion about neutral.
        head_tempo: tempo of the head's motion.
        arms_tempo: tempo of the arms' motion.
        hip_tempo: tempo of the hip's motion.
        arms_rest_pitch_rad: added to both shoulder pitches (positive: hands rest lower).
        arms_rest_bend_rad: added to both elbows' bend (positive: more bent).
        arms_raise_limit_rad: soft lower limit of the shoulder pitch (how high the arms go).
    """

    head_gain: float = field(default=1.0, metadata=_gain("head"))
    arms_gain: float = field(default=1.0, metadata=_gain("arm"))
    hip_gain: float = field(default=1.0, metadata=_gain("hip"))
    head_tempo: float = field(default=1.0, metadata=_tempo("head"))
    arms_tempo: float = field(default=1.0, metadata=_tempo("arm"))
    hip_tempo: float = field(default=1.0, metadata=_tempo("hip"))
    arms_rest_pitch_rad: float = field(
        default=0.0,
        metadata=param(
            "style: added to both shoulder pitches (positive: the hands rest lower)",
            minimum=-MAX_REST_OFFSET_RAD,
            maximum=MAX_REST_OFFSET_RAD,
            unit="rad",
        ),
    )
    arms_rest_bend_rad: float = field(
        default=0.0,
        metadata=param(
            "style: added to both elbows' bend (positive: more bent)",
            minimum=-MAX_REST_OFFSET_RAD,
            maximum=MAX_REST_OFFSET_RAD,
            unit="rad",
        ),
    )
    arms_raise_limit_rad: float = field(
        default=-2.0857,
        metadata=param(
            "style: soft lower limit of the shoulder pitch, how high the arms may rise "
            "(-2.0857, the joint's limit: off)",
            minimum=-2.0857,
            maximum=1.5708,
            unit="rad",
        ),
    )

    def __post_init__(self) -> None:
        """Validate every field against its declaration.

        Raises:
            ConfigurationError: a value is refused (NaN, inf, out of range, wrong type).
        """
        validate_settings(self)


STYLE_FIELDS = tuple(f.name for f in dataclasses.fields(StyleSettings))
IDENTITY = StyleSettings()


def _bend_signs(robot: RobotDescription) -> np.ndarray:
    """+1 / -1 on the elbow-roll joints in the direction of more bend, 0 elsewhere.

    Pepper's left elbow bends towards negative roll, the right towards positive.
    """
    signs = np.zeros(robot.n_joints)
    for j, name in enumerate(robot.names):
        if name.endswith("ElbowRoll"):
            signs[j] = -1.0 if name.startswith("L") else 1.0
    return signs


def _pitch_mask(robot: RobotDescription) -> np.ndarray:
    return np.array([name.endswith("ShoulderPitch") for name in robot.names])


@dataclass(frozen=True)
class _Effective:
    """Per-joint vectors of a style: gain, tempo, offset, raise limit and how far it is on.

    ``limit`` is finite everywhere; ``on`` is 1 where the soft height limit acts, 0 where it does
    not, and in between while a blend switches it on or off, so a blend never mixes an infinite
    "no limit" with a finite one (which gives NaN) and the limit fades in instead of snapping.
    """

    gain: np.ndarray
    tempo: np.ndarray
    offset: np.ndarray
    limit: np.ndarray
    on: np.ndarray

    def blend(self, other: _Effective, fraction: float) -> _Effective:
        def mix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.asarray(a + fraction * (b - a))

        # where only one side limits, the limit is that side's; ``on`` fades it in or out
        limit = np.where(self.on > 0.0, self.limit, other.limit)
        other_limit = np.where(other.on > 0.0, other.limit, self.limit)
        return _Effective(
            mix(self.gain, other.gain),
            mix(self.tempo, other.tempo),
            mix(self.offset, other.offset),
            mix(limit, other_limit),
            mix(self.on, other.on),
        )


class StyleTransform:
    """The causal, per-step style transform of one trajectory stream (see the module docstring).

    Args:
        robot: the robot whose joints the poses hold.
        settings: the style (default: the identity).
        rate_hz: frame rate of the poses (the filter's clock, or 100 Hz offline).
    """

    def __init__(
        self, robot: RobotDescription, settings: StyleSettings | None = None, rate_hz: float = 100.0
    ) -> None:
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise InputError(f"rate_hz must be a positive number, got {rate_hz!r}")
        self.robot = robot
        self.period_s = 1.0 / rate_hz
        self.neutral_rad = robot.neutral_rad.copy()
        self._masks = {part: robot.group_mask(part) for part in JOINT_GROUPS}
        self._bend = _bend_signs(robot)
        self._pitch = _pitch_mask(robot)
        self._lower = robot.lower_rad
        self.settings = settings or IDENTITY
        self._current = self._vectors(self.settings)
        self._blend_from: _Effective | None = None
        self._blend_s = 0.0
        self._slow: np.ndarray | None = None  # two low-pass stages (tempo < 1), (2, J)
        self._fast: np.ndarray | None = None  # the low-pass of the emphasis (tempo > 1), (J,)

    def _vectors(self, settings: StyleSettings) -> _Effective:
        n = self.robot.n_joints
        gain, tempo = np.ones(n), np.ones(n)
        for part, mask in self._masks.items():
            gain[mask] = getattr(settings, f"{part}_gain")
            tempo[mask] = getattr(settings, f"{part}_tempo")
        offset = np.where(self._pitch, settings.arms_rest_pitch_rad, 0.0)
        offset = offset + self._bend * settings.arms_rest_bend_rad
        limit = np.where(self._pitch, settings.arms_raise_limit_rad, self._lower)
        on = (limit > self._lower).astype(np.float64)  # at the joint's limit: off
        return _Effective(gain, tempo, offset, limit, on)

    @property
    def is_identity(self) -> bool:
        """True when the style in force (and any blend) leaves every pose unchanged."""
        return self.settings == IDENTITY and self._blend_from is None

    def update(self, settings: StyleSettings) -> None:
        """Take a new style, blended in over ``STYLE_BLEND_S`` from the one in force now."""
        if settings == self.settings:
            return
        self._blend_from = self._effective()
        self._blend_s = 0.0
        self.settings = settings
        self._current = self._vectors(settings)

    def _effective(self) -> _Effective:
        if self._blend_from is None:
            return self._current
        fraction = minimum_jerk(self._blend_s / STYLE_BLEND_S)
        return self._blend_from.blend(self._current, fraction)

    def reset(self, pose_rad: np.ndarray | None = None) -> None:
        """Forget the tempo filters' memory: the next pose starts them at rest there."""
        del pose_rad  # the filters start from the next pose itself
        self._slow = None
        self._fast = None

    def static(self, pose_rad: np.ndarray) -> np.ndarray:
        """The pose with size, rest and height applied and no tempo memory (a filter restart)."""
        return self._shape(np.asarray(pose_rad, dtype=np.float64), self._effective())

    def _shape(self, pose: np.ndarray, eff: _Effective) -> np.ndarray:
        shaped = self.neutral_rad + eff.gain * (pose - self.neutral_rad) + eff.offset
        limited = eff.on > 0.0
        if limited.any():
            width = RAISE_SOFTNESS_RAD
            low, free = eff.limit[limited], shaped[limited]
            soft = low + width * np.logaddexp(0.0, (free - low) / width)
            shaped[limited] = free + eff.on[limited] * (soft - free)
        return np.asarray(shaped)

    def step(self, pose_rad: np.ndarray) -> np.ndarray:
        """The styled pose for the next frame (causal: only this and earlier poses count)."""
        pose = np.asarray(pose_rad, dtype=np.float64)
        if pose.shape != (self.robot.n_joints,):
            raise InputError(f"a pose must have {self.robot.n_joints} angles, got {pose.shape}")
        if self.is_identity:  # the filter's default: no work, and the tempo filters start fresh
            self._slow = self._fast = None  # from the pose in force when a style is set
            return pose.copy()
        eff = self._effective()
        if self._blend_from is not None:
            self._blend_s += self.period_s
            if self._blend_s >= STYLE_BLEND_S:
                self._blend_from = None
        if self._slow is None or self._fast is None:
            self._slow = np.stack([pose, pose])
            self._fast = pose.copy()
        slow_tau = TEMPO_TAU_S * np.maximum(1.0 / eff.tempo - 1.0, 0.0)
        alpha = 1.0 - np.exp(-self.period_s / np.maximum(slow_tau, 1e-12))
        self._slow[0] += alpha * (pose - self._slow[0])
        self._slow[1] += alpha * (self._slow[0] - self._slow[1])
        self._fast += (1.0 - np.exp(-self.period_s / TEMPO_TAU_S)) * (pose - self._fast)
        paced = np.where(
            eff.tempo < 1.0,
            self._slow[1],
            pose + np.maximum(eff.tempo - 1.0, 0.0) * (pose - self._fast),
        )
        return self._shape(paced, eff)

    def run(self, poses_rad: np.ndarray) -> np.ndarray:
        """Style a whole trajectory (n_frames, n_joints) frame by frame, as the filter would.

        The transform starts fresh (:meth:`reset`) at the first frame; an identity style returns
        a copy of the input.

        Raises:
            InputError: the trajectory has the wrong shape or holds a non-finite angle.
        """
        poses = np.asarray(poses_rad, dtype=np.float64)
        if poses.ndim != 2 or poses.shape[1] != self.robot.n_joints:
            raise InputError(
                f"a trajectory must be (frames, {self.robot.n_joints}), got {poses.shape}"
            )
        if not np.isfinite(poses).all():
            raise InputError("a trajectory to style holds a non-finite angle")
        self.reset()
        if self.is_identity:
            return poses.copy()
        return np.array([self.step(pose) for pose in poses]).reshape(poses.shape)


def style_trajectory(
    robot: RobotDescription, settings: StyleSettings, poses_rad: np.ndarray, rate_hz: float
) -> np.ndarray:
    """``poses_rad`` (n_frames, n_joints) styled as the live filter styles them, then clipped.

    The clip into the joint ranges stands in offline for the live filter's limiter.
    """
    styled = StyleTransform(robot, settings, rate_hz).run(poses_rad)
    return np.clip(styled, robot.lower_rad, robot.upper_rad)
