"""Populations: ONE batched simulation of one agent under many conditions (perturbation seeds, wind values,
switch timings), recording only the masses an analysis needs.

:func:`simulate_commands` records every mass, velocity and spring of every step, which for a population
(B = 1,100 rows × 30,000 steps) would take gigabytes; :func:`run_population` runs the same ``MSDN.step``
loop and keeps only the tracked masses (usually the CMP). Rows are independent: a row that blows up is
flagged, put back at rest on the layout so that it cannot poison the batch with NaN, and its tracked
positions after the blow-up are NaN.

Command convention (as :func:`bptsb_ros.sim.rollout.simulate_commands`): the command used to go from step
i−1 to i is the one in force at step i; an open-loop SWG rest length at step i is l·(1 + A sin(ω iΔt + φ)),
a closed-loop one l·(1 + W·[s_{i−1}, 1]).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from bptsb_ros.body.msdn import MSDN, BodyState
from bptsb_ros.brains import FeedbackLayer, SineWaveGenerator


@dataclass
class Population:
    """tracked: (T+1, B, K, 2) positions of the tracked masses [m] (NaN after a row diverged);
    final: the state after step T; diverged_at: (B,) step at which each row diverged, −1 if never."""

    tracked: torch.Tensor
    final: BodyState
    diverged_at: torch.Tensor

    @property
    def diverged(self) -> torch.Tensor:
        return self.diverged_at >= 0


def wind_force(body: MSDN, wind: torch.Tensor) -> torch.Tensor:
    """Wind (B, 2) or (2,) [N] → (B, M, 2) (or (1, M, 2)) force on every movable mass."""
    w = torch.as_tensor(wind, dtype=body.l.dtype)
    if w.dim() == 1:
        w = w.unsqueeze(0)
    return w[:, None, :].expand(w.shape[0], body.n_movable, 2)


@torch.no_grad()
def run_population(
    body: MSDN,
    steps: int,
    state: BodyState,
    *,
    swg: SineWaveGenerator | None = None,
    feedback: FeedbackLayer | None = None,
    wind: torch.Tensor | Callable[[int], torch.Tensor] | None = None,
    track: tuple[int, ...] | None = None,
    check_every: int = 100,
    limit: float = 100.0,
    progress: Callable[[int], None] | None = None,
) -> Population:
    """Simulate a batch of B bodies sharing one brain for ``steps`` steps from ``state`` (B rows).

    Args:
        swg: open loop: rest lengths from the SWG clock (``state.step`` is the clock's step).
        feedback: closed loop: rest lengths from the previous state (give exactly one of swg, feedback).
        wind: force on every movable mass [N]: (2,) or (B, 2) constant, or a function of the step index
            i = 1..steps returning (B, 2) or (2,) (the wind in force at step i).
        track: movable-mass indices (state rows) to record; default the CMP.
        check_every: steps between divergence checks; a row with a non-finite state or |r| > ``limit`` m
            is flagged and reset to rest on the layout.
        progress: called with the number of steps done every ``check_every`` steps.
    """
    if (swg is None) == (feedback is None):
        raise ValueError("run_population needs exactly one of swg (open loop) or feedback (closed loop)")
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    track = (body.cmp_local,) if track is None else tuple(track)
    if min(track) < 0:
        raise ValueError("run_population: no mass to track (the body has no CMP; pass track=...)")
    index = torch.as_tensor(track, dtype=torch.long)
    batch = state.r.shape[0]
    out = state.r.new_empty((steps + 1, batch, len(track), 2))
    out[0] = state.r[:, index]
    diverged_at = torch.full((batch,), -1, dtype=torch.long)
    k0 = state.step
    rest_swg = None
    if swg is not None:
        rest_swg = swg.rest_length_at_steps(body.l, torch.arange(k0 + 1, k0 + steps + 1), body.dt)  # (steps, E)
    constant = None
    if wind is not None and not callable(wind):
        constant = wind_force(body, wind)
    for i in range(1, steps + 1):
        rest = rest_swg[i - 1] if rest_swg is not None else feedback.rest_length(body.l, state)
        force = constant
        if callable(wind):
            force = wind_force(body, wind(i))
        state = body.step(state, rest, force)
        out[i] = state.r[:, index]
        if i % check_every == 0 or i == steps:
            state = _reset_diverged(body, state, diverged_at, limit, rest, force)
            if progress is not None:
                progress(i)
    bad = diverged_at >= 0
    if bool(bad.any()):
        steps_idx = torch.arange(steps + 1).unsqueeze(1)  # (T+1, 1)
        after = (steps_idx >= (diverged_at - check_every).clamp(min=0).unsqueeze(0)) & bad.unsqueeze(0)
        out[after] = float("nan")
    return Population(out, state, diverged_at)


def _reset_diverged(body: MSDN, state: BodyState, diverged_at: torch.Tensor, limit: float,
                    rest: torch.Tensor, force: torch.Tensor | None) -> BodyState:
    """Flag rows that blew up since the last check (non-finite or |r| > limit) and put them back at rest."""
    r, v, a = state.r, state.v, state.a
    ok = torch.isfinite(r).all((1, 2)) & torch.isfinite(v).all((1, 2)) & torch.isfinite(a).all((1, 2))
    ok &= r.abs().amax((1, 2)) <= limit
    if bool(ok.all()):
        return state
    new = ~ok & (diverged_at < 0)
    diverged_at[new] = state.step
    bad = ~ok
    r0 = body.positions0[body.movable_index].expand_as(r)
    r = torch.where(bad[:, None, None], r0, r)
    v = torch.where(bad[:, None, None], torch.zeros_like(v), v)
    rest_b = rest.expand(r.shape[0], -1) if rest.dim() == 1 else rest
    f = None if force is None else force.expand_as(r)
    a_new, length = body.acceleration(r, v, rest_b, f)
    a = torch.where(bad[:, None, None], a_new, a)
    length = torch.where(bad[:, None], length, state.length)
    return BodyState(r, v, a, length, state.step)
