"""Numpy steps of torch's LSTM and GRU cells, for streaming at a few microseconds per frame.

A torch call costs tens of microseconds of overhead per frame whatever the layer size; the
recurrent models of this package are small enough that one numpy step costs a few microseconds.
The gate layouts are those of ``torch.nn.LSTM`` (input, forget, cell, output) and
``torch.nn.GRU`` (reset, update, new; the reset gate scales the hidden projection including
its bias). Arrays are float64; weights are stored transposed, ``x @ w_ih``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from torch import nn


def sigmoid(x: np.ndarray) -> np.ndarray:
    """Logistic function."""
    return 1.0 / (1.0 + np.exp(-x))


@dataclass(frozen=True)
class CellWeights:
    """One recurrent layer: input and hidden projections (transposed) with their biases."""

    w_ih: np.ndarray  # (n_in, gates * hidden)
    w_hh: np.ndarray  # (hidden, gates * hidden)
    b_ih: np.ndarray  # (gates * hidden,)
    b_hh: np.ndarray  # (gates * hidden,)

    @classmethod
    def of(cls, layer: nn.LSTM | nn.GRU, index: int = 0) -> CellWeights:
        """Copy layer ``index`` (forward direction) of a torch LSTM or GRU."""

        def arr(name: str) -> np.ndarray:
            return getattr(layer, f"{name}_l{index}").detach().cpu().double().numpy().copy()

        return cls(
            arr("weight_ih").T.copy(), arr("weight_hh").T.copy(), arr("bias_ih"), arr("bias_hh")
        )


def lstm_step(
    w: CellWeights, x: np.ndarray, h: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """One LSTM step (seed 002 eqs. 1-6): returns the new (h, c); works on (n,) or (N, n)."""
    gates = x @ w.w_ih + h @ w.w_hh + w.b_ih + w.b_hh
    i, f, g, o = np.split(gates, 4, axis=-1)
    c_new = sigmoid(f) * c + sigmoid(i) * np.tanh(g)
    return sigmoid(o) * np.tanh(c_new), c_new


def gru_step(w: CellWeights, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """One GRU step; returns the new h; works on (n,) or (N, n).

    The gates r, z and the candidate n in torch's order, r and z by one sigmoid, slices not
    copies (for one frame numpy's calls, not the arithmetic, are the cost).
    """
    gx = x @ w.w_ih
    gx += w.b_ih
    gh = h @ w.w_hh
    gh += w.b_hh
    size = h.shape[-1]
    rz = sigmoid(gx[..., : 2 * size] + gh[..., : 2 * size])
    n = gh[..., 2 * size :] * rz[..., :size]
    n += gx[..., 2 * size :]
    z = rz[..., size:]
    new = (1.0 - z) * np.tanh(n, out=n)
    new += z * h
    return new


def linear_weights(layer: nn.Linear) -> tuple[np.ndarray, np.ndarray]:
    """(weight transposed, bias) of a torch Linear layer as float64 arrays."""
    return (
        layer.weight.detach().cpu().double().numpy().T.copy(),
        layer.bias.detach().cpu().double().numpy().copy(),
    )
