"""Streaming models start an utterance settled, not from their zero state (numpy only).

A causal recurrent model's first frames come from a state it is never in mid-utterance: a
zero hidden state and, for the autoregressive samplers, a learned start pose that stands for
"no previous pose yet". On the shared clips the default sampler moved HeadPitch by 0.035 rad and
a shoulder by 0.4 rad between its first two frames: a jump that the offline synthesis
(``audio2pose synth``, the evaluation) handed on, and that the evaluation's speed histograms
counted as motion. So every streaming model first runs :data:`WARM_START_FRAMES` frames of the
utterance's first feature frame, whose poses are discarded, and the utterance's first pose
continues from the state they reach. It needs nothing but the first frame, so it is causal, and
the offline path (:func:`with_warm_start` on the whole utterance) and the online path
(:class:`WarmStarted` around a frame predictor) give the same poses for the same seed.
A stateless model (the MLP) gives the same poses with or without it.

Samplers warm up quietly, at temperature 0: they draw their noise (so the noise that follows is
the same) but use none of it, and their speech gate is not stepped. With the noise on, a
sampler trained on the shared clips swung its head to the yaw limit (2 rad) during the warm-up
of a clip whose first frame was speech, and back within its first 0.2 s.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

WARM_START_FRAMES = 100  # 1 s at 100 Hz: the default sampler settles within about 0.2 s


@runtime_checkable
class _Sampler(Protocol):
    """A sampling predictor: its ``temperature`` scales its noise (0: most likely poses)."""

    temperature: float


class _Predictor(Protocol):
    def step(self, features: np.ndarray) -> np.ndarray: ...

    def reset(self) -> None: ...

    def run(self, frames: np.ndarray) -> np.ndarray: ...


def with_warm_start(frames: np.ndarray, n: int = WARM_START_FRAMES) -> np.ndarray:
    """(..., T, F) frames -> (..., n + T, F): the first frame repeated ``n`` times in front.

    The model's output for the first ``n`` frames is the warm-up; drop it (``[..., n:, :]``).

    Raises:
        ValueError: no frames.

    """
    if frames.shape[-2] == 0:
        raise ValueError("an utterance without frames has no first frame to warm up on")
    first = np.repeat(frames[..., :1, :], n, axis=-2)
    return np.concatenate([first, frames], axis=-2)


class WarmStarted:
    """A frame predictor whose first frame after a (re)start is preceded by the warm-up."""

    def __init__(self, predictor: _Predictor, n: int = WARM_START_FRAMES) -> None:
        """Wrap ``predictor`` (``step``, ``reset``, ``run``), which must be freshly started."""
        self.predictor = predictor
        self.n = n
        self._settled = False

    def reset(self) -> None:
        """Forget the state: the next frame warms the model up again."""
        self.predictor.reset()
        self._settled = False

    def run(self, frames: np.ndarray) -> np.ndarray:
        """(N, n_features) frames in order -> (N, n_joints) poses."""
        if self._settled or len(frames) == 0:
            return self.predictor.run(frames)
        self._settled = True
        frames = np.asarray(frames)
        warm_up = with_warm_start(frames[:1], self.n)[: self.n]
        if isinstance(self.predictor, _Sampler):  # quietly: its most likely poses
            temperature = self.predictor.temperature
            self.predictor.temperature = 0.0
            try:
                self.predictor.run(warm_up)
            finally:
                self.predictor.temperature = temperature
        else:
            self.predictor.run(warm_up)
        return self.predictor.run(frames)

    def step(self, features: np.ndarray) -> np.ndarray:
        """One (n_features,) frame -> (n_joints,) pose."""
        if self._settled:
            return self.predictor.step(features)
        return self.run(np.asarray(features)[None])[0]
