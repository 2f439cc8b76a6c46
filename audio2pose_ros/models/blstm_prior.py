"""BLSTM conditioned on prior motion, seed 002 (Greenwood et al. 2017), section 3.2.

The utterance is synthesised in chunks of ``chunk_frames``. A motion BLSTM reads the last
``prior_frames`` poses before the chunk; its final states (both directions), repeated over the
chunk, join the audio features as input to a deep BLSTM that predicts k-frame spans
(:mod:`~audio2pose_ros.models.span`). At inference the model's own output is fed back
recursively as the next chunk's prior (seed Figure 2); the first chunk's prior is a learned
start pose held still. Training (our choice; the seed gives no details) uses two consecutive
chunks per window: the second chunk's prior is the ground truth (teacher forcing) or, with
probability ``own_prior_probability`` per window, the model's own detached prediction of the
first chunk (scheduled sampling), so the model learns to continue from its own motion.
Streams: no (bidirectional within each chunk; use ``audio2pose synth``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from audio2pose_ros.models.base import SEED002_RECIPE, PoseModel
from audio2pose_ros.models.span import recombine_spans, span_loss


@dataclass(frozen=True)
class BLSTMPriorConfig:
    """Architecture of :class:`PriorMotionBLSTM`."""

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 32  # per direction, audio + motion BLSTM stack
    layers: int = 2
    motion_units: int = 16  # per direction, prior-motion BLSTM
    span_frames: int = 10  # k
    prior_frames: int = 20  # 200 ms of prior motion
    chunk_frames: int = 100  # poses predicted per recursion step (1 s)
    own_prior_probability: float = 0.5  # scheduled sampling during training


class PriorMotionBLSTM(PoseModel):
    """Seed 002 section 3.2 model; forward maps (B, T, F) -> (B, T, J) in [0, 1]."""

    name: ClassVar[str] = "blstm_prior"
    streaming: ClassVar[bool] = False
    recipe = SEED002_RECIPE

    def __init__(self, config: BLSTMPriorConfig) -> None:
        """Build the motion BLSTM, the audio + motion BLSTM stack and the span layer."""
        super().__init__()
        self.config = config
        self.motion = nn.LSTM(
            config.n_joints, config.motion_units, batch_first=True, bidirectional=True
        )
        self.blstm = nn.LSTM(
            config.n_features + 2 * config.motion_units,
            config.hidden_units,
            num_layers=config.layers,
            batch_first=True,
            bidirectional=True,
        )
        self.out = nn.Linear(2 * config.hidden_units, config.span_frames * config.n_joints)
        self.start_pose = nn.Parameter(torch.full((config.n_joints,), 0.5))

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def _chunk_spans(self, features: torch.Tensor, prior: torch.Tensor) -> torch.Tensor:
        """(B, C, F) chunk and (B, P, J) prior poses -> (B, C, k, J) spans."""
        _, (h_n, _) = self.motion(prior)  # h_n: (2, B, M), final states of both directions
        code = torch.cat([h_n[0], h_n[1]], dim=-1)  # (B, 2M)
        batch, n_frames, _ = features.shape
        inputs = torch.cat([features, code[:, None].expand(-1, n_frames, -1)], dim=-1)
        hidden, _ = self.blstm(inputs)  # (B, C, 2H)
        out = torch.sigmoid(self.out(hidden))
        return out.view(batch, n_frames, self.config.span_frames, self.config.n_joints)

    def _start_prior(self, batch: int) -> torch.Tensor:
        return self.start_pose.expand(batch, self.config.prior_frames, -1)

    @staticmethod
    def _next_prior(prior: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
        """The last P frames of ``prior`` followed by ``poses``."""
        return torch.cat([prior, poses], dim=1)[:, -prior.shape[1] :]

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Recursive synthesis chunk by chunk, each conditioned on the previous output."""
        prior = self._start_prior(features.shape[0])
        chunks = []
        for start in range(0, features.shape[1], self.config.chunk_frames):
            poses = recombine_spans(
                self._chunk_spans(features[:, start : start + self.config.chunk_frames], prior)
            )
            chunks.append(poses)
            prior = self._next_prior(prior, poses)
        return torch.cat(chunks, dim=1)

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Span MSE over consecutive chunks with teacher forcing / scheduled sampling."""
        size = self.config.chunk_frames
        prior = self._start_prior(features.shape[0])
        loss = features.new_zeros(())
        for start in range(0, features.shape[1], size):
            part = slice(start, start + size)
            spans = self._chunk_spans(features[:, part], prior)
            loss = loss + span_loss(spans, targets[:, part], mask[:, part])
            own = recombine_spans(spans).detach()
            truth = torch.where(mask[:, part], targets[:, part], own)
            use_own = torch.rand(features.shape[0], 1, 1) < self.config.own_prior_probability
            prior = self._next_prior(prior, torch.where(use_own, own, truth))
        return loss / -(-features.shape[1] // size)
