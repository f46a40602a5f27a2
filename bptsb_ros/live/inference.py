"""Trained brains evaluated one command at a time, without torch's per-call overhead (the live brain nodes).

A torch module call on one input costs tens of microseconds of dispatch around a few hundred flops. These classes
hold the trained weights as numpy arrays in the agent's dtype and compute the same expressions:

* :class:`ForceMap` — the NARMA brain (:class:`~bptsb_ros.brains.fnn.LinearInputLayer` or
  :class:`~bptsb_ros.brains.fnn.MLPBrain`) and :func:`bptsb_ros.agent.brain_forces`: task input → forces (M, 2) on
  the movable masses, none on the CMP;
* :class:`SwgTable` — :func:`bptsb_ros.sim.rollout.swg_rest_lengths` itself, evaluated for blocks of
  :data:`SWG_BLOCK` steps at once and looked up per step (the offline function's values, not a re-implementation);
* :class:`FeedbackMap` — :meth:`~bptsb_ros.brains.feedback.FeedbackLayer.rest_length_from_features`:
  l·(1 + W·[s, 1]) on driven springs.

A float64 brain gives the torch module's values to rounding (a matrix product summed in another order:
``tests/live/test_brain_inference.py`` checks 1e-12 relative); a float32 one to float32 rounding.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import force_inputs
from bptsb_ros.brains.fnn import LinearInputLayer, MLPBrain
from bptsb_ros.sim.rollout import swg_rest_lengths

#: steps of SWG rest lengths computed per call of the offline function
SWG_BLOCK = 1024


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy())


class ForceMap:
    """Task input u (n_in,) (already scaled: :func:`bptsb_ros.sim.inputs.brain_input`) → forces (M, 2) [N] of
    ``agent``'s LIL or MLP brain, as :func:`bptsb_ros.agent.brain_forces` gives them."""

    def __init__(self, agent: Any) -> None:
        brain, body = agent.brain, agent.body
        if isinstance(brain, MLPBrain):
            self.layers = [(_np(layer.weight).T.copy(), _np(layer.bias)) for layer in brain.layers]
        elif isinstance(brain, LinearInputLayer):
            self.layers = [(_np(brain.weight).T.copy(), _np(brain.bias))]
        else:
            raise TypeError(f"ForceMap needs an MLP or LIL brain, got {type(brain).__name__}")
        self.dtype = self.layers[0][0].dtype
        self.n_in = self.layers[0][0].shape[0]
        self.mask = force_inputs(body).numpy()
        self.n_movable = body.n_movable

    def __call__(self, u: np.ndarray) -> np.ndarray:
        h = np.asarray(u, dtype=self.dtype).reshape(1, -1)
        last = len(self.layers) - 1
        for i, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if i < last:
                h = np.maximum(h, 0)  # ReLU (torch.relu keeps -0.0 and NaN alike; inputs here are finite)
        forces = np.zeros((self.n_movable, 2), dtype=self.dtype)
        forces[self.mask] = h.reshape(-1, 2)
        return forces


class SwgTable:
    """SWG rest lengths (E,) [m] of ``body`` and ``swg`` at any step: :func:`~bptsb_ros.sim.rollout.swg_rest_lengths`
    for the block of :data:`SWG_BLOCK` steps holding it (computed once, the last two blocks kept)."""

    def __init__(self, body: Any, swg: Any) -> None:
        self.body, self.swg = body, swg
        self.blocks: dict[int, np.ndarray] = {}

    def __call__(self, step: int) -> np.ndarray:
        block, row = divmod(int(step), SWG_BLOCK)
        table = self.blocks.get(block)
        if table is None:
            with torch.no_grad():
                table = _np(swg_rest_lengths(self.body, self.swg, block * SWG_BLOCK, SWG_BLOCK))
            self.blocks = {b: t for b, t in self.blocks.items() if b == block - 1}
            self.blocks[block] = table
        return table[row]


class FeedbackMap:
    """State features (F,) → rest lengths (E,) [m] of a fitted :class:`~bptsb_ros.brains.feedback.FeedbackLayer`
    ``layer`` on trained rest lengths ``base`` (E,), with gain g: l + g·(l·(1 + W·[s, 1]) − l)."""

    def __init__(self, layer: Any, base: torch.Tensor) -> None:
        w = _np(layer.weight)
        self.w_in = np.ascontiguousarray(w[:, :-1].T)  # (F, E)
        self.bias = w[:, -1].copy()
        self.driven = _np(layer.driven).astype(w.dtype)
        self.base = _np(base)
        self.dtype = w.dtype
        self.n_features = self.w_in.shape[0]

    def __call__(self, features: np.ndarray, gain: float = 1.0) -> np.ndarray:
        signal = (np.asarray(features, dtype=self.dtype) @ self.w_in + self.bias) * self.driven
        rest = self.base * (1 + signal)
        return rest if gain == 1.0 else self.base + gain * (rest - self.base)
