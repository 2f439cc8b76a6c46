"""Deep bidirectional LSTM of seed 002 (Greenwood et al. 2017), section 3.1.

A stack of BLSTM layers reads the whole utterance; at each time step a sigmoid layer predicts
the span of the next k poses (:mod:`~audio2pose_ros.models.span`), recombined by their mean.
Trained with MSE, RMSprop at 1e-3, patience 5 and learning-rate decay by 10 down to 1e-5
(section 4). The seed used 40 log filter banks at 59.94 frames/s and k <= 29; here the features
are the package's (LogFB-26 at 100 frames/s) and k = 10 frames (100 ms) by default.
Streams: no (the backward direction needs the whole utterance; use ``audio2pose synth``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import torch
from torch import nn

from audio2pose_ros.models.base import SEED002_RECIPE, PoseModel
from audio2pose_ros.models.span import recombine_spans, span_loss


@dataclass(frozen=True)
class BLSTMConfig:
    """Architecture of :class:`SpanBLSTM`."""

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 32  # per direction
    layers: int = 2  # "deep" BLSTM
    span_frames: int = 10  # k


class SpanBLSTM(PoseModel):
    """Seed 002 section 3.1 BLSTM; forward maps (B, T, F) -> (B, T, J) in [0, 1]."""

    name: ClassVar[str] = "blstm"
    streaming: ClassVar[bool] = False
    recipe = SEED002_RECIPE

    def __init__(self, config: BLSTMConfig) -> None:
        """Build the BLSTM stack and the span output layer."""
        super().__init__()
        self.config = config
        self.blstm = nn.LSTM(
            config.n_features,
            config.hidden_units,
            num_layers=config.layers,
            batch_first=True,
            bidirectional=True,
        )
        self.out = nn.Linear(2 * config.hidden_units, config.span_frames * config.n_joints)

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def spans(self, features: torch.Tensor) -> torch.Tensor:
        """(B, T, F) -> (B, T, k, J) span predictions in [0, 1]."""
        hidden, _ = self.blstm(features)  # (B, T, 2H)
        batch, n_frames, _ = hidden.shape
        out = torch.sigmoid(self.out(hidden))
        return out.view(batch, n_frames, self.config.span_frames, self.config.n_joints)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Mean-recombined spans: (B, T, F) -> (B, T, J)."""
        return recombine_spans(self.spans(features))

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """MSE of every span slot (section 4: MSE objective)."""
        return span_loss(self.spans(features), targets, mask)
