"""States of a body driven by a held input, read once per input block (the time-series tasks' sampling)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.msdn import MSDN
from bptsb_ros.sim.rollout import held_inputs


def block_positions(body: MSDN, forces_of_u: Callable[[torch.Tensor], torch.Tensor], u: np.ndarray, tau: int,
                    chunk_blocks: int = 250) -> np.ndarray:
    """Drive ``body`` from rest with inputs held τ steps and return the movable masses' positions at the end of
    every block, one batched simulation.

    Args:
        body: the MSDN (not modified).
        forces_of_u: maps held inputs (..., B, 1) to external forces (..., B, M, 2) [N] (a brain, scale included).
        u: (K,) or (B, K) inputs; row b is batch member b's series.
        tau: simulation steps per input (step k carries u[(k − 1) // τ], ``held_inputs``).
        chunk_blocks: blocks simulated per window (bounds memory).

    Returns:
        (B, K, M, 2) positions [m]; entry j is the state after the τ steps of u_j ("immediately after the final
        step", the paper's output sampling).
    """
    u = np.atleast_2d(np.asarray(u, dtype=np.float64))
    batch, k_total = u.shape
    dtype = body.l.dtype
    steps = k_total * tau
    with torch.no_grad():
        held = held_inputs(torch.as_tensor(u.T, dtype=dtype), tau, steps)  # (steps + 1, B)
        forces0 = forces_of_u(held[:1].unsqueeze(-1))[0]
        state = body.initial_state(batch, external_force=forces0)
        out = np.empty((batch, k_total, body.n_movable, 2))
        for first in range(0, k_total, chunk_blocks):
            last = min(first + chunk_blocks, k_total)
            sl = slice(first * tau + 1, last * tau + 1)
            forces = forces_of_u(held[sl].unsqueeze(-1))  # (W, B, M, 2)
            win = rollout_window(body, state, body.l.expand(forces.shape[0], -1), forces)
            body.check_finite(win.final)
            out[:, first:last] = win.r[tau - 1:: tau].double().numpy().transpose(1, 0, 2, 3)
            state = win.final
    return out
