"""Streaming inference without torch: numpy kernels run a checkpoint's tensors.

The online graph runs tiny networks (the packaged MLP has 747 parameters) one 10 ms frame at a
time; torch costs about 250 MB of resident memory and seconds of import for that. This module
loads a checkpoint with safetensors' numpy API and runs the streaming models that have a numpy
kernel here, frame by frame, with float64 arithmetic:

=============== ==================================================================================
model           kernel
=============== ==================================================================================
``mlp``         seed 003 section 4.3.3: ReLU layers, sigmoid output; a message's frames at once
``lstm``        seed 003 section 4.3.4 made causal: one LSTM cell step per frame, (h, c) carried
``live``        a GRU step on audio and the last pose, Gaussian output, smooth (bursty) noise
``live_groups`` two ``live`` kernels (head; arms and hip) and the causal speech gate
=============== ==================================================================================

Gate layouts are torch's (LSTM: input, forget, cell, output; GRU: reset, update, new, the reset
gate scaling the hidden projection including its bias), so the kernels give the same poses as
the models' own streaming predictors (``test/test_runtime_numpy.py`` checks them against torch
on real speech).

:func:`load_streaming_model` applies the checks of
:func:`~audio2pose_ros.checkpoints.torch_io.load_checkpoint` without torch: the container, header,
F32-only tensor entries and their offsets
(:func:`~audio2pose_ros.checkpoints.format.read_checkpoint_file`), the digest, the header
sections, that the tensors are exactly the model's names and shapes (before any tensor is
read), and that every value is finite float32. A checkpoint whose model has no kernel here, or
whose config the kernel does not know exactly (a missing or extra key, a value outside the
kernel's range), is handed to the torch loader, which validates it fully and runs it; only
then is torch imported.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from safetensors.numpy import load_file

from audio2pose_ros.audio.features import FeatureSpec
from audio2pose_ros.audio.normalize import FeatureNormalizer
from audio2pose_ros.checkpoints.format import (
    CheckpointError,
    CheckpointFile,
    check_made_for,
    check_tensor_layout,
    header_sections,
    load_checked_tensors,
    read_checkpoint_file,
    verify_digest,
)
from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.body_noise import body_noise_for, check_body_noise
from audio2pose_ros.models.sampling_noise import (
    NoiseShape,
    NoiseStream,
    NormalBlocks,
    check_burst,
    check_per_joint,
)
from audio2pose_ros.models.speech_gate import (
    PART_BURST_KEYS,
    PART_CORRELATION_KEYS,
    PART_TEMPERATURE_KEYS,
    Factor,
    GroupedSampler,
    SpeechGate,
    check_velocity_limit,
    nonzero,
    part_bursts,
    part_correlations,
    part_factor,
    part_step_limits,
)
from audio2pose_ros.models.warm_start import WarmStarted
from audio2pose_ros.robot.description import RobotDescription

__all__ = [
    "KERNELS",
    "FramePredictor",
    "StreamingModel",
    "load_streaming_model",
    "numpy_kernel_for",
]

MAX_KERNEL_UNITS = 1024  # widths beyond this go to the torch loader (which refuses them)
_MIN_LOG_STD = np.full((), -7.0)  # the live model's clamp of its log standard deviation
_MAX_LOG_STD = np.zeros(())
# 0-d arrays: numpy's ufuncs take them quicker than Python floats (the same float64 values)
_ZERO, _ONE = np.zeros(()), np.ones(())


class FramePredictor(Protocol):
    """Normalised feature frames in, poses in [0, 1] out, with the state carried between them."""

    def step(self, features: np.ndarray) -> np.ndarray:
        """(n_features,) frame -> (n_joints,) pose."""

    def reset(self) -> None:
        """Forget the state carried between frames."""

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames in order -> (N, n_joints) poses."""


