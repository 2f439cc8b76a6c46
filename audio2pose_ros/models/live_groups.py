"""Two live samplers side by side: one for the head, one for the arms and hip (ours).

The head is labelled by talking-head clips whose arms are out of frame, the arms by a lecture
whose speaker's face is too small to track: no clip labels both. A single autoregressive model
fed back its own untrained outputs for the joints a clip does not label would see, at run time,
inputs it never saw in training. This model splits the joints into two groups, each with its own
:class:`~audio2pose_ros.models.live.LiveSampler` (causal GRU, Gaussian output, time-correlated
sampling noise) that reads the audio and only its own group's previous pose. Each part's loss
is the masked Gaussian negative log-likelihood of its joints, so a clip trains only the part
whose joints it labels; both parts train together, on the union of the data sets.

People keep still when they stop talking; a sampler whose noise never stops does not. The
sampling noise of both parts is therefore scaled by a causal speech gate read from the same
normalised audio features (:mod:`audio2pose_ros.models.speech_gate`): the frame's mean log
filter-bank energy e_t is compared with a slowly decaying peak of recent energy,
v_t = sigmoid((e_t - peak_t + gate_margin) / gate_width), smoothed over 0.3 s; the temperature
is multiplied by
silence_temperature + (1 - silence_temperature) v_t, and by each part's own temperature (a
free-running sampler's motion is not as large as real motion at temperature 1: its one-step
uncertainty does not add up to the real spread; a part's temperature may be one per joint). With
``velocity_limit`` > 0 and the robot bound, no sampled step moves a joint faster than that
share of its velocity limit (the sample is clamped to the previous pose plus or minus the
step, :func:`~audio2pose_ros.models.speech_gate.part_step_limits`), and the clamped pose is
what the part reads back: the sampler never asks the robot for a jump the motion filter would
drop. Each part's noise also has its own
burstiness (``first_burst``, ``second_burst``: :mod:`audio2pose_ros.models.sampling_noise`) and
its own noise correlation (``first_correlation``, ``second_correlation``; unset, a part takes
``noise_correlation``): a head nods faster than an arm swings. These
:data:`SAMPLING_SETTINGS` act only when sampling;
:mod:`audio2pose_ros.learning.sampler_selection` chooses them on validation clips after training,
without retraining (:meth:`LiveGroups.with_sampling`). A relative gate (against the
recent peak) does not depend on the recording level.
Streams: yes (two GRU cell steps per frame); the streaming predictor samples with a settable
seed (the head part's noise from ``seed``, the body part's from ``seed + 1``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from typing import Any, ClassVar, cast

import numpy as np
import torch

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.base import PoseModel, StreamingPredictor
from audio2pose_ros.models.body_noise import BodyNoise, body_noise_for, check_body_noise
from audio2pose_ros.models.live import LiveConfig, LivePredictor, LiveSampler
from audio2pose_ros.models.sampling_noise import PerJoint, check_burst, check_per_joint
from audio2pose_ros.models.speech_gate import (
    PART_BURST_KEYS,
    PART_CORRELATION_KEYS,
    PART_TEMPERATURE_KEYS,
    Factor,
    GroupedSampler,
    SpeechGate,
    check_velocity_limit,
    part_correlations,
    part_factor,
    part_step_limits,
)
from audio2pose_ros.robot.description import RobotDescription

SAMPLING_SETTINGS = (
    *PART_TEMPERATURE_KEYS,
    *PART_BURST_KEYS,
    "noise_correlation",
    *PART_CORRELATION_KEYS,
    "silence_temperature",
    "body_margin_m",
    "body_band_m",
    "velocity_limit",
)


@dataclass(frozen=True)
class LiveGroupsConfig:
    """Architecture of :class:`LiveGroups`.

    Attributes:
        first_group: bit j set = joint j belongs to the first part (default 3: joints 0 and 1,
            HeadPitch and HeadYaw in Pepper's order); the other joints form the second part.
        first_correlation: the first part's noise correlation; None = ``noise_correlation``.
        second_correlation: the second part's; None = ``noise_correlation``.
        first_temperature, second_temperature: each part's temperature factor, one for all
            its joints or one per joint (the hip sways less than the arms swing).
        body_margin_m, body_band_m: body-aware sampling of the part that moves the arms
            (:mod:`audio2pose_ros.models.body_noise`; needs the robot, bound by the checkpoint
            that holds the model); a band of 0 turns it off.
        velocity_limit: when sampling, no joint's step from one frame to the next exceeds
            this share of the robot's velocity limit for that joint
            (:func:`~audio2pose_ros.models.speech_gate.part_step_limits`; needs the robot);
            0 turns it off.

    """

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 32
    input_noise: float = 0.05
    noise_correlation: float = 0.975  # of a part without its own correlation
    noise_order: int = 2
    first_group: int = 3
    first_temperature: PerJoint = 2.5  # head, or one per joint; `make default-model` chooses it
    second_temperature: PerJoint = 1.0  # arms and hip, or one per joint; likewise
    first_burst: PerJoint = 0.0  # burstiness of the head part's noise (sampling_noise), or one
    second_burst: PerJoint = 0.0  # per joint of the part; of the arm part's; likewise
    silence_temperature: float = 0.05  # noise left in silence (1 = no speech gate); likewise
    gate_margin: float = 1.0  # z-units of the features' mean below the recent peak
    gate_width: float = 0.2
    first_correlation: float | None = None  # head; `make default-model` chooses it
    second_correlation: float | None = None  # arms and hip; likewise
    body_margin_m: float = 0.02  # body-aware sampling (body_noise): the arm noise is 0 here
    body_band_m: float = 0.0  # ... and whole this far beyond the margin (0 = off)
    velocity_limit: float = 0.0  # sampled steps within this share of the joints' speed limit


class LiveGroups(PoseModel):
    """Two :class:`LiveSampler` s over disjoint joint groups; (B, T, F) -> (B, T, J)."""

    name: ClassVar[str] = "live_groups"
    streaming: ClassVar[bool] = True
    stochastic: ClassVar[bool] = True

    def __init__(self, config: LiveGroupsConfig) -> None:
        """Build both parts."""
        super().__init__()
        first = np.array([(config.first_group >> j) & 1 == 1 for j in range(config.n_joints)])
        if config.first_group >= 1 << config.n_joints or first.all() or not first.any():
            raise ConfigurationError(
                f"first_group={config.first_group} must select some but not all of "
                f"{config.n_joints} joints"
            )
        check_body_noise(config.body_margin_m, config.body_band_m)
        self.groups = (np.flatnonzero(first), np.flatnonzero(~first))
        per_part = {  # each part's burstiness and temperature: one, or one per joint of the part
            key: check(getattr(config, key), len(joints), key)
            for keys, check in (
                (PART_BURST_KEYS, check_burst),
                (PART_TEMPERATURE_KEYS, check_per_joint),
            )
            for key, joints in zip(keys, self.groups, strict=True)
        }
        config = replace(
            config,
            **cast(dict[str, Any], per_part),  # the names are the config's own fields
            velocity_limit=check_velocity_limit(config.velocity_limit),
        )
        self.config = config
        self._robot: RobotDescription | None = None
        self._body_noise: BodyNoise | None = None
        self._body_part = -1
        self.parts = torch.nn.ModuleList(
            LiveSampler(
                LiveConfig(
                    config.n_features,
                    len(joints),
                    config.hidden_units,
                    config.input_noise,
                    correlation,
                    config.noise_order,
                    burst,
                )
            )
            for joints, burst, correlation in zip(
                self.groups,
                (config.first_burst, config.second_burst),
                self.part_correlations(),
                strict=True,
            )
        )

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict; a part's correlation only if it has its own.

        Checkpoints whose parts share ``noise_correlation``, without body-aware sampling and
        without a velocity limit, keep the keys they always had.
        """
        config = {k: v for k, v in asdict(self.config).items() if v is not None}
        if not self.config.body_band_m:
            del config["body_margin_m"], config["body_band_m"]
        if not self.config.velocity_limit:
            del config["velocity_limit"]
        return config

    def bind_robot(self, robot: RobotDescription) -> None:
        """The robot whose body the arm part's sampling keeps off (body-aware sampling)."""
        if robot != self._robot:
            self._robot, self._body_noise, self._body_part = robot, None, -1

    def body_noise(self) -> tuple[BodyNoise | None, int]:
        """The body-aware noise factors and the index of the part they scale (None, -1: off).

        Off when the band is 0, no robot is bound, or no part moves an arm joint.
        """
        if self._body_noise is None:
            self._body_noise, self._body_part = body_noise_for(
                self._robot, self.groups, self.config.body_margin_m, self.config.body_band_m
            )
        return self._body_noise, self._body_part

    def part_correlations(self) -> tuple[float, float]:
        """Each part's noise correlation."""
        return part_correlations(asdict(self.config))

    def samplers(self) -> list[LiveSampler]:
        """The two parts, typed (``parts`` is a ``ModuleList`` of :class:`LiveSampler`)."""
        return [cast(LiveSampler, part) for part in self.parts]

    def _scatter(self, outputs: list[torch.Tensor]) -> torch.Tensor:
        shape = (*outputs[0].shape[:-1], self.config.n_joints)
        poses = outputs[0].new_zeros(shape)
        for joints, out in zip(self.groups, outputs, strict=True):
            poses[..., torch.from_numpy(joints)] = out
        return poses

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Both parts' most likely motion (temperature 0), joints in the robot's order."""
        return self._scatter([part(features) for part in self.parts])

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Sum of the parts' masked Gaussian negative log-likelihoods."""
        total = features.new_zeros(())
        for joints, part in zip(self.groups, self.samplers(), strict=True):
            index = torch.from_numpy(joints)
            if mask[..., index].any():
                total = total + part.training_loss(features, targets[..., index], mask[..., index])
        return total

    def with_sampling(self, **settings: float | tuple[float, ...]) -> LiveGroups:
        """A copy with the same weights and other :data:`SAMPLING_SETTINGS` (no retraining).

        The temperatures and the gate's rest level act only when sampling, so they can be chosen
        after training (:mod:`audio2pose_ros.learning.sampler_selection`).

        Raises:
            ConfigurationError: a setting that is not a sampling setting.

        """
        unknown = sorted(set(settings) - set(SAMPLING_SETTINGS))
        if unknown:
            raise ConfigurationError(f"{unknown} are not sampling settings {SAMPLING_SETTINGS}")
        # dataclasses.replace is typed per field; the names were checked just above
        model = LiveGroups(replace(self.config, **cast(dict[str, Any], settings)))
        model.load_state_dict(self.state_dict())
        if self._robot is not None:
            model.bind_robot(self._robot)
        return model.train(self.training)

    def part_temperatures(self) -> tuple[Factor, Factor]:
        """Each part's own temperature factor: a number, or an array of one per joint."""
        return (
            part_factor(self.config.first_temperature),
            part_factor(self.config.second_temperature),
        )

    def step_limits(self) -> tuple[np.ndarray, ...] | None:
        """Per part, each joint's largest sampled step (normalised units); None: unbounded."""
        return part_step_limits(self._robot, self.groups, self.config.velocity_limit)

    def sample(
        self,
        features: torch.Tensor,
        n_samples: int,
        generator: torch.Generator | None = None,
        temperature: float = 1.0,
        quiet_frames: int = 0,
    ) -> torch.Tensor:
        """(B, T, F) -> (S, B, T, J), the same motion as the streaming predictor.

        Sequence i (sample-major: i = s * B + b) of part k draws its noise, frame by frame,
        from ``numpy.random.default_rng(seed + 2 i + k)``, where ``seed`` is the generator's
        initial seed (0 without one): sample 0 of a single utterance equals what
        ``streaming_predictor(seed)`` produces frame by frame, so ``audio2pose synth`` and the
        inference node move alike for the same seed (to rounding; with body-aware sampling,
        coal's 1e-6 m distance tolerance, carried on by the feedback, lets them drift apart by
        up to about 1e-3 of a joint's range). The first ``quiet_frames`` frames (a
        warm-up) sample the most likely pose and leave the speech gate untouched, as the
        streaming predictor does at temperature 0; the frames after them keep each joint's step
        within :meth:`step_limits`.
        """
        seed = generator.initial_seed() if generator is not None else 0
        batch, n_frames, _ = features.shape
        x = np.tile(features.detach().cpu().double().numpy(), (n_samples, 1, 1))
        gate = SpeechGate(
            self.config.silence_temperature, self.config.gate_margin, self.config.gate_width
        )
        scale = np.zeros((*x.shape[:2], 1))  # (S * B, T, 1)
        for row, factors in zip(x, scale, strict=True):
            factors[quiet_frames:, 0] = gate.run(row[quiet_frames:])
        body, body_part = self.body_noise() if temperature else (None, -1)
        limits = self.step_limits() if temperature else None
        outputs: list[np.ndarray] = [np.empty(0), np.empty(0)]
        for k in sorted(range(2), key=lambda k: k == body_part):  # the body part last
            part, factor = self.samplers()[k], self.part_temperatures()[k]
            core = part._core()
            draws = core.noise.draws(part.config.n_joints)
            white = np.stack(
                [
                    np.random.default_rng(seed + 2 * i + k).standard_normal((n_frames, draws))
                    for i in range(n_samples * batch)
                ]
            )
            noise = core.noise.filter(white) * scale * factor
            noise_scale = None
            if body is not None and k == body_part:
                noise_scale = self._body_factors(body, k, outputs[1 - k], quiet_frames)
            outputs[k] = core.run(
                x,
                noise,
                temperature,
                noise_scale,
                None if limits is None else limits[k],
                quiet_frames,
            )
        return self._scatter(
            [torch.from_numpy(p).float().view(n_samples, batch, n_frames, -1) for p in outputs]
        )

    def _body_factors(
        self, body: BodyNoise, k: int, other: np.ndarray, quiet_frames: int
    ) -> Callable[[int, np.ndarray], np.ndarray]:
        """Part k's noise factors at frame t from both parts' poses at t - 1 (body_noise)."""
        body.reset()
        full = np.empty((len(other), self.config.n_joints))

        def factors(t: int, previous: np.ndarray) -> np.ndarray:
            if t < quiet_frames:  # the warm-up samples its mean: no noise to scale
                return np.ones(len(previous))
            full[:, self.groups[k]] = previous
            full[:, self.groups[1 - k]] = other[:, t - 1]
            return body.factors(full)

        return factors

    def streaming_predictor(self, seed: int = 0, temperature: float = 1.0) -> LiveGroupsPredictor:
        """Per-frame sampler: same seed, same motion; ``temperature`` 0 = ``forward``."""
        return LiveGroupsPredictor(self, seed, temperature)


class LiveGroupsPredictor(GroupedSampler, StreamingPredictor):
    """Streaming sampler of :class:`LiveGroups` with a settable seed and temperature."""

    def __init__(self, model: LiveGroups, seed: int = 0, temperature: float = 1.0) -> None:
        """One :class:`LivePredictor` per part (seeds ``seed`` and ``seed + 1``)."""
        self._groups = model.groups
        self._n_joints = model.config.n_joints
        self._factors = model.part_temperatures()
        config = model.config
        self._gate = SpeechGate(config.silence_temperature, config.gate_margin, config.gate_width)
        self._parts = [
            LivePredictor(part._core(), seed + k, temperature)
            for k, part in enumerate(model.samplers())
        ]
        self._body_noise, self._body_part = body_noise_for(  # its own: one per thread
            model._robot, model.groups, config.body_margin_m, config.body_band_m
        )
        self._max_steps = model.step_limits()
        self.seed = seed
        self.temperature = temperature
        self.reset()
