"""The interface of every pose model: a torch module, its training recipe and optional streaming.

The torch module serves training and offline synthesis; the constant-cost streaming predictor
serves the online graph.

Models map z-normalised audio features (B, T, n_features) to joint angles normalised to [0, 1]
by the joint ranges (seed 003 eq. 3.14), shape (B, T, n_joints). A model trains in one or more
:class:`FitStage` s (e.g. the denoising autoencoder of seed 000 before its speech network), each
with its own loss; the default is one stage minimising the masked MSE of ``forward``, the loss L
of seed 003 eq. 3.15. The optimiser and learning-rate schedule come from the model's
:class:`TrainingRecipe` (seed 003: Adam with early stopping; seed 002 section 4: RMSprop with
learning-rate decay on plateaus).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from audio2pose_ros.errors import ConfigurationError

LossFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


class OfflineOnlyModelError(ConfigurationError):
    """A model that needs the whole utterance was asked to run online."""


@dataclass(frozen=True)
class TrainingRecipe:
    """Optimiser and schedule of a model family.

    Attributes:
        optimizer: ``"adam"`` (seed 003 section 4.3.3) or ``"rmsprop"`` (seed 002 section 4).
        learning_rate: initial learning rate.
        patience: epochs without validation improvement before the learning rate decays or
            training stops.
        lr_decay: on a plateau, reload the best weights and multiply the learning rate by this
            factor; 0 stops at the first plateau instead.
        min_learning_rate: stop once decaying would go below this rate.

    """

    optimizer: str = "adam"
    learning_rate: float = 1e-3
    patience: int = 10
    lr_decay: float = 0.0
    min_learning_rate: float = 1e-5


SEED003_RECIPE = TrainingRecipe("adam", 1e-3, 10)  # seed 003 sections 4.3.3-4.3.4
SEED002_RECIPE = TrainingRecipe("rmsprop", 1e-3, 5, 0.1, 1e-5)  # seed 002 section 4


def masked_mse(prediction: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over known targets only: the loss L of seed 003 eq. 3.15."""
    weight = mask.to(prediction.dtype)
    return ((prediction - target) ** 2 * weight).sum() / weight.sum().clamp_min(1.0)


@dataclass(frozen=True)
class FitStage:
    """One training stage: a loss over (features, targets, mask) and the parameters it updates.

    Attributes:
        name: shown in progress bars and stored in training states.
        loss: training loss of a batch of windows, (B, T, F), (B, T, J), (B, T, J) -> scalar.
        parameters: the parameters this stage optimises.
        validation_loss: loss for early stopping on whole validation utterances (model in eval
            mode, no gradients); None = masked MSE of ``forward`` (seed 003 eq. 3.15).
        learning_rate: overrides the recipe's initial learning rate for this stage.

    """

    name: str
    loss: LossFn
    parameters: Callable[[], Iterable[nn.Parameter]]
    validation_loss: LossFn | None = None
    learning_rate: float | None = None


class StreamingPredictor(ABC):
    """One frame in, one pose out, with whatever state the model carries between frames."""

    @abstractmethod
    def step(self, features: np.ndarray) -> np.ndarray:
        """Map one (n_features,) normalised feature frame to an (n_joints,) pose in [0, 1]."""

    @abstractmethod
    def reset(self) -> None:
        """Forget the state carried between frames (start of a new utterance)."""


class PoseModel(nn.Module, ABC):
    """Base class of the model families; subclasses set ``name``, ``streaming``, ``recipe``.

    Attributes:
        name: registry key used by checkpoints and the command line.
        streaming: True when the model is causal with constant cost per frame and can run in
            ``inference_node``; False when it needs the whole utterance (``audio2pose synth``).
        stochastic: True when :meth:`sample` draws different motions for the same audio.
        recipe: optimiser and learning-rate schedule.

    """

    name: ClassVar[str]
    streaming: ClassVar[bool]
    stochastic: ClassVar[bool] = False
    recipe: ClassVar[TrainingRecipe] = SEED003_RECIPE

    @abstractmethod
    def config_dict(self) -> dict[str, Any]:
        """Constructor arguments, stored in checkpoints to rebuild the model."""

    @abstractmethod
    def forward(self, features: torch.Tensor) -> torch.Tensor:
        """Map (B, T, n_features) features to (B, T, n_joints) poses in [0, 1].

        Samplers return their most likely (zero-noise) motion here.
        """

    def training_loss(
        self, features: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor
    ) -> torch.Tensor:
        """Loss of one batch of windows; default: masked MSE of ``forward`` (eq. 3.15)."""
        return masked_mse(self(features), targets, mask)

    def fit_stages(self) -> list[FitStage]:
        """Training stages in order; default: one stage of :meth:`training_loss` on all weights."""
        return [FitStage("regression", self.training_loss, self.parameters)]

    def sample(
        self,
        features: torch.Tensor,
        n_samples: int,
        generator: torch.Generator | None = None,
        temperature: float = 1.0,
        quiet_frames: int = 0,
    ) -> torch.Tensor:
        """Draw ``n_samples`` motions per utterance: (B, T, F) -> (S, B, T, J) in [0, 1].

        ``quiet_frames``: the first frames of a streaming sampler's warm-up
        (:mod:`audio2pose_ros.models.warm_start`) draw their noise but sample at temperature 0,
        as the streaming predictor does during its warm-up.

        Raises:
            NotImplementedError: the model is deterministic (``stochastic`` False).

        """
        raise NotImplementedError(f"model {self.name!r} is deterministic and cannot sample")

    def streaming_predictor(self, seed: int = 0) -> StreamingPredictor:
        """Return a constant-cost per-frame predictor; offline-only models raise.

        Args:
            seed: seed of a sampler's noise (same seed, same motion); deterministic models
                ignore it, so callers may always pass it.

        """
        raise OfflineOnlyModelError(
            f"model {self.name!r} needs the whole utterance and cannot stream; "
            "use `audio2pose synth` for offline synthesis"
        )


def require_streaming(model: PoseModel, path: str) -> None:
    """Refuse an offline-only model for online use, pointing to ``audio2pose synth``.

    Args:
        model: the loaded model.
        path: where it was loaded from (named in the message).

    Raises:
        OfflineOnlyModelError: ``model.streaming`` is False.

    """
    if not model.streaming:
        raise OfflineOnlyModelError(
            f"{path}: model {model.name!r} needs the whole utterance and cannot run online; "
            f"use `audio2pose synth FILE.wav --model {path}` instead"
        )