class _Stepwise:
    """A torch-side model's streaming predictor (step and reset) with :meth:`run` added."""

    def __init__(self, predictor: Any) -> None:
        self.predictor = predictor

    def step(self, features: np.ndarray) -> np.ndarray:
        return self.predictor.step(features)

    def reset(self) -> None:
        self.predictor.reset()

    def run(self, frames: np.ndarray) -> np.ndarray:
        return np.array([self.predictor.step(frame) for frame in frames])


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function."""
    return 1.0 / (1.0 + np.exp(-x))


def _weights(tensors: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """A torch ``(out, in)`` weight as a float64 ``(in, out)`` array, for ``x @ w``."""
    return np.ascontiguousarray(tensors[name].astype(np.float64).T)


def _vector(tensors: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    return tensors[name].astype(np.float64)


# --- kernels ----------------------------------------------------------------------------------


class MLPKernel:
    """Seed 003 section 4.3.3 MLP: ReLU hidden layers and a sigmoid output; no state."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]]) -> None:
        """``layers``: (weight as (in, out), bias) per Linear layer, the output layer last."""
        self._layers = layers

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames -> (N, n_joints) poses, all frames in one product per layer."""
        x = np.asarray(frames, dtype=np.float64)
        for weight, bias in self._layers[:-1]:
            x = np.maximum(x @ weight + bias, 0.0)
        weight, bias = self._layers[-1]
        return sigmoid(x @ weight + bias)

    def step(self, features: np.ndarray) -> np.ndarray:
        """One frame."""
        return self.run(features)

    def reset(self) -> None:
        """Stateless: nothing to forget."""


class LSTMKernel:
    """Seed 003 section 4.3.4 LSTM, causal: one cell step per frame with (h, c) carried."""

    _h: np.ndarray
    _c: np.ndarray

    def __init__(
        self,
        w_ih: np.ndarray,
        w_hh: np.ndarray,
        bias: np.ndarray,
        w_out: np.ndarray,
        b_out: np.ndarray,
    ) -> None:
        """Weights as (in, 4H) and (H, 4H), the summed input and hidden biases, output layer."""
        self._w_ih, self._w_hh, self._bias = w_ih, w_hh, bias
        self._w_out, self._b_out = w_out, b_out
        self.reset()

    def step(self, features: np.ndarray) -> np.ndarray:
        """One frame: the cell step (seed 002 eqs. 1-6), then the sigmoid output layer."""
        gates = np.asarray(features, dtype=np.float64) @ self._w_ih + self._h @ self._w_hh
        i, f, g, o = np.split(gates + self._bias, 4)
        self._c = sigmoid(f) * self._c + sigmoid(i) * np.tanh(g)
        self._h = sigmoid(o) * np.tanh(self._c)
        return sigmoid(self._h @ self._w_out + self._b_out)

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames in order -> (N, n_joints) poses."""
        return np.array([self.step(frame) for frame in frames])

    def reset(self) -> None:
        """Zero state, as at the start of an utterance."""
        hidden = self._w_hh.shape[0]
        self._h, self._c = np.zeros(hidden), np.zeros(hidden)


