"""Frame-wise multilayer perceptron of seed 003 (Ondras 2018), section 4.3.3.

Each 10 ms audio feature frame maps independently to the 11 joint angles: N_l hidden layers of
N_u ReLU units with He initialisation, and a sigmoid output layer targeting angles normalised to
[0, 1] (section 3.4.2). Table 4.5's optimum for LogFB-26 is N_l = 7, N_u = 8 (747 parameters),
the default here. Streams: yes (no state, constant cost per frame).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from audio2pose_ros.models.base import PoseModel, StreamingPredictor


@dataclass(frozen=True)
class MLPConfig:
    """Architecture of :class:`FramewiseMLP` (defaults: seed 003 Table 4.5, LogFB-26 row)."""

    n_features: int = 26
    n_joints: int = 11
    hidden_layers: int = 7  # N_l
    hidden_units: int = 8  # N_u
    dropout: float = 0.0  # seed 003 appendix A: dropout flattened the motion, so 0 by default


class FramewiseMLP(PoseModel):
    """Seed 003 section 4.3.3 MLP; forward maps (B, T, F) -> (B, T, J) in [0, 1]."""

    name: ClassVar[str] = "mlp"
    streaming: ClassVar[bool] = True

    def __init__(self, config: MLPConfig) -> None:
        """Build the layers and apply He (Kaiming) initialisation to the ReLU layers."""
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        width = config.n_features
        for _ in range(config.hidden_layers):
            linear = nn.Linear(width, config.hidden_units)
            nn.init.kaiming_normal_(linear.weight, nonlinearity="relu")
            nn.init.zeros_(linear.bias)
            layers += [linear, nn.ReLU()]
            if config.dropout > 0:
                layers.append(nn.Dropout(config.dropout))
            width = config.hidden_units
        layers.append(nn.Linear(width, config.n_joints))
        self.net = nn.Sequential(*layers)

    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments as a dict."""
        return asdict(self.config)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """(B, T, F) or (N, F) normalised features -> same leading shape x n_joints, in [0, 1]."""
        return torch.sigmoid(self.net(features))

    def streaming_predictor(self, seed: int = 0) -> StreamingPredictor:
        """A numpy copy of the weights: one frame costs a few tiny matrix products (no seed)."""
        return _NumpyMLP(
            [
                (
                    m.weight.detach().cpu().double().numpy().T.copy(),
                    m.bias.detach().cpu().double().numpy().copy(),
                )
                for m in self.net
                if isinstance(m, nn.Linear)
            ]
        )


class _NumpyMLP(StreamingPredictor):
    """The MLP's inference path in numpy (torch's per-call overhead is ~40 us per frame)."""

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]]) -> None:
        self._layers = layers

    def step(self, features: np.ndarray) -> np.ndarray:
        x = np.asarray(features, dtype=np.float64)
        for weight, bias in self._layers[:-1]:
            x = np.maximum(x @ weight + bias, 0.0)
        weight, bias = self._layers[-1]
        return 1.0 / (1.0 + np.exp(-(x @ weight + bias)))

    def reset(self) -> None:
        """Stateless: nothing to forget."""
