"""Expanded NARMA emulation (paper, "Time-series emulation task"): an input u(t) ~ U(0, 1) is turned
by a LIL or MLP brain into forces on the movable masses except the CMP; each input is held for
τ = 20 steps; the system output is the CMP's y at the end of each block, compared with

    y(t+1) = 0.3 y(t) + Σ_{i<m} (u(t−i)³ − u(t−i)⁴) + 0.2 Σ_{i<m} (y(t−i)³ − y(t−i)⁴) + 0.1,  m = 2.

Each epoch restarts the body from rest with a fresh input sequence and backpropagates through the
whole episode (no truncation). The first ``washout`` samples are discarded, samples up to
``train_end`` train, the rest are held out; the metric is the NMSE on a held-out sequence.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import brain_forces
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.held_window import held_force_readout, held_window_unsupported
from bptsb_ros.sim.inputs import brain_input, narma_inputs
from bptsb_ros.sim.rollout import held_inputs
from bptsb_ros.tasks.base import Task


def expanded_narma(u: np.ndarray, order: int = 2) -> np.ndarray:
    """Target y(1..K) for inputs u(0..K-1) (K,), y(0) = 0 and y(t<0) = u(t<0) = 0."""
    # plain floats: numpy calls on two-element slices made this loop a third of a NARMA update
    us = [float(x) for x in np.asarray(u, dtype=np.float64)]
    y = [0.0] * (len(us) + 1)
    for t in range(len(us)):
        lo = max(0, t - order + 1)
        s_u = s_y = 0.0
        for i in range(lo, t + 1):
            s_u += us[i] ** 3 - us[i] ** 4
            s_y += y[i] ** 3 - y[i] ** 4
        y[t + 1] = 0.3 * y[t] + s_u + 0.2 * s_y + 0.1
    return np.array(y[1:])


def narma(u: np.ndarray, order: int) -> np.ndarray:
    """The NARMA model of the supplement ("The target IPC"), y(1..K) for inputs u(0..K-1), y(t ≤ 0) = 0:

        m = 2:  y(t+1) = 0.4 y(t) + 0.4 y(t) y(t−1) + 0.6 u(t)³ + 0.1
        m > 2:  y(t+1) = 0.3 y(t) + 0.05 y(t) Σ_{i=0}^{m−1} y(t−i) + 1.5 u(t−m+1) u(t) + 0.1

    (u(t < 0) = 0). The usual input is u ~ U(0, 0.5) (Atiya & Parlos 2000); NARMA10 is ``order=10``.
    """
    if order < 2:
        raise ValueError(f"NARMA order m must be >= 2, got {order}")
    k = len(u)
    y = np.zeros(k + 1)  # y[t] = y(t); y(0) = 0
    for t in range(k):
        if order == 2:
            y_prev = y[t - 1] if t >= 1 else 0.0
            y[t + 1] = 0.4 * y[t] + 0.4 * y[t] * y_prev + 0.6 * u[t] ** 3 + 0.1
        else:
            window = y[max(0, t - order + 1): t + 1]
            u_old = u[t - order + 1] if t - order + 1 >= 0 else 0.0
            y[t + 1] = 0.3 * y[t] + 0.05 * y[t] * window.sum() + 1.5 * u_old * u[t] + 0.1
    return y[1:]


def delay_target(u: np.ndarray, delay: int) -> np.ndarray:
    """The memory task's target y(t) = u(t − Δt) for inputs u(0..K−1) (zero before the series starts)."""
    if delay < 0:
        raise ValueError(f"delay must be >= 0, got {delay}")
    out = np.zeros(len(u))
    out[delay:] = u[: len(u) - delay] if delay else u
    return out


def nmse(pred: np.ndarray, target: np.ndarray) -> float:
    """Normalised mean squared error: mean((pred − target)²) / var(target)."""
    return float(np.mean((pred - target) ** 2) / np.var(target))


