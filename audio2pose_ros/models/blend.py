"""A cross-fade from one running model's poses to another's: a model switched live never jumps.

When the inference node is given another checkpoint while it runs (a personal model after
enrolment, or back to the default), both models run on the same frames for
:data:`BLEND_FRAMES` frames and their poses are mixed, the new model's weight rising from 0 to 1
along a smoothstep (:func:`blend_weights`), after which the old model stops. The first mixed pose
is the old model's own, the last the new one's.

A mixed pose's step from the one before is at most the larger of the two models' own steps plus
the change of weight times how far apart the two models' poses are (:func:`blend_step_bound`):
with the joints' ranges as that distance, at most :data:`MAX_WEIGHT_SLOPE` / ``frames`` of a
joint's range per frame on top of what either model does by itself. A mix of two poses inside
the joint limits stays inside them. What comes out is still the model's raw output: the motion
filter's limits and body guard act on it as on any other.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BLEND_FRAMES", "MAX_WEIGHT_SLOPE", "PoseBlend", "blend_step_bound", "blend_weights"]

BLEND_FRAMES = 100  # 1 s of 10 ms frames from the old model's poses to the new one's
MAX_WEIGHT_SLOPE = 1.5  # the smoothstep's steepest slope (at its middle), per unit of its span


def blend_weights(first: int, count: int, frames: int = BLEND_FRAMES) -> np.ndarray:
    """The new model's weights of blend frames ``first`` .. ``first + count - 1``, in [0, 1].

    Frame 0 has weight 0 (the old model's pose), frame ``frames`` and after weight 1; between,
    the smoothstep ``3 t^2 - 2 t^3`` of ``t = k / frames``: it starts and ends without a kink.
    """
    if frames < 1:
        raise ValueError(f"a blend takes at least one frame, not {frames}")
    t = np.clip(np.arange(first, first + count, dtype=np.float64) / frames, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def blend_step_bound(
    old_step: np.ndarray, new_step: np.ndarray, gap: np.ndarray, frames: int = BLEND_FRAMES
) -> np.ndarray:
    """The largest step a mixed pose can take, per joint.

    Between frames ``k - 1`` and ``k`` the mix ``(1 - w) a + w b`` moves by
    ``(1 - w_k) da + w_k db + (w_k - w_{k-1}) (b - a)_{k-1}``: at most the larger of the two
    models' own steps ``old_step``, ``new_step`` plus the weight's largest change
    (:data:`MAX_WEIGHT_SLOPE` / ``frames``) times ``gap``, the largest distance between their
    poses (the joint's range, at most).
    """
    return np.maximum(old_step, new_step) + MAX_WEIGHT_SLOPE / frames * gap


class PoseBlend:
    """The mix of two models' poses over :data:`BLEND_FRAMES` frames, a message at a time.

    Args:
        frames: how many frames the blend takes.
    """

    def __init__(self, frames: int = BLEND_FRAMES) -> None:
        blend_weights(0, 0, frames)  # refuses a blend of no frames
        self.frames = frames
        self.done = 0  # frames mixed so far

    @property
    def finished(self) -> bool:
        """Whether the new model's weight has reached 1 (the old model can stop)."""
        return self.done >= self.frames

    def mix(self, old: np.ndarray, new: np.ndarray) -> np.ndarray:
        """The next ``len(old)`` mixed poses of the two models' (frames, joints) poses."""
        if old.shape != new.shape:
            raise ValueError(f"poses of shapes {old.shape} and {new.shape} cannot be mixed")
        weights = blend_weights(self.done, len(old), self.frames)[:, None]
        self.done += len(old)
        return old + weights * (new - old)