class LiveKernel:
    """The live sampler: GRU on (audio, last pose), Gaussian output, time-correlated noise.

    At frame t the noise comes from :class:`~audio2pose_ros.models.sampling_noise.NoiseStream`
    (AR(1), or two stages, optionally bursty) with draws from
    ``numpy.random.default_rng(seed)``; pose = clip(mu + temperature * sigma * noise, 0, 1),
    mu = sigmoid of the first half of the output layer, sigma = exp of the second half clamped
    to [-7, 0] (``temperature`` a number or one per joint); with ``max_step`` set, each
    joint's step from the previous pose is bounded by it; the pose is the next frame's previous
    pose.
    """

    def __init__(
        self,
        tensors: Mapping[str, np.ndarray],
        noise: NoiseShape,
        seed: int = 0,
        temperature: float = 1.0,
        prefix: str = "",
    ) -> None:
        """Take the GRU, output layer and start pose (names after ``prefix``); start."""
        self._w_ih = _weights(tensors, f"{prefix}gru.weight_ih_l0")
        self._w_hh = _weights(tensors, f"{prefix}gru.weight_hh_l0")
        self._b_ih = _vector(tensors, f"{prefix}gru.bias_ih_l0")
        self._b_hh = _vector(tensors, f"{prefix}gru.bias_hh_l0")
        self._w_out = _weights(tensors, f"{prefix}out.weight")
        self._b_out = _vector(tensors, f"{prefix}out.bias")
        self._start_pose = _vector(tensors, f"{prefix}start_pose")
        self._shape = noise
        self._draws = noise.draws(int(self._start_pose.shape[0]))
        self.seed = seed
        self.temperature: Factor = temperature
        self.max_step: np.ndarray | None = None
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Forget the state; optionally change the seed of the sampling noise."""
        if seed is not None:
            self.seed = seed
        hidden, features = self._w_hh.shape[0], self._w_ih.shape[0] - len(self._start_pose)
        # this frame's input (features, then the previous pose) and hidden state
        self._input = np.concatenate([np.zeros(features), self._start_pose])
        self._hidden = np.zeros(hidden)
        self._rz = np.empty(2 * hidden)
        self._normals = NormalBlocks(np.random.default_rng(self.seed), self._draws)
        self._stream = NoiseStream(self._shape, int(self._start_pose.shape[0]))
        self._noise = self._stream.start(self._normals.next())
        self._first = True

    def step(self, features: np.ndarray) -> np.ndarray:
        """Sample the pose of one frame (a new array; the kernel keeps a copy of it)."""
        if not self._first:
            self._noise = self._stream.next(self._normals.next())
        self._first = False
        x, hidden, rz = self._input, self._hidden, self._rz
        previous = x[len(x) - len(self._start_pose) :]
        x[: len(x) - len(previous)] = features
        # the gates r, z and the candidate n of torch's GRU, in its order (slices, not copies)
        gates_x = x @ self._w_ih
        gates_x += self._b_ih
        gates_h = hidden @ self._w_hh
        gates_h += self._b_hh
        size = len(hidden)
        np.add(gates_x[: 2 * size], gates_h[: 2 * size], out=rz)
        _sigmoid_in_place(rz)
        new = gates_h[2 * size :]
        new *= rz[:size]
        new += gates_x[2 * size :]
        np.tanh(new, out=new)
        z = rz[size:]
        hidden *= z  # h = (1 - z) n + z h
        np.subtract(_ONE, z, out=rz[:size])
        new *= rz[:size]
        hidden += new
        raw = hidden @ self._w_out
        raw += self._b_out
        joints = len(raw) // 2
        pose = _sigmoid_in_place(raw[:joints])
        temperature = self.temperature
        if nonzero(temperature):
            log_std = raw[joints:]
            np.maximum(log_std, _MIN_LOG_STD, out=log_std)
            np.minimum(log_std, _MAX_LOG_STD, out=log_std)
            spread = temperature * np.exp(log_std, out=log_std)
            spread *= self._noise
            pose += spread
            np.maximum(pose, _ZERO, out=pose)
            np.minimum(pose, _ONE, out=pose)
        if self.max_step is not None:
            np.maximum(pose, previous - self.max_step, out=pose)
            np.minimum(pose, previous + self.max_step, out=pose)
        previous[:] = pose
        return pose

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames in order -> (N, n_joints) sampled poses."""
        return np.array([self.step(frame) for frame in frames])


def _sigmoid_in_place(x: np.ndarray) -> np.ndarray:
    """:func:`sigmoid` of ``x`` into ``x`` (the same operations, no new array)."""
    np.negative(x, out=x)
    np.exp(x, out=x)
    x += _ONE
    return np.divide(_ONE, x, out=x)


