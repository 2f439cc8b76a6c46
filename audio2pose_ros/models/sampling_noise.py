"""The live sampler's noise: smooth, unit-variance, optionally bursty (numpy only, no torch).

The live model (:mod:`audio2pose_ros.models.live`) samples y_t = mu_t + temperature * sigma_t *
e_t. Its noise e_t is white noise n_t filtered by an AR(1) stage,
e_t = rho e_(t-1) + sqrt(1 - rho^2) n_t with e_0 = n_0, once (``order`` 1) or twice in cascade
(``order`` 2, rescaled to unit variance), so samples wander smoothly instead of jittering at
100 Hz.

Real head and arm speed is heavy-tailed: long stretches of near stillness and short quick
movements. Gaussian noise of one fixed size gives speeds of one typical size instead. With
``burst`` b > 0 the white innovations are scaled by a slowly varying log-normal envelope,
n_t = w_t exp(b z_t - b^2), where z_t is a unit-variance AR(1) of coefficient
:data:`BURST_CORRELATION` (about half a second at 100 Hz) started at z_0 = its first draw; since
E[exp(2 b z - 2 b^2)] = 1 for z ~ N(0, 1) the noise keeps unit variance, only its speed is spread
over quiet stretches and bursts (a stochastic-volatility process). ``burst`` 0 is the plain
noise, drawing exactly as before.

``burst`` may also be one value per joint, b_j, over the one envelope z_t:
n_(t,j) = w_(t,j) exp(b_j z_t - b_j^2). Each joint keeps unit variance; the joints move in
bursts at the same moments, each as bursty as its b_j. People turn their heads in rarer,
quicker bursts than they nod (in the Obama clips the p99/p50 ratio of yaw speed is about 8, of
pitch about 6), which one shared b cannot give both joints.

Offline (:meth:`NoiseShape.filter`, a whole utterance at once) and streaming
(:class:`NoiseStream`, frame by frame) produce the same numbers from the same draws: per frame
:meth:`NoiseShape.draws` standard normals, the joints' first and the envelope's last.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from audio2pose_ros.errors import ConfigurationError

PerJoint = float | tuple[float, ...]  # one value for every joint of a part, or one per joint
Burst = PerJoint  # a burstiness: one for every joint, or one per joint

BURST_CORRELATION = 0.98  # AR(1) coefficient of the burst envelope's log: ~0.5 s at 100 Hz
MAX_BURST = 2.0  # exp(2 b^2) inflates rare peaks; beyond this the envelope is mostly spikes
NORMAL_BLOCK = 64  # frames of a streaming sampler's standard normals drawn at once


def check_per_joint(value: object, n_joints: int, name: str, high: float = math.inf) -> PerJoint:
    """``value`` as a :data:`PerJoint`: a number, or one number per joint, each in [0, high].

    A list (as a checkpoint's JSON config holds it) becomes a tuple.

    Raises:
        ConfigurationError: not a number or a sequence of ``n_joints`` numbers, or a value
            outside [0, ``high``] (NaN and infinity included).

    """
    per_joint = isinstance(value, Sequence) and not isinstance(value, str)
    values: list[object] = list(value) if isinstance(value, Sequence) and per_joint else [value]
    if per_joint and len(values) != n_joints:
        raise ConfigurationError(
            f"{name} must be a number or {n_joints} numbers (one per joint), got {value!r}"
        )
    checked = []
    for v in values:
        if (
            not isinstance(v, int | float)
            or isinstance(v, bool)
            or not 0.0 <= v <= high  # False for NaN
            or not math.isfinite(v)
        ):
            bound = f"[0, {high}]" if math.isfinite(high) else "finite and >= 0"
            raise ConfigurationError(f"{name} must be {bound}, got {value!r}")
        checked.append(float(v))
    return tuple(checked) if per_joint else checked[0]


def check_burst(value: object, n_joints: int, name: str = "burst") -> Burst:
    """``value`` as a :data:`Burst`: :func:`check_per_joint` with values in [0, MAX_BURST]."""
    return check_per_joint(value, n_joints, name, MAX_BURST)


def is_bursty(burst: Burst) -> bool:
    """Whether any joint's burstiness is above 0 (the noise then draws an envelope)."""
    return any(burst) if isinstance(burst, tuple) else bool(burst)


def format_per_joint(value: PerJoint) -> str:
    """``0.6``, or per joint ``0/1.2``; a run of n equal joints as ``4x8`` (``4x8/1``)."""
    if not isinstance(value, tuple):
        return f"{value:g}"
    runs = [(v, len(list(same))) for v, same in itertools.groupby(value)]
    return "/".join(f"{v:g}x{n}" if n > 1 else f"{v:g}" for v, n in runs)


@dataclass(frozen=True)
class NoiseShape:
    """Correlation, smoothness and burstiness of the sampling noise.

    Attributes:
        rho: AR(1) coefficient in [0, 1) (0 = white).
        order: AR(1) stages in cascade, 1 or 2.
        burst: log-std of the burst envelope, in [0, :data:`MAX_BURST`] (0 = none); a
            number for every joint or a tuple of one per joint (:func:`check_burst`).

    """

    rho: float
    order: int = 1
    burst: Burst = 0.0

    @cached_property
    def innovation(self) -> float:
        """sqrt(1 - rho^2): the weight of a new draw in one AR(1) step."""
        return math.sqrt(1.0 - self.rho * self.rho)

    @cached_property
    def second_gain(self) -> float:
        """Std of a second AR(1) stage run on unit-variance AR(1) noise."""
        return math.sqrt((1.0 + self.rho * self.rho) / (1.0 - self.rho * self.rho))

    def draws(self, n_joints: int) -> int:
        """Standard normals drawn per frame: one per joint, and one for the envelope."""
        return n_joints + (1 if self.bursty else 0)

    @cached_property
    def bursty(self) -> bool:
        """Whether the noise has a burst envelope (:func:`is_bursty`)."""
        return is_bursty(self.burst)

    @cached_property
    def burst_array(self) -> np.ndarray:
        """The burstiness as an array: () for every joint, or (J,) per joint."""
        return np.asarray(self.burst, dtype=float)

    def _envelope(self, z_draws: np.ndarray) -> np.ndarray:
        """exp(b z_t - b^2) per joint for the envelope's draws (..., T) -> (..., T, 1 or J)."""
        z = _ar1(z_draws, BURST_CORRELATION, axis=-1)[..., None]
        b = self.burst_array
        return np.exp(b * z - b * b)

    def filter(self, white: np.ndarray) -> np.ndarray:
        """(N, T, draws) standard normals -> (N, T, J) unit-variance noise, whole utterances."""
        from scipy import signal

        joints = white.shape[-1] - (1 if self.bursty else 0)
        innovations = white[..., :joints]
        if self.bursty:
            innovations = innovations * self._envelope(white[..., joints])
        first = _ar1(innovations, self.rho, axis=1)
        if self.order == 1:
            return first
        first[:, 0] *= self.second_gain / self.innovation  # stationary variance from frame 0
        second = signal.lfilter([self.innovation], [1.0, -self.rho], first, axis=1)
        return second / self.second_gain


def _ar1(draws: np.ndarray, rho: float, axis: int) -> np.ndarray:
    """x_t = rho x_(t-1) + sqrt(1 - rho^2) d_t along ``axis``, started at x_0 = d_0."""
    from scipy import signal

    innovation = math.sqrt(1.0 - rho * rho)
    scaled = np.moveaxis(draws, axis, 0).copy()
    scaled[0] /= innovation  # so that x_0 = d_0, already unit variance
    return np.moveaxis(signal.lfilter([innovation], [1.0, -rho], scaled, axis=0), 0, axis)


class NormalBlocks:
    """A generator's standard normals, ``draws`` a frame, drawn :data:`NORMAL_BLOCK` frames at once.

    The generator fills a block in order, so the numbers are those of drawing frame by frame
    (``rng.standard_normal(draws)``); one call of the generator costs more than the few numbers
    a frame takes. A frame's numbers are a view of the block, never written again.
    """

    def __init__(self, rng: np.random.Generator, draws: int) -> None:
        """Draw from ``rng`` (which nothing else draws from), ``draws`` numbers a frame."""
        self._rng = rng
        self._block, self._row = np.empty((0, draws)), 0

    def next(self) -> np.ndarray:
        """The next frame's (draws,) standard normals."""
        if self._row == len(self._block):
            self._block, self._row = (
                self._rng.standard_normal((NORMAL_BLOCK, self._block.shape[1])),
                0,
            )
        self._row += 1
        return self._block[self._row - 1]


class NoiseStream:
    """The same noise as :meth:`NoiseShape.filter`, one frame at a time."""

    def __init__(self, shape: NoiseShape, n_joints: int) -> None:
        """Noise of ``shape`` for ``n_joints`` joints; call :meth:`start` before :meth:`next`."""
        self.shape = shape
        self.n_joints = n_joints
        # the weights as 0-d arrays: numpy's ufuncs take them quicker than Python floats
        self._rho, self._innovation, self._gain = (
            np.full((), value) for value in (shape.rho, shape.innovation, shape.second_gain)
        )
        self._rho_z = BURST_CORRELATION
        self._innovation_z = math.sqrt(1.0 - BURST_CORRELATION * BURST_CORRELATION)
        self._noise = np.zeros(n_joints)
        self._smooth = np.zeros(n_joints)
        self._z = 0.0

    def _innovations(self, draw: np.ndarray, first: bool) -> np.ndarray:
        if not self.shape.bursty:
            return draw
        z = float(draw[self.n_joints])
        self._z = z if first else self._rho_z * self._z + self._innovation_z * z
        b = self.shape.burst_array
        return draw[: self.n_joints] * np.exp(b * (self._z - b))

    def start(self, draw: np.ndarray) -> np.ndarray:
        """The first frame's noise from its :meth:`NoiseShape.draws` standard normals."""
        self._noise = self._innovations(draw, first=True)
        self._smooth = self._noise * self.shape.second_gain
        return self._current()

    def next(self, draw: np.ndarray) -> np.ndarray:
        """The next frame's noise from its draws."""
        rho, innovation = self._rho, self._innovation
        fresh = self._innovations(draw, first=False)
        self._noise = rho * self._noise + innovation * fresh
        self._smooth = rho * self._smooth + innovation * self._noise
        return self._current()

    def _current(self) -> np.ndarray:
        return self._noise if self.shape.order == 1 else self._smooth / self._gain
