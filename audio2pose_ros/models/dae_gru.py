"""Denoising autoencoder of motion plus a speech GRU, seed 000 (Nikolov 2020), sections 4.3-4.5.

Stage 1 (section 4.4): a denoising autoencoder learns a compact code of the per-frame motion
vector [joint angles, velocities] (section 4.3.2 eq. 4.10 uses pose and velocity; velocities
are backward differences, 0 at the first frame, scaled by ``velocity_scale`` so both halves have
similar ranges). Inputs are corrupted with Gaussian noise (eq. 4.14) and reconstructed with
the MSE (eq. 4.15); Adam at 1e-4 (section 5.2).
Stage 2 (sections 4.5, 5.3): the speech network maps a 61-frame audio context centred on each
frame (section 4.3.3, 60 + 1 frames, padded at the utterance edges) through time-distributed
ReLU layers with dropout 0.1 and a GRU to the motion code of that frame; the frozen decoder maps
it back to poses (velocities discarded, section 4.8), and the MSE of those poses trains the
speech network (the SpeechToDecoded network of Figure 4.6); Adam at 1e-3. Regressing the
encoder's codes directly (section 5.3's SpeechToEncoded) weights code directions the decoder
ignores as much as those it uses, and learned far slower in our tests.
Differences from the seed: LogFB-26 at 100 frames/s instead of MFCC-26 averaged to 20 frames/s
(61 frames therefore span 0.61 s, not 3 s), joint angles instead of head rotation vectors,
zero padding (the speaker's mean frame after z-normalisation) instead of features of silence,
smaller layers and no batch normalisation. Stage 2 trains on ``frames_per_window`` random frames
of each training window per step, because every frame needs its own 61-frame GRU pass.
Streams: no. The context looks 30 frames ahead, and a causal variant would re-run the GRU over 61
frames for every frame (61 cell steps per 10 ms); the ``live`` and ``lstm`` models stream.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import torch
from torch import nn
from torch.nn import functional

from audio2pose_ros.errors import ConfigurationError
from audio2pose_ros.models.base import FitStage, PoseModel, masked_mse


@dataclass(frozen=True)
class DAEGRUConfig:
    """Architecture of :class:`DAEGRU` (seed 000 sections 4.4-4.5, scaled down)."""

    n_features: int = 26
    n_joints: int = 11
    code_dim: int = 16  # motion code (seed: 24, the input size)
    dae_hidden: int = 64
    noise_std: float = 0.05  # Gaussian corruption, in [0, 1]-normalised angle units
    velocity_scale: float = 10.0  # velocities per frame times this
    context_frames: int = 61  # 60 + 1 frames centred on the predicted frame
    hidden_units: int = 32  # time-distributed layers and GRU (seed: 256)
    dense_layers: int = 2  # time-distributed ReLU layers before the GRU (seed: 3)
    dropout: float = 0.1  # seed 000 section 5.3
    dae_learning_rate: float = 1e-4  # seed 000 section 5.2
    frames_per_window: int = 16  # frames per training window in stage 2
    output_stride: int = 5  # predict every 5th frame (seed 000: 20 poses/s), interpolate between


class DAEGRU(PoseModel):
    """Seed 000 DAE + SpeechToDecoded GRU; forward maps (B, T, F) -> (B, T, J) in [0, 1]."""

    name: ClassVar[str] = "dae_gru"
    streaming: ClassVar[bool] = False

    def __init__(self, config: DAEGRUConfig) -> None:
        """Build the autoencoder and the speech network."""
        super().__init__()
        if config.context_frames % 2 != 1:
            raise ConfigurationError(f"context_frames must be odd, got {config.context_frames}")
        self.config = config
        motion_dim = 2 * config.n_joints
        self.encoder = nn.Sequential(
            nn.Linear(motion_dim, config.dae_hidden),
            nn.ReLU(),
            nn.Linear(config.dae_hidden, config.code_dim),
        )
        self.decoder = nn.Sequential(
            nn.Linear(config.code_dim, config.dae_hidden),
            nn.ReLU(),
            nn.Linear(config.dae_hidden, motion_dim),
        )
        layers: list[nn.Module] = []
        width = config.n_features
        for _ in range(config.dense_layers):
            layers += [
                nn.Linear(width, config.hidden_units),
                nn.ReLU(),
                nn.Dropout(config.dropout),
            ]
            width = config.hidden_units
        self.speech_dense = nn.Sequential(*layers)
        self.speech_gru = nn.GRU(width, config.hidden_units, batch_first=True)
        self.speech_dropout = nn.Dropout(config.dropout)
        self.speech_out = nn.Linear(config.hidden_units, config.code_dim)

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def motion_vectors(self, poses: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(B, T, J) poses -> (B, T, 2J) [angles, scaled velocities] and its (B, T, 2J) mask."""
        velocity = functional.pad(poses[:, 1:] - poses[:, :-1], (0, 0, 1, 0))
        velocity_mask = functional.pad(mask[:, 1:] & mask[:, :-1], (0, 0, 1, 0), value=False)
        vectors = torch.cat([poses, self.config.velocity_scale * velocity], dim=-1)
        return vectors, torch.cat([mask, velocity_mask], dim=-1)

    def decode_poses(self, code: torch.Tensor) -> torch.Tensor:
        """Motion code (..., code_dim) -> poses (..., J) in [0, 1] (velocities discarded)."""
        return torch.sigmoid(self.decoder(code)[..., : self.config.n_joints])

    def _reconstruct(self, vectors: torch.Tensor) -> torch.Tensor:
        out = self.decoder(self.encoder(vectors))
        joints = self.config.n_joints
        return torch.cat([torch.sigmoid(out[..., :joints]), out[..., joints:]], dim=-1)

    def speech_to_code(
        self, features: torch.Tensor, frames: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(B, T, F) -> (B, n, code_dim) predicted motion codes for ``frames`` (None: all).

        The time-distributed layers run once per padded frame; the GRU then reads the
        61-frame window of their outputs centred on each requested frame.
        """
        half = self.config.context_frames // 2
        dense = self.speech_dense(functional.pad(features, (0, 0, half, half)))  # (B, T+2h, H)
        windows = dense.unfold(1, self.config.context_frames, 1)  # (B, T, H, context)
        if frames is not None:
            windows = windows[:, frames]
        contexts = windows.transpose(2, 3).reshape(-1, self.config.context_frames, dense.shape[2])
        _, h_n = self.speech_gru(contexts)  # h_n: (1, B * n, H)
        code = self.speech_out(self.speech_dropout(h_n[0]))
        return code.view(features.shape[0], -1, self.config.code_dim)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Speech -> motion code -> poses every ``output_stride`` frames, interpolated between.

        Seed 000 predicts 20 poses/s; a 61-frame GRU pass for every frame at 100 frames/s would
        cost five times as much. Decoded poses are interpolated linearly to every frame.
        """
        n_frames = features.shape[1]
        keys = torch.arange(0, n_frames, self.config.output_stride)
        if keys[-1] != n_frames - 1:
            keys = torch.cat([keys, torch.tensor([n_frames - 1])])
        poses = self.decode_poses(self.speech_to_code(features, keys))  # (B, K, J)
        if len(keys) == n_frames:
            return poses
        position = torch.arange(n_frames, dtype=features.dtype)
        right = torch.searchsorted(keys, torch.arange(n_frames), right=False).clamp(
            1, len(keys) - 1
        )
        left = right - 1
        weight = ((position - keys[left]) / (keys[right] - keys[left])).to(poses.dtype)[
            None, :, None
        ]
        return poses[:, left] * (1.0 - weight) + poses[:, right] * weight

    def _dae_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        vectors, vector_mask = self.motion_vectors(targets, mask)
        noisy = vectors + self.config.noise_std * torch.randn_like(vectors)  # eq. 4.14
        return masked_mse(self._reconstruct(noisy), vectors, vector_mask)  # eq. 4.15

    def _dae_validation_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        vectors, vector_mask = self.motion_vectors(targets, mask)
        return masked_mse(self._reconstruct(vectors), vectors, vector_mask)

    def _decoded_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        count = min(self.config.frames_per_window, features.shape[1])
        frames = torch.randperm(features.shape[1])[:count]
        poses = self.decode_poses(self.speech_to_code(features, frames))  # (B, n, J)
        return masked_mse(poses, targets[:, frames], mask[:, frames])

    def fit_stages(self) -> list[FitStage]:
        """Stage 1: the denoising autoencoder; stage 2: the speech network (decoder frozen)."""
        speech = [self.speech_dense, self.speech_gru, self.speech_out]
        return [
            FitStage(
                "denoising_autoencoder",
                self._dae_loss,
                lambda: [*self.encoder.parameters(), *self.decoder.parameters()],
                validation_loss=self._dae_validation_loss,
                learning_rate=self.config.dae_learning_rate,
            ),
            FitStage(
                "speech_to_decoded",
                self._decoded_loss,
                lambda: [p for module in speech for p in module.parameters()],
            ),
        ]