class LiveGroupsKernel(GroupedSampler):
    """Two live kernels over disjoint joint groups, their noise scaled by the speech gate.

    Per frame: factor = the gate's temperature factor (0 at temperature 0); part k samples at
    temperature * its own temperature * factor with seed ``seed + k``, with its own noise
    correlation where the config gives one (``first_correlation``, ``second_correlation``) and
    ``noise_correlation`` otherwise; the parts' poses are scattered into the robot's joint order.
    """

    def __init__(
        self,
        tensors: Mapping[str, np.ndarray],
        config: Mapping[str, Any],
        seed: int = 0,
        temperature: float = 1.0,
        robot: RobotDescription | None = None,
    ) -> None:
        """Build both parts and the gate from the tensors and the config.

        With ``robot`` (the checkpoint's) and a ``body_band_m`` > 0, the arm part samples
        with the body in mind (:mod:`audio2pose_ros.models.body_noise`), as the torch model.
        """
        self._groups = _live_groups(config)
        self._n_joints = config["n_joints"]
        self._factors = tuple(part_factor(config[key]) for key in PART_TEMPERATURE_KEYS)
        self._gate = SpeechGate(
            config["silence_temperature"], config["gate_margin"], config["gate_width"]
        )
        order = config["noise_order"]
        bursts = part_bursts(config)
        rhos = part_correlations(config)
        self._parts = [
            LiveKernel(
                tensors,
                NoiseShape(rhos[k], order, check_burst(bursts[k], len(self._groups[k]))),
                seed + k,
                temperature,
                prefix=f"parts.{k}.",
            )
            for k in range(len(self._groups))
        ]
        self._body_noise, self._body_part = body_noise_for(
            robot,
            self._groups,
            float(config.get("body_margin_m", 0.0)),
            float(config.get("body_band_m", 0.0)),
        )
        self._max_steps = part_step_limits(
            robot, self._groups, float(config.get("velocity_limit", 0.0))
        )
        self.seed = seed
        self.temperature = temperature
        self.reset()


# --- what each kernel accepts -----------------------------------------------------------------


@dataclass(frozen=True)
class KernelSpec:
    """A model family this module runs: its exact config keys, tensor shapes and builder.

    Attributes:
        config_keys: the config keys the kernel reads, all required but ``optional_keys``
            (left out, their default applies), no others.
        accepts: whether a config's values lie in the kernel's range.
        shapes: the tensor names and shapes of a config (torch's ``state_dict`` layout).
        build: the predictor, from the tensors, the config, and keyword options (``seed``,
            ``temperature`` for samplers; ``robot``, the checkpoint's, where ``takes_robot``).
        takes_robot: the kernel samples with the robot's body in mind (body-aware sampling).
    """

    config_keys: frozenset[str]
    accepts: Callable[[Mapping[str, Any]], bool]
    shapes: Callable[[Mapping[str, Any]], dict[str, tuple[int, ...]]]
    build: Callable[..., FramePredictor]
    optional_keys: frozenset[str] = frozenset()
    takes_robot: bool = False


def _is_int(value: object, low: int = 1) -> bool:
    return (
        isinstance(value, int)
        and not isinstance(value, bool)
        and low <= value <= (MAX_KERNEL_UNITS)
    )


def _is_fraction(value: object) -> bool:
    """A number in [0, 1) (rho, dropout, noise)."""
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and 0.0 <= value < 1.0
    )


def _sizes_ok(config: Mapping[str, Any]) -> bool:
    return all(_is_int(config[k]) for k in ("n_features", "n_joints", "hidden_units"))


def _mlp_linear_indices(config: Mapping[str, Any]) -> list[int]:
    """Indices of the Linear layers in FramewiseMLP's ``net`` (a Dropout follows each ReLU)."""
    per_layer = 3 if config["dropout"] > 0 else 2
    return [i * per_layer for i in range(config["hidden_layers"] + 1)]


