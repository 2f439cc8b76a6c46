"""The interface of every pose model: a torch module and an optional streaming predictor.

The torch module serves training and offline synthesis; the constant-cost streaming predictor
serves the online graph.

Models map z-normalised audio features (B, T, n_features) to joint angles normalised to [0, 1]
by the joint ranges (seed 003 eq. 3.14), shape (B, T, n_joints).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn


class StreamingPredictor(ABC):
    """One frame in, one pose out, with whatever state the model carries between frames."""

    @abstractmethod
    def step(self, features: np.ndarray) -> np.ndarray:
        """Map one (n_features,) normalised feature frame to an (n_joints,) pose in [0, 1]."""

    @abstractmethod
    def reset(self) -> None:
        """Forget the state carried between frames (start of a new utterance)."""


class PoseModel(nn.Module, ABC):
    """Base class of the model families; subclasses set ``name`` and ``streaming``.

    Attributes:
        name: registry key used by checkpoints and the command line.
        streaming: True when the model is causal with constant cost per frame and can run in
            ``inference_node``; False when it needs the whole utterance (``audio2pose synth``).

    """

    name: ClassVar[str]
    streaming: ClassVar[bool]

    @abstractmethod
    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments, stored in checkpoints to rebuild the model."""

    @abstractmethod
    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Map (B, T, n_features) features to (B, T, n_joints) poses in [0, 1]."""

    def streaming_predictor(self) -> StreamingPredictor:
        """Return a constant-cost per-frame predictor; offline-only models raise."""
        raise NotImplementedError(
            f"model {self.name!r} needs the whole utterance and cannot stream; "
            "use `audio2pose synth` for offline synthesis"
        )
