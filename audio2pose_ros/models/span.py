"""Span prediction of seed 002 (Greenwood et al. 2017) section 3.1: k frames per time step.

At every time step t the network predicts the span of poses t, t+1, ..., t+k-1 (seed: 1 <= k <=
29). Each frame therefore receives up to k predictions, recombined by their mean (section 3.1:
"we simply take the mean at each predicted time step"). Training compares every span slot with
the pose it predicts.
"""

from __future__ import annotations

import torch


def recombine_spans(spans: torch.Tensor) -> torch.Tensor:
    """Mean of all span predictions of each frame: (B, T, k, J) -> (B, T, J).

    Frame t receives the prediction of slot o from step t - o, for every o < k with t - o >= 0.
    """
    _, n_frames, k, _ = spans.shape
    total = torch.zeros_like(spans[:, :, 0])
    count = torch.zeros(n_frames, 1, dtype=spans.dtype)
    for offset in range(min(k, n_frames)):
        total[:, offset:] += spans[:, : n_frames - offset, offset]
        count[offset:] += 1.0
    return total / count


def span_loss(spans: torch.Tensor, targets: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Masked MSE of every span slot against the pose it predicts (slots beyond the end skipped).

    Args:
        spans: (B, T, k, J) predictions.
        targets: (B, T, J) poses in [0, 1].
        mask: (B, T, J) True where the pose is known.

    Returns:
        Scalar mean squared error over all known (slot, frame, joint) pairs.

    """
    n_frames, k = spans.shape[1], spans.shape[2]
    total = spans.new_zeros(())
    weight_sum = spans.new_zeros(())
    for offset in range(min(k, n_frames)):
        weight = mask[:, offset:].to(spans.dtype)
        error = spans[:, : n_frames - offset, offset] - targets[:, offset:]
        total = total + (error**2 * weight).sum()
        weight_sum = weight_sum + weight.sum()
    return total / weight_sum.clamp_min(1.0)