def _mlp_shapes(config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
    shapes: dict[str, tuple[int, ...]] = {}
    width = config["n_features"]
    indices = _mlp_linear_indices(config)
    for n, index in enumerate(indices):
        out = config["n_joints"] if n == len(indices) - 1 else config["hidden_units"]
        shapes[f"net.{index}.weight"] = (out, width)
        shapes[f"net.{index}.bias"] = (out,)
        width = out
    return shapes


def _build_mlp(
    tensors: Mapping[str, np.ndarray], config: Mapping[str, Any], seed: int = 0
) -> MLPKernel:
    """A deterministic model: ``seed`` is accepted (every streaming model takes one) and unused."""
    return MLPKernel(
        [
            (_weights(tensors, f"net.{i}.weight"), _vector(tensors, f"net.{i}.bias"))
            for i in _mlp_linear_indices(config)
        ]
    )


def _lstm_shapes(config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
    features, joints, hidden = config["n_features"], config["n_joints"], config["hidden_units"]
    return {
        "lstm.weight_ih_l0": (4 * hidden, features),
        "lstm.weight_hh_l0": (4 * hidden, hidden),
        "lstm.bias_ih_l0": (4 * hidden,),
        "lstm.bias_hh_l0": (4 * hidden,),
        "out.weight": (joints, hidden),
        "out.bias": (joints,),
    }


def _build_lstm(
    tensors: Mapping[str, np.ndarray], _config: Mapping[str, Any], seed: int = 0
) -> LSTMKernel:
    """A deterministic model: ``seed`` is accepted (every streaming model takes one) and unused."""
    return LSTMKernel(
        _weights(tensors, "lstm.weight_ih_l0"),
        _weights(tensors, "lstm.weight_hh_l0"),
        _vector(tensors, "lstm.bias_ih_l0") + _vector(tensors, "lstm.bias_hh_l0"),
        _weights(tensors, "out.weight"),
        _vector(tensors, "out.bias"),
    )


def _live_shapes(config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
    features, joints, hidden = config["n_features"], config["n_joints"], config["hidden_units"]
    return {
        "start_pose": (joints,),
        "gru.weight_ih_l0": (3 * hidden, features + joints),
        "gru.weight_hh_l0": (3 * hidden, hidden),
        "gru.bias_ih_l0": (3 * hidden,),
        "gru.bias_hh_l0": (3 * hidden,),
        "out.weight": (2 * joints, hidden),
        "out.bias": (2 * joints,),
    }


def _build_live(
    tensors: Mapping[str, np.ndarray],
    config: Mapping[str, Any],
    seed: int = 0,
    temperature: float = 1.0,
) -> LiveKernel:
    noise = NoiseShape(
        float(config["noise_correlation"]),
        config.get("noise_order", 1),
        check_burst(config.get("noise_burst", 0.0), config["n_joints"]),
    )
    return LiveKernel(tensors, noise, seed, temperature)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_burst(value: object, n_joints: int) -> bool:
    return _accepted(partial(check_burst, value, n_joints))


def _live_accepts(config: Mapping[str, Any]) -> bool:
    order = config.get("noise_order", 1)
    return (
        _sizes_ok(config)
        and _is_fraction(config["noise_correlation"])
        and _is_number(config["input_noise"])
        and not isinstance(order, bool)
        and order in (1, 2)
        and _is_burst(config.get("noise_burst", 0.0), config["n_joints"])
    )


def _live_groups(config: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Joint indices of the two parts (bit j of ``first_group`` = joint j in the first)."""
    first = np.array([(config["first_group"] >> j) & 1 == 1 for j in range(config["n_joints"])])
    return np.flatnonzero(first), np.flatnonzero(~first)


def _live_groups_accepts(config: Mapping[str, Any]) -> bool:
    numbers = ("silence_temperature", "gate_margin", "gate_width")
    if not (
        _live_accepts(config)
        and _is_int(config["first_group"])
        and config["first_group"] < 1 << config["n_joints"]
        and all(_is_number(config[k]) for k in numbers)
        and all(_is_fraction(config.get(k, 0.0)) for k in _GROUP_CORRELATIONS)
        and _body_noise_ok(config)
        and _accepted(partial(check_velocity_limit, config.get("velocity_limit", 0.0)))
    ):
        return False
    groups = _live_groups(config)
    return all(len(joints) for joints in groups) and all(
        _is_burst(burst, len(joints))
        and _accepted(partial(check_per_joint, config[key], len(joints), key))
        for burst, key, joints in zip(
            part_bursts(config), PART_TEMPERATURE_KEYS, groups, strict=True
        )
    )


def _accepted(check: Callable[[], object]) -> bool:
    """Whether ``check()`` returns without a :class:`ConfigurationError`."""
    try:
        check()
    except ConfigurationError:
        return False
    return True


def _body_noise_ok(config: Mapping[str, Any]) -> bool:
    margin, band = config.get("body_margin_m", 0.0), config.get("body_band_m", 0.0)
    return _accepted(partial(check_body_noise, margin, band))


def _live_groups_shapes(config: Mapping[str, Any]) -> dict[str, tuple[int, ...]]:
    shapes = {}
    for k, joints in enumerate(_live_groups(config)):
        part = _live_shapes({**config, "n_joints": len(joints)})
        shapes.update({f"parts.{k}.{name}": shape for name, shape in part.items()})
    return shapes


_GROUP_BURSTS = frozenset(PART_BURST_KEYS)  # optional: older checkpoints lack them
_GROUP_CORRELATIONS = frozenset(PART_CORRELATION_KEYS)  # optional: likewise
_GROUP_BODY = frozenset({"body_margin_m", "body_band_m"})  # optional: likewise
_GROUP_LIMIT = frozenset({"velocity_limit"})  # optional: likewise
_LIVE_KEYS = frozenset(
    {"n_features", "n_joints", "hidden_units", "input_noise", "noise_correlation"}
)
KERNELS: dict[str, KernelSpec] = {
    "mlp": KernelSpec(
        frozenset({"n_features", "n_joints", "hidden_layers", "hidden_units", "dropout"}),
        lambda c: _sizes_ok(c) and _is_int(c["hidden_layers"], 0) and _is_fraction(c["dropout"]),
        _mlp_shapes,
        _build_mlp,
    ),
    "lstm": KernelSpec(
        frozenset({"n_features", "n_joints", "hidden_units"}), _sizes_ok, _lstm_shapes, _build_lstm
    ),
    "live": KernelSpec(
        _LIVE_KEYS | {"noise_order", "noise_burst"},
        _live_accepts,
        _live_shapes,
        _build_live,
        frozenset({"noise_order", "noise_burst"}),
    ),
    "live_groups": KernelSpec(
        _LIVE_KEYS
        | {
            "noise_order",
            "first_group",
            "first_temperature",
            "second_temperature",
            "silence_temperature",
            "gate_margin",
            "gate_width",
        }
        | _GROUP_BURSTS
        | _GROUP_CORRELATIONS
        | _GROUP_BODY
        | _GROUP_LIMIT,
        _live_groups_accepts,
        _live_groups_shapes,
        LiveGroupsKernel,
        _GROUP_BURSTS | _GROUP_CORRELATIONS | _GROUP_BODY | _GROUP_LIMIT,
        takes_robot=True,
    ),
}


def numpy_kernel_for(name: str, config: object) -> KernelSpec | None:
    """The kernel that runs model ``name`` with ``config``, or None (the torch loader's case)."""
    spec = KERNELS.get(name)
    if (
        spec is None
        or not isinstance(config, dict)
        or not spec.config_keys - spec.optional_keys <= set(config) <= spec.config_keys
    ):
        return None
    return spec if spec.accepts(config) else None


# --- loading ----------------------------------------------------------------------------------


@dataclass
class StreamingModel:
    """A verified streaming checkpoint, ready to run online.

    Attributes:
        name: the model family.
        features: the feature specification it expects.
        normalizer: feature z-normalisation statistics.
        robot: the joints and ranges it was trained for.
        runtime: ``"numpy"`` (a kernel of this module) or ``"torch"`` (the model's own
            streaming predictor; torch was imported).
        info: the header's free-form training information.
    """

    name: str
    features: FeatureSpec
    normalizer: FeatureNormalizer
    robot: RobotDescription
    runtime: str
    make_predictor: Callable[..., FramePredictor]
    info: dict[str, Any] = field(default_factory=dict)

    def predictor(self, **options: Any) -> FramePredictor:
        """A new frame-by-frame predictor (``seed``, ``temperature`` for samplers).

        It starts settled (:mod:`audio2pose_ros.models.warm_start`), as the offline synthesis
        does, so both give the same poses for the same seed.
        """
        return WarmStarted(self.make_predictor(**options))


def _read_tensors(
    file: CheckpointFile, model: str, shapes: dict[str, tuple[int, ...]]
) -> dict[str, np.ndarray]:
    """The file's tensors, after checking they are exactly ``shapes``; finite float32 each."""
    check_tensor_layout(file, model, shapes)
    return load_checked_tensors(
        file, load_file, lambda t: t.dtype == np.float32 and bool(np.isfinite(t).all())
    )


def _torch_model(
    path: Path, robot: RobotDescription | None, features: FeatureSpec | None
) -> StreamingModel:
    """Load with torch (a model without a numpy kernel here): the full torch-side checks."""
    from audio2pose_ros.checkpoints.torch_io import load_checkpoint
    from audio2pose_ros.models.base import require_streaming

    checkpoint = load_checkpoint(path, robot=robot, features=features)
    require_streaming(checkpoint.model, str(path))
    return StreamingModel(
        name=checkpoint.model.name,
        features=checkpoint.features,
        normalizer=checkpoint.normalizer,
        robot=checkpoint.robot,
        runtime="torch",
        make_predictor=lambda **options: _Stepwise(checkpoint.model.streaming_predictor(**options)),
        info=checkpoint.info,
    )


def load_streaming_model(
    path: str | Path,
    robot: RobotDescription | None = None,
    features: FeatureSpec | None = None,
    allow_torch: bool = True,
) -> StreamingModel:
    """Load and verify a streaming checkpoint, with numpy kernels where this module has one.

    Args:
        path: the ``.safetensors`` checkpoint.
        robot: when given, the checkpoint's joints and ranges must equal it.
        features: when given, the checkpoint's feature specification must equal it.
        allow_torch: hand checkpoints without a kernel to the torch loader; when False they
            are refused instead.

    Raises:
        CheckpointError: the file is unreadable, modified after saving, crafted, or made for
            other joints or features; or (``allow_torch`` False) it has no numpy kernel.
        OfflineOnlyModelError: through the torch loader, a model that cannot stream.
    """
    file = read_checkpoint_file(path)
    verify_digest(file)
    name, config = file.header["model"]["name"], file.header["model"]["config"]
    spec = numpy_kernel_for(name, config)
    if spec is None:
        if not allow_torch:
            raise CheckpointError(
                f"{file.path}: model {name!r} with this config has no numpy kernel "
                f"(kernels: {sorted(KERNELS)})"
            )
        return _torch_model(file.path, robot, features)
    stored_robot, stored_features, normalizer = header_sections(file)
    check_made_for(file, stored_robot, stored_features, robot, features)
    if config["n_joints"] != stored_robot.n_joints or config["n_features"] != stored_features.dim:
        raise CheckpointError(
            f"{file.path}: model maps {config['n_features']} features to "
            f"{config['n_joints']} joints, but the header describes "
            f"{stored_features.dim} features and {stored_robot.n_joints} joints"
        )
    tensors = _read_tensors(file, name, spec.shapes(config))

    def make_predictor(**options: Any) -> FramePredictor:
        if spec.takes_robot:
            options["robot"] = stored_robot
        return spec.build(tensors, config, **options)

    return StreamingModel(
        name=name,
        features=stored_features,
        normalizer=normalizer,
        robot=stored_robot,
        runtime="numpy",
        make_predictor=make_predictor,
        info=file.header.get("info", {}),
    )
