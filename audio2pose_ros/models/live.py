"""The live model: a causal, autoregressive GRU sampler that streams (this package's own).

Seeds 000 and 003 report averaged, slow motion as the main weakness of MSE regression, which
collapses the one-to-many speech-to-motion mapping to its mean; seed 002 section 3.3 answers it
with a CVAE that needs the whole utterance. This model keeps the answer and streams: at frame t a
GRU reads the audio features x_t and its own previous pose y_{t-1}, and outputs a Gaussian over
the pose, mean mu_t (sigmoid, in [0, 1]) and standard deviation sigma_t. It samples
y_t = clip(mu_t + temperature * sigma_t * e_t, 0, 1), where e_t is unit-variance noise that is
correlated over time, e_t = rho e_{t-1} + sqrt(1 - rho^2) n_t with n_t ~ N(0, I), so samples
wander smoothly instead of jittering at 100 Hz (with ``noise_order`` 2 the AR(1) filter is
applied twice, a smoother noise whose speed, unlike an AR(1)'s, is itself correlated over
time, rescaled to unit variance; with ``noise_burst`` > 0 the innovations come in bursts, as
real motion does: :mod:`audio2pose_ros.models.sampling_noise`); temperature 0 gives the
deterministic ``forward``. Conditioning on its own output lets a sample commit to one of
several plausible motions and continue it.

Training (teacher forcing): the previous ground-truth pose, corrupted with Gaussian noise of
``input_noise`` so the model does not learn to copy it, is the pose input; the loss is the
Gaussian negative log-likelihood of the true pose (masked), Adam as in seed 003. The first
frame's previous pose is a learned start pose. Each training window starts with half a second
of its first frame held, as an utterance starts online (:mod:`audio2pose_ros.models.warm_start`):
without it, the warm-up's repeated frame was an input the model never saw, and its first
poses drifted, then snapped back when the speech began.
Streams: yes (one GRU cell step per frame; the streaming predictor is numpy and samples with a
settable seed and temperature).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.base import PoseModel, StreamingPredictor
from audio2pose_ros.models.recurrent_numpy import CellWeights, gru_step, linear_weights, sigmoid
from audio2pose_ros.models.sampling_noise import (
    NoiseShape,
    NoiseStream,
    NormalBlocks,
    PerJoint,
    check_burst,
    is_bursty,
)
from audio2pose_ros.models.speech_gate import Factor, nonzero

WARM_UP_TRAINING_FRAMES = 50  # a settled hold before every training window (warm_start)
_MIN_LOG_STD = -7.0  # sigma >= 1e-3 of the joint range: keeps the likelihood finite
_MAX_LOG_STD = 0.0


@dataclass(frozen=True)
class LiveConfig:
    """Architecture of :class:`LiveSampler`."""

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 48
    input_noise: float = 0.05  # std of the noise on teacher-forced poses, [0, 1] units
    noise_correlation: float = 0.95  # rho of the sampling noise (0 = white)
    noise_order: int = 1  # AR(1) filters in cascade on the sampling noise: 1 or 2
    noise_burst: PerJoint = 0.0  # log-std of the noise's burst envelope (0 = steady); or per joint

    def noise_shape(self) -> NoiseShape:
        """The sampling noise this config describes."""
        return NoiseShape(self.noise_correlation, self.noise_order, self.noise_burst)


class LiveSampler(PoseModel):
    """Autoregressive Gaussian GRU; forward maps (B, T, F) -> (B, T, J) at temperature 0."""

    name: ClassVar[str] = "live"
    streaming: ClassVar[bool] = True
    stochastic: ClassVar[bool] = True

    def __init__(self, config: LiveConfig) -> None:
        """Build the GRU, the Gaussian output layer and the start pose."""
        super().__init__()
        if not 0.0 <= config.noise_correlation < 1.0:
            raise ConfigurationError(
                f"noise_correlation must be in [0, 1), got {config.noise_correlation}"
            )
        if config.noise_order not in (1, 2):
            raise ConfigurationError(f"noise_order must be 1 or 2, got {config.noise_order}")
        config = replace(
            config, noise_burst=check_burst(config.noise_burst, config.n_joints, "noise_burst")
        )
        self.config = config
        self.gru = nn.GRU(
            config.n_features + config.n_joints, config.hidden_units, batch_first=True
        )
        self.out = nn.Linear(config.hidden_units, 2 * config.n_joints)
        self.start_pose = nn.Parameter(torch.full((config.n_joints,), 0.5))

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict; ``noise_order`` only if not 1, ``noise_burst`` if not 0.

        Checkpoints of first-order models without bursts keep the keys they always had, which
        the torch-free kernel (:mod:`audio2pose_ros.checkpoints.numpy_runtime`) requires.
        """
        config = asdict(self.config)
        if config["noise_order"] == 1:
            del config["noise_order"]
        if not is_bursty(config["noise_burst"]):
            del config["noise_burst"]
        return config

    def _gaussian(self, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Hidden states -> (mean in [0, 1], log std), each (..., J)."""
        raw_mean, raw_log_std = self.out(hidden).chunk(2, dim=-1)
        return torch.sigmoid(raw_mean), raw_log_std.clamp(_MIN_LOG_STD, _MAX_LOG_STD)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Free-running at temperature 0: each mean is fed back as the next previous pose."""
        previous = self.start_pose.expand(features.shape[0], -1)
        state = None
        poses = []
        for t in range(features.shape[1]):
            step_in = torch.cat([features[:, t], previous], dim=-1)[:, None]  # (B, 1, F + J)
            hidden, state = self.gru(step_in, state)
            previous, _ = self._gaussian(hidden[:, 0])
            poses.append(previous)
        return torch.stack(poses, dim=1)

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Masked Gaussian negative log-likelihood under teacher forcing with noisy inputs.

        Every window is preceded by :data:`WARM_UP_TRAINING_FRAMES` copies of its first frame,
        its first pose as their target: what the model sees when it starts an utterance
        (:mod:`audio2pose_ros.models.warm_start`), so that it learns to hold still there.
        """
        features, targets, mask = (
            torch.cat([x[:, :1].expand(-1, WARM_UP_TRAINING_FRAMES, -1), x], dim=1)
            for x in (features, targets, mask)
        )
        start = self.start_pose.expand(features.shape[0], 1, -1)
        known = torch.where(mask, targets, start.expand_as(targets))
        previous = torch.cat([start, known[:, :-1]], dim=1)
        previous = previous + self.config.input_noise * torch.randn_like(previous)
        hidden, _ = self.gru(torch.cat([features, previous], dim=-1))  # (B, T, H)
        mean, log_std = self._gaussian(hidden)
        nll = 0.5 * ((targets - mean) * torch.exp(-log_std)) ** 2 + log_std
        weight = mask.to(nll.dtype)
        return (nll * weight).sum() / weight.sum().clamp_min(1.0)

    def sample(
        self,
        features: torch.Tensor,
        n_samples: int,
        generator: torch.Generator | None = None,
        temperature: float = 1.0,
        quiet_frames: int = 0,
    ) -> torch.Tensor:
        """(B, T, F) -> (S, B, T, J); noise from ``generator``, recurrence run in numpy.

        The first ``quiet_frames`` frames sample their most likely pose (their noise is drawn
        and filtered, so the rest of the noise is the same).
        """
        batch, n_frames, _ = features.shape
        core = self._core()
        draws = core.noise.draws(self.config.n_joints)
        white = torch.randn(n_samples * batch, n_frames, draws, generator=generator)
        x = np.tile(features.detach().cpu().double().numpy(), (n_samples, 1, 1))
        noise = core.noise.filter(white.double().numpy())
        noise[:, :quiet_frames] = 0.0
        poses = core.run(x, noise, temperature)
        return torch.from_numpy(poses).float().view(n_samples, batch, n_frames, -1)

    def _core(self) -> _LiveCore:
        return _LiveCore(
            CellWeights.of(self.gru),
            *linear_weights(self.out),
            self.start_pose.detach().cpu().double().numpy().copy(),
            self.config.noise_shape(),
        )

    def streaming_predictor(self, seed: int = 0, temperature: float = 1.0) -> LivePredictor:
        """Per-frame sampler; ``temperature`` 0 reproduces ``forward`` frame by frame."""
        return LivePredictor(self._core(), seed, temperature)


class _LiveCore:
    """The live model's recurrence in numpy, for a batch of N sequences."""

    def __init__(
        self,
        cell: CellWeights,
        w_out: np.ndarray,
        b_out: np.ndarray,
        start_pose: np.ndarray,
        noise: NoiseShape,
    ) -> None:
        self.cell, self.w_out, self.b_out, self.start_pose = cell, w_out, b_out, start_pose
        self.noise = noise

    def start(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Initial (hidden, previous pose) for ``n`` sequences."""
        return np.zeros((n, self.cell.w_hh.shape[0])), np.tile(self.start_pose, (n, 1))

    def _output(
        self,
        hidden: np.ndarray,
        noise: np.ndarray,
        temperature: Factor,
        previous: np.ndarray,
        max_step: np.ndarray | None,
    ) -> np.ndarray:
        raw = hidden @ self.w_out + self.b_out
        joints = raw.shape[-1] // 2
        pose = sigmoid(raw[..., :joints])
        if nonzero(temperature):
            std = np.exp(np.minimum(np.maximum(raw[..., joints:], _MIN_LOG_STD), _MAX_LOG_STD))
            pose = np.minimum(np.maximum(pose + temperature * std * noise, 0.0), 1.0)
        if max_step is not None:
            pose = np.minimum(np.maximum(pose, previous - max_step), previous + max_step)
        return pose

    def step(
        self,
        x: np.ndarray,
        state: tuple[np.ndarray, np.ndarray],
        noise: np.ndarray,
        temperature: Factor,
        max_step: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """(N, F) frame, state, (N, J) unit noise -> (N, J) poses and the new state.

        ``temperature`` is a number or one per joint; ``max_step`` (J,), if given, bounds each
        joint's step from the previous pose (a velocity limit in the pose's units per frame).
        """
        hidden, previous = state
        hidden = gru_step(self.cell, np.concatenate([x, previous], axis=-1), hidden)
        pose = self._output(hidden, noise, temperature, previous, max_step)
        return pose, (hidden, pose)

    def run(
        self,
        x: np.ndarray,
        noise: np.ndarray,
        temperature: float,
        noise_scale: Callable[[int, np.ndarray], np.ndarray] | None = None,
        max_step: np.ndarray | None = None,
        free_frames: int = 0,
    ) -> np.ndarray:
        """(N, T, F) utterances and (N, T, J) unit noise -> (N, T, J) poses.

        The same recurrence as :meth:`step`, with the audio half of the input projection
        computed for all frames at once. ``noise_scale(t, previous)``, if given, returns (N,)
        factors for frame t's noise from the (N, J) poses of frame t - 1 (t >= 1).
        ``max_step`` bounds the steps of frames t >= ``free_frames``, as in :meth:`step`.
        """
        n, n_frames, n_features = x.shape
        hidden_units = self.cell.w_hh.shape[0]
        split = 2 * hidden_units  # reset and update gates | new gate
        w_pose = self.cell.w_ih[n_features:]
        audio_gates = x @ self.cell.w_ih[:n_features] + self.cell.b_ih  # (N, T, 3H)
        hidden, previous = self.start(n)
        poses = np.empty((n, n_frames, self.start_pose.shape[0]))
        for t in range(n_frames):
            gx = audio_gates[:, t] + previous @ w_pose
            gh = hidden @ self.cell.w_hh + self.cell.b_hh
            rz = sigmoid(gx[:, :split] + gh[:, :split])
            new = np.tanh(gx[:, split:] + rz[:, :hidden_units] * gh[:, split:])
            hidden = new + rz[:, hidden_units:] * (hidden - new)
            unit = noise[:, t]
            if noise_scale is not None and t:
                unit = unit * noise_scale(t, previous)[:, None]
            limit = max_step if t >= free_frames else None
            previous = poses[:, t] = self._output(hidden, unit, temperature, previous, limit)
        return poses


class LivePredictor(StreamingPredictor):
    """Streaming sampler of :class:`LiveSampler` with a settable seed and temperature."""

    def __init__(self, core: _LiveCore, seed: int = 0, temperature: Factor = 1.0) -> None:
        """Start a new utterance with noise from ``numpy.random.default_rng(seed)``.

        ``temperature`` may be one per joint; ``max_step`` (None: unbounded) may be set to
        bound each joint's step per frame (:meth:`_LiveCore.step`).
        """
        self._core = core
        self.temperature = temperature
        self.max_step: np.ndarray | None = None
        self.seed = seed
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """Forget the state; optionally change the seed of the sampling noise."""
        if seed is not None:
            self.seed = seed
        hidden, previous = self._core.start(1)
        self._state = (hidden[0], previous[0])
        self._stream = NoiseStream(self._core.noise, int(previous.shape[1]))
        draws = self._core.noise.draws(int(previous.shape[1]))
        self._normals = NormalBlocks(np.random.default_rng(self.seed), draws)
        self._noise = self._stream.start(self._normals.next())
        self._first = True

    def step(self, features: np.ndarray) -> np.ndarray:
        """Sample the pose of one (n_features,) frame."""
        if not self._first:
            self._noise = self._stream.next(self._normals.next())
        self._first = False
        pose, self._state = self._core.step(
            np.asarray(features, dtype=np.float64),
            self._state,
            self._noise,
            self.temperature,
            self.max_step,
        )
        return pose