class NarmaTask(Task):
    name = "narma"
    fused_window = "episodes"
    loss_label = "output MSE [m²]"
    paper_reference = (
        "paper: double-circle N_mov=17, LIL or MLP brain, u~U(0,1) scaled to (0,20), τ=20 steps, output = y of "
        "the CMP; metric: NMSE of the output vs the expanded NARMA2 target (the paper's values are in a "
        "figure table, not in its text)"
    )

    def __init__(self, agent, cfg) -> None:
        super().__init__(agent, cfg)
        if agent.body.cmp_local < 0:
            raise ValueError("the NARMA task needs a body with a central mass point")
        self.rng = np.random.default_rng(cfg.seed)
        self.steps_per_update = cfg.narma.n_inputs * cfg.narma.tau
        tc = cfg.training
        self.fused_episodes = tc.backend == "fused" and held_window_unsupported(agent.body, adjoint=tc.adjoint) is None

    def num_updates(self) -> int:
        return self.cfg.epochs

    def episode(self, u: np.ndarray, *, grad: bool = True) -> torch.Tensor:
        """Run one episode from rest for inputs u (K,); returns the CMP y at each block end (K,).

        Under ``training.backend: fused`` the brain's forces are computed once per block and the window is one
        autograd node (:func:`~bptsb_ros.body.held_window.held_force_readout`); otherwise the per-step forces go
        through :func:`~bptsb_ros.body.adjoint.rollout_window`. The two agree to rounding."""
        n = self.cfg.narma
        body = self.agent.body
        if self.fused_episodes:
            with torch.set_grad_enabled(grad):
                blocks = brain_forces(self.agent, brain_input(torch.as_tensor(u, dtype=body.l.dtype).unsqueeze(-1), n))
                state = body.initial_state(1, external_force=blocks[0])
                return held_force_readout(body, state, blocks, n.tau, body.cmp_local, 1)
        steps = len(u) * n.tau
        per_step = held_inputs(torch.as_tensor(u, dtype=body.l.dtype), n.tau, steps)  # (steps+1,)
        forces = brain_forces(self.agent, brain_input(per_step.unsqueeze(-1), n))  # (steps+1, M, 2)
        state = body.initial_state(1, external_force=forces[0])
        with torch.set_grad_enabled(grad):
            win = rollout_window(body, state, body.l.expand(steps, -1), forces[1:], adjoint=self.cfg.training.adjoint)
        body.check_finite(win.final)
        return win.r[n.tau - 1:: n.tau, 0, body.cmp_local, 1]

    def target(self, u: np.ndarray) -> np.ndarray:
        """The series the output is trained on for inputs u (K,): entry t is compared with the output after
        u(t) was held (expanded NARMA: y(t+1); memory task: u(t − delay))."""
        n = self.cfg.narma
        return delay_target(u, n.delay) if n.target == "memory" else expanded_narma(u, n.order)

    def block_positions(self, u: np.ndarray) -> np.ndarray:
        """(K, M, 2) positions of the movable masses at the end of each input block, one episode from rest (no
        gradients) — the states whose IPC the paper shows."""
        from bptsb_ros.sim.blocks import block_positions

        n = self.cfg.narma
        return block_positions(self.agent.body, lambda x: brain_forces(self.agent, brain_input(x, n)), u,
                               self.cfg.narma.tau)[0]

    def update_loss(self, index: int) -> tuple[torch.Tensor, dict[str, float]]:
        n = self.cfg.narma
        u = self.rng.uniform(0.0, 1.0, n.n_inputs)
        y = torch.as_tensor(self.target(u), dtype=self.agent.body.l.dtype)
        out = self.episode(u)
        sl = slice(n.washout, n.train_end)
        return ((out[sl] - y[sl]) ** 2).mean(), {}

    def state_dict(self) -> dict[str, Any]:
        return {"rng": self.rng.bit_generator.state}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state["rng"]

    def evaluate(self) -> dict[str, Any]:
        n = self.cfg.narma
        u = narma_inputs(n.eval_seed, n.n_inputs)
        y = self.target(u)
        out = self.episode(u, grad=False).double().numpy()
        test = slice(n.train_end, n.n_inputs)
        post = slice(n.washout, n.n_inputs)
        self._eval = {"u": u, "y": y, "out": out}
        return {
            "metric": "nmse_test",
            "nmse_test": nmse(out[test], y[test]),
            "nmse_after_washout": nmse(out[post], y[post]),
            "nmse_of_constant_mean": 1.0,
            "paper_reference": self.paper_reference,
        }
