"""Perturbations of the movable masses (paper: Fig. 4(b,c), Methods "Lissajous curve drawing task").

A perturbation of strength σ displaces every movable mass by N(0, σ²) per coordinate. Seed i draws one
standard-normal pattern z_i (M, 2), the same for every σ, so a σ sweep varies only the strength. The offline
experiment (``lissajous-perturbation``), ``body_sim``'s scheduled perturbation (``perturb_at``) and the offline
replay of a live run all draw their displacements here. ``MSDN.displaced`` applies one.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from bptsb_ros.agent import Agent


def perturbation_pattern(n_masses: int, seed: int) -> torch.Tensor:
    """(M, 2) float64 standard-normal pattern z of ``seed`` (``torch.randn`` of a generator seeded with it)."""
    if n_masses < 1:
        raise ValueError(f"need at least one movable mass, got {n_masses}")
    return torch.randn(n_masses, 2, generator=torch.Generator().manual_seed(int(seed)), dtype=torch.float64)


def perturbation(n_masses: int, sigma: float, seed: int) -> np.ndarray:
    """(M, 2) float64 displacement σ·z [m] of every movable mass (σ ≥ 0, finite)."""
    if not (math.isfinite(sigma) and sigma >= 0):
        raise ValueError(f"sigma must be finite and >= 0, got {sigma}")
    return (sigma * perturbation_pattern(n_masses, seed)).numpy()


def perturbation_batch(n_masses: int, seeds: int, sigmas: np.ndarray, dtype: torch.dtype) -> torch.Tensor:
    """(len(sigmas)·seeds, M, 2) displacements [m]: row j·seeds + i = σ_j · z_i, z_i the pattern of seed i."""
    z = torch.stack([perturbation_pattern(n_masses, i) for i in range(seeds)])
    return (torch.as_tensor(sigmas, dtype=torch.float64)[:, None, None, None] * z[None]).reshape(-1, n_masses, 2) \
        .to(dtype)


@torch.no_grad()
def simulate_perturbed(agent: Agent, steps: int, perturbations: dict[int, np.ndarray], *,
                       wind: np.ndarray | torch.Tensor | None = None, feedback_from: int | None = None) -> torch.Tensor:
    """Positions (steps + 1, M, 2) of the movable masses of an agent's run from rest, with the state of each step
    k in ``perturbations`` displaced by ``perturbations[k]`` (M, 2) [m] — what ``body_sim`` does live.

    The SWG drives the body; from step ``feedback_from`` on (if given) the fitted feedback layer does (the closed
    loop after ``open_loop_steps``). ``wind``: (steps + 1, 2) wind [N] in force at each step, or None. A
    displacement keeps the velocities and recomputes the accelerations with the rest length and force in force
    at that step (``MSDN.displaced``).
    """
    from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop

    body = agent.body
    if feedback_from is not None and agent.feedback is None:
        raise ValueError("feedback_from needs an agent with a feedback layer")
    w = None if wind is None else torch.as_tensor(wind, dtype=body.l.dtype)
    if w is not None and w.shape != (steps + 1, 2):
        raise ValueError(f"wind must be ({steps + 1}, 2), got {tuple(w.shape)}")
    cuts = sorted({k for k in perturbations if 0 <= k <= steps}
                  | ({feedback_from} if feedback_from is not None and 0 < feedback_from < steps else set())
                  | {steps})
    rows: list[torch.Tensor] = []
    state = None
    k = 0
    for b in cuts:
        seg_wind = None if w is None else w[k:b + 1]
        if state is None or b > k:
            if feedback_from is not None and k >= feedback_from:
                roll = simulate_closed_loop(body, agent.feedback, b - k, state=state, wind=seg_wind)
            else:
                roll = simulate_open_loop(agent, b - k, state=state, wind=seg_wind)
            rows.append(roll.r[:, 0] if not rows else roll.r[1:, 0])
            state, rest, force = roll.final, roll.rest_length[-1], roll.external_force[-1]
        if b in perturbations:
            d = torch.as_tensor(np.asarray(perturbations[b]), dtype=body.l.dtype).reshape(1, -1, 2)
            state = body.displaced(state, d, rest, force)
            rows[-1] = torch.cat([rows[-1][:-1], state.r], 0)
        k = b
    return torch.cat(rows, 0)
