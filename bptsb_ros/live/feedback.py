"""What ``feedback_brain`` commands, ROS-free: the closed loop body state at step k → rest lengths in force at step
k+1, l·(1 + g·W·[s_k + ε, 1]) with the agent's fitted feedback layer (``FeedbackLayer.rest_length_from_features``
at gain g = 1 and noise ε = 0, the function ``FeedbackLayer.rest_length`` applies offline to ``state_features``).

With ``open_loop`` = W > 0 the SWG answers ``/clock`` for steps 0…W and the feedback layer takes over from step
W+1 (the states of steps W, W+1, … answer steps W+1, W+2, …); with W = 0 the command for step 0 is the trained rest
length and the layer answers every later step.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from bptsb_ros.brains.feedback import FeedbackLayer
from bptsb_ros.sim.rollout import swg_rest_lengths


def perturbed_rest_length(layer: FeedbackLayer, base: torch.Tensor, features: torch.Tensor, gain: float,
                          noise: float, rng: np.random.Generator) -> torch.Tensor:
    """Rest lengths (1, E) [m] l·(1 + g·W·[s + ε, 1]) with ε ~ N(0, noise²) per feature, drawn from ``rng`` only when
    ``noise`` > 0; ``gain`` 1 and ``noise`` 0 give ``layer.rest_length_from_features`` exactly.

    Args:
        base: (E,) trained rest lengths l [m]; features: (1, F) state features s, laid out as ``state_features``.
    """
    if noise > 0:
        features = features + torch.from_numpy(rng.standard_normal(features.shape[1]) * noise).to(features.dtype)
    rest = layer.rest_length_from_features(base, features)
    return rest if gain == 1.0 else base + gain * (rest - base)


class FeedbackCommands:
    """The commands of a feedback brain for ``agent`` (with a fitted feedback layer; an SWG brain if
    ``open_loop`` > 0). ``noise_seed`` seeds the feature noise."""

    def __init__(self, agent, open_loop: int = 0, noise_seed: int = 0) -> None:
        self.agent, self.open_loop = agent, int(open_loop)
        body = agent.body
        self.base = body.l.detach()
        self.state_type = agent.feedback.state_type
        self.mass = body.mass.detach().double().numpy()  # (M,) movable masses: effort → acceleration
        self.size = body.topology.n_springs if self.state_type == "spring_length" else 2 * body.n_movable
        self.what = "spring lengths" if self.state_type == "spring_length" else f"mass states ({self.state_type})"
        self.rng = np.random.default_rng(noise_seed)

    def on_clock(self, step: int) -> torch.Tensor | None:
        """Rest lengths (E,) [m] for ``step`` when ``/clock`` announces it and the clock answers it (step <= W), else
        None (the state of the step before answers it)."""
        if step > self.open_loop:
            return None
        if self.open_loop == 0:
            return self.base
        with torch.no_grad():
            return swg_rest_lengths(self.agent.body, self.agent.brain, step, 1)[0]

    def features(self, values: Sequence[float] | np.ndarray) -> torch.Tensor | str:
        """The layer's state features (1, F) from the values of a state message — spring lengths (E) [m], or the
        movable positions [m], velocities [m/s] or efforts [N] (→ accelerations [m/s²], effort / mass) (2M) — or
        why not (wrong number of values)."""
        x = np.asarray(values, dtype=np.float64).reshape(-1)
        if x.size != self.size:
            return f"{x.size} values, expected {self.size}"
        if self.state_type == "acceleration":
            x = (x.reshape(-1, 2) / self.mass[:, None]).reshape(-1)
        return torch.from_numpy(x).to(self.base.dtype).unsqueeze(0)

    def on_state(self, step: int, values: Sequence[float] | np.ndarray, gain: float = 1.0,
                 noise: float = 0.0) -> torch.Tensor | str | None:
        """Rest lengths (1, E) [m] for step ``step`` + 1 from the state of ``step`` (None: the clock answers that
        step; a string: why the state was ignored)."""
        if step < self.open_loop:
            return None
        features = self.features(values)
        if isinstance(features, str):
            return f"ignored {self.what} of step {step}: {features}"
        with torch.no_grad():
            return perturbed_rest_length(self.agent.feedback, self.base, features, gain, noise, self.rng)
