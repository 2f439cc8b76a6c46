"""Conditional variational autoencoder of seed 002 (Greenwood et al. 2017), section 3.3.

Encoder Q(z | x, c): a BLSTM over the motion x and the audio features c, whose final states give
the mean and log-variance of a small Gaussian latent z (3-d, as the seed). Decoder P(x | z, c):
a BLSTM over the audio features with z repeated at every frame, then sigmoid poses in [0, 1].
Loss: reconstruction MSE plus the Kullback-Leibler divergence KL(Q || N(0, I)) (section 4),
weighted by ``kl_weight`` per frame (KL / T; the seed gives no weight: 1e-3 let the latent carry
the motion that the audio does not explain in our tests, 1e-2 mostly ignored it); RMSprop with
the seed 002 schedule. Sampling draws
z ~ N(0, temperature^2 I), one z per utterance, so one utterance gives several plausible motions
(section 5.3); ``forward`` decodes the prior mean z = 0.
Streams: no (bidirectional; use ``audio2pose synth``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from audio2pose_ros.models.base import SEED002_RECIPE, PoseModel, masked_mse


@dataclass(frozen=True)
class CVAEConfig:
    """Architecture of :class:`SpeechCVAE`."""

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 32  # per direction, encoder and decoder
    latent_dim: int = 3  # seed 002 section 5.3
    kl_weight: float = 0.001  # weight of KL per frame against the per-element MSE (see above)


class SpeechCVAE(PoseModel):
    """Seed 002 section 3.3 CVAE; forward maps (B, T, F) -> (B, T, J) in [0, 1] with z = 0."""

    name: ClassVar[str] = "cvae"
    streaming: ClassVar[bool] = False
    stochastic: ClassVar[bool] = True
    recipe = SEED002_RECIPE

    def __init__(self, config: CVAEConfig) -> None:
        """Build encoder and decoder BLSTMs."""
        super().__init__()
        self.config = config
        units = config.hidden_units
        self.encoder = nn.LSTM(
            config.n_features + config.n_joints, units, batch_first=True, bidirectional=True
        )
        self.to_latent = nn.Linear(2 * units, 2 * config.latent_dim)
        self.decoder = nn.LSTM(
            config.n_features + config.latent_dim, units, batch_first=True, bidirectional=True
        )
        self.out = nn.Linear(2 * units, config.n_joints)

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def decode(self, features: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """(B, T, F) features and (B, latent) codes -> (B, T, J) poses."""
        repeated = z[:, None].expand(-1, features.shape[1], -1)
        hidden, _ = self.decoder(torch.cat([features, repeated], dim=-1))  # (B, T, 2H)
        return torch.sigmoid(self.out(hidden))

    def encode(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Posterior mean and log-variance, each (B, latent); unknown joints read as 0.5."""
        motion = torch.where(mask, targets, torch.full_like(targets, 0.5))
        _, (h_n, _) = self.encoder(torch.cat([features, motion], dim=-1))
        stats = self.to_latent(torch.cat([h_n[0], h_n[1]], dim=-1))
        mean, log_var = stats.chunk(2, dim=-1)
        return mean, log_var

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Decode the prior mean z = 0."""
        z = features.new_zeros(features.shape[0], self.config.latent_dim)
        return self.decode(features, z)

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Reconstruction MSE + kl_weight * KL / T (reparameterised sample of z)."""
        mean, log_var = self.encode(features, targets, mask)
        z = mean + torch.exp(0.5 * log_var) * torch.randn_like(mean)
        reconstruction = masked_mse(self.decode(features, z), targets, mask)
        kl = -0.5 * (1.0 + log_var - mean**2 - log_var.exp()).sum(dim=-1).mean()
        return reconstruction + self.config.kl_weight * kl / features.shape[1]

    def sample(
        self,
        features: torch.Tensor,
        n_samples: int,
        generator: torch.Generator | None = None,
        temperature: float = 1.0,
        quiet_frames: int = 0,
    ) -> torch.Tensor:
        """(B, T, F) -> (S, B, T, J): one z ~ N(0, temperature^2 I) per sample and utterance.

        Raises:
            ValueError: ``quiet_frames`` given: the CVAE does not stream, so it has no warm-up.

        """
        if quiet_frames:
            raise ValueError("the cvae does not stream: it has no warm-up frames to keep quiet")
        batch = features.shape[0]
        z = temperature * torch.randn(
            n_samples * batch, self.config.latent_dim, generator=generator
        )
        repeated = features.repeat(n_samples, 1, 1)  # (S * B, T, F), sample-major
        return self.decode(repeated, z).view(n_samples, batch, *features.shape[1:2], -1)
