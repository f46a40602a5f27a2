"""What ``feedback_brain`` commands, ROS-free: the closed loop body state at step k → rest lengths in force at step
k+1, l·(1 + g·W·[s_k + ε, 1]) with the agent's fitted feedback layer (``FeedbackLayer.rest_length_from_features``
at gain g = 1 and noise ε = 0, the function ``FeedbackLayer.rest_length`` applies offline to ``state_features``),
evaluated in numpy (:class:`~bptsb_ros.live.inference.FeedbackMap`).

The state of step k arrives as the body publishes it: the positions (N, 2) [m] of every mass for the state type
``spring_length`` (the spring lengths are computed from them exactly as the body's step computes them,
:func:`spring_lengths`), or the movable masses' positions, velocities or efforts (2M,) for the other types.

With ``open_loop`` = W > 0 the SWG answers ``/clock`` for steps 0…W and the feedback layer takes over from step
W+1 (the states of steps W, W+1, … answer steps W+1, W+2, …); with W = 0 the command for step 0 is the trained rest
length and the layer answers every later step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from bptsb_ros.brains.feedback import FeedbackLayer
from bptsb_ros.live.inference import FeedbackMap, SwgTable


def perturbed_rest_length(layer: FeedbackLayer, base: torch.Tensor, features: torch.Tensor, gain: float,
                          noise: float, rng: np.random.Generator) -> torch.Tensor:
    """Rest lengths (1, E) [m] l·(1 + g·W·[s + ε, 1]) with ε ~ N(0, noise²) per feature, drawn from ``rng`` only when
    ``noise`` > 0; ``gain`` 1 and ``noise`` 0 give ``layer.rest_length_from_features`` exactly (the torch reference
    of :class:`FeedbackCommands`).

    Args:
        base: (E,) trained rest lengths l [m]; features: (1, F) state features s, laid out as ``state_features``.
    """
    if noise > 0:
        features = features + torch.from_numpy(rng.standard_normal(features.shape[1]) * noise).to(features.dtype)
    rest = layer.rest_length_from_features(base, features)
    return rest if gain == 1.0 else base + gain * (rest - base)


def spring_lengths(positions: np.ndarray, springs: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Lengths (E,) [m] of springs (E, 2) (mass indices i, j) from the positions (N, 2) [m] of every mass: |r_i − r_j|
    in ``dtype``, the arithmetic of the body's step (``body/kernel.py``: the difference, its squares summed, the
    square root), so a float64 body's published positions give its own lengths bit for bit."""
    p = np.asarray(positions).astype(dtype, copy=False)
    d = p[springs[:, 0]] - p[springs[:, 1]]
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])


class FeedbackCommands:
    """The commands of a feedback brain for ``agent`` (with a fitted feedback layer; an SWG brain if
    ``open_loop`` > 0). ``noise_seed`` seeds the feature noise."""

    def __init__(self, agent, open_loop: int = 0, noise_seed: int = 0) -> None:
        self.agent, self.open_loop = agent, int(open_loop)
        body = agent.body
        self.base = body.l.detach()
        self.layer = FeedbackMap(agent.feedback, self.base)
        self.dtype = self.layer.dtype
        self.state_type = agent.feedback.state_type
        self.mass = body.mass.detach().double().numpy()  # (M,) movable masses: effort → acceleration
        self.springs = np.asarray(body.topology.springs, dtype=np.int64).reshape(-1, 2)
        self.n_masses = body.topology.n_masses
        self.size = 2 * self.n_masses if self.state_type == "spring_length" else 2 * body.n_movable
        self.what = "mass positions" if self.state_type == "spring_length" else f"mass states ({self.state_type})"
        self.rng = np.random.default_rng(noise_seed)
        self.swg = SwgTable(body, agent.brain) if self.open_loop else None

    def on_clock(self, step: int) -> np.ndarray | None:
        """Rest lengths (E,) [m] for ``step`` when ``/clock`` announces it and the clock answers it (step <= W), else
        None (the state of the step before answers it)."""
        if step > self.open_loop:
            return None
        if self.swg is None:
            return self.layer.base
        return self.swg(step)

    def features(self, values: Sequence[float] | np.ndarray) -> np.ndarray | str:
        """The layer's state features (F,) from the values of a state message — the positions (N, 2) of every mass
        [m] (→ spring lengths), or the movable positions [m], velocities [m/s] or efforts [N] (→ accelerations
        [m/s²], effort / mass) (2M) — or why not (wrong number of values)."""
        x = np.asarray(values, dtype=np.float64).reshape(-1)
        if x.size != self.size:
            return f"{x.size} values, expected {self.size}"
        if self.state_type == "spring_length":
            return spring_lengths(x.reshape(-1, 2), self.springs, self.dtype)
        if self.state_type == "acceleration":
            x = (x.reshape(-1, 2) / self.mass[:, None]).reshape(-1)
        return x.astype(self.dtype, copy=False)

    def on_state(self, step: int, values: Sequence[float] | np.ndarray, gain: float = 1.0,
                 noise: float = 0.0) -> np.ndarray | str | None:
        """Rest lengths (E,) [m] for step ``step`` + 1 from the state of ``step`` (None: the clock answers that
        step; a string: why the state was ignored)."""
        if step < self.open_loop:
            return None
        features = self.features(values)
        if isinstance(features, str):
            return f"ignored {self.what} of step {step}: {features}"
        if noise > 0:
            features = features + (self.rng.standard_normal(features.size) * noise).astype(self.dtype)
        return self.layer(features, gain)
