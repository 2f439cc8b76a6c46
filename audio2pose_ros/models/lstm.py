"""Causal LSTM of seed 003 (Ondras 2018), section 4.3.4, in a streaming form.

One hidden layer of N_u' = 12 LSTM units (the seed's optimum, Figure 4.13) and an output layer
of 11 sigmoid units targeting angles normalised to [0, 1]; mean squared error, Adam, early
stopping. The seed trained on 300-frame windows (N_tau = 3 s) and re-ran such a window for every
frame online (41 ms per prediction); here the recurrent state (h, c) is carried from frame to
frame instead, so one frame costs one cell step. Streams: yes (causal, constant cost per frame).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from audio2pose_ros.models.base import PoseModel, StreamingPredictor
from audio2pose_ros.models.recurrent_numpy import CellWeights, linear_weights, lstm_step, sigmoid


@dataclass(frozen=True)
class LSTMConfig:
    """Architecture of :class:`CausalLSTM` (defaults: seed 003 section 4.3.4)."""

    n_features: int = 26
    n_joints: int = 11
    hidden_units: int = 12  # N_u'


class CausalLSTM(PoseModel):
    """Seed 003 section 4.3.4 LSTM; forward maps (B, T, F) -> (B, T, J) in [0, 1]."""

    name: ClassVar[str] = "lstm"
    streaming: ClassVar[bool] = True

    def __init__(self, config: LSTMConfig) -> None:
        """Build the LSTM layer and the sigmoid output layer."""
        super().__init__()
        self.config = config
        self.lstm = nn.LSTM(config.n_features, config.hidden_units, batch_first=True)
        self.out = nn.Linear(config.hidden_units, config.n_joints)

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """(B, T, F) normalised features -> (B, T, J) poses in [0, 1], from a zero state."""
        hidden, _ = self.lstm(features)  # (B, T, H)
        return torch.sigmoid(self.out(hidden))

    def streaming_predictor(self, seed: int = 0) -> StreamingPredictor:
        """A numpy copy of the weights carrying (h, c) between frames (``seed`` unused)."""
        return _NumpyLSTM(CellWeights.of(self.lstm), *linear_weights(self.out))


class _NumpyLSTM(StreamingPredictor):
    """One LSTM cell step and the output layer per frame."""

    def __init__(self, cell: CellWeights, w_out: np.ndarray, b_out: np.ndarray) -> None:
        self._cell, self._w_out, self._b_out = cell, w_out, b_out
        self._h = self._c = np.zeros(0)
        self.reset()

    def step(self, features: np.ndarray) -> np.ndarray:
        self._h, self._c = lstm_step(
            self._cell, np.asarray(features, dtype=np.float64), self._h, self._c
        )
        return sigmoid(self._h @ self._w_out + self._b_out)

    def reset(self) -> None:
        """Zero state, as at the start of ``forward``."""
        hidden = self._cell.w_hh.shape[0]
        self._h, self._c = np.zeros(hidden), np.zeros(hidden)
