"""Offline simulation of agents: open loop (SWG rest lengths, brain forces from an input series) and
closed loop (feedback layer). Every step is ``MSDN.step``, the function the live node also runs.

Command convention (as ``MSDN.step``): the command used to go from step k to k+1 is the one "in
force at step k+1"; an open-loop SWG command at step k is l·(1 + A sin(ω k Δt + φ)); a closed-loop
command at step k+1 is l·(1 + W·[s_k, 1]) from the state at step k.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bptsb_ros.agent import Agent, brain_forces
from bptsb_ros.body.msdn import MSDN, BodyState
from bptsb_ros.brains import FeedbackLayer, SineWaveGenerator


@dataclass
class Rollout:
    """Recorded simulation, steps 0..T (T+1 entries), batch kept.

    r, v, a: (T+1, B, M, 2) movable masses; length, rest_length: (T+1, B, E);
    external_force: (T+1, B, M, 2); final: the state after step T.
    """

    r: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    length: torch.Tensor
    rest_length: torch.Tensor
    external_force: torch.Tensor
    final: BodyState

    @property
    def steps(self) -> int:
        return self.r.shape[0] - 1


class _Recorder:
    def __init__(self, steps: int, state: BodyState, n_springs: int) -> None:
        b, m = state.r.shape[0], state.r.shape[1]
        like = state.r
        self.r = like.new_empty((steps + 1, b, m, 2))
        self.v = torch.empty_like(self.r)
        self.a = torch.empty_like(self.r)
        self.length = like.new_empty((steps + 1, b, n_springs))
        self.rest = torch.empty_like(self.length)
        self.ext = torch.zeros_like(self.r)

    def put(self, i: int, state: BodyState, rest: torch.Tensor, ext: torch.Tensor | None) -> None:
        self.r[i], self.v[i], self.a[i], self.length[i] = state.r, state.v, state.a, state.length
        self.rest[i] = rest
        if ext is not None:
            self.ext[i] = ext

    def result(self, final: BodyState) -> Rollout:
        return Rollout(self.r, self.v, self.a, self.length, self.rest, self.ext, final)


def swg_rest_lengths(body: MSDN, swg: SineWaveGenerator, first_step: int, count: int) -> torch.Tensor:
    """(count, E) SWG rest lengths at steps first_step .. first_step+count-1."""
    t = torch.arange(first_step, first_step + count, dtype=body.l.dtype) * body.dt
    return swg.rest_length(body.l, t)


def held_inputs(u: torch.Tensor, tau: int) -> torch.Tensor:
    """Input series (K,) held for ``tau`` steps each → per-step series (K·tau,)."""
    return u.repeat_interleave(tau)


@torch.no_grad()
def simulate_open_loop(
    agent: Agent,
    steps: int,
    *,
    state: BodyState | None = None,
    inputs: torch.Tensor | None = None,
    wind: torch.Tensor | None = None,
    displacement: torch.Tensor | None = None,
    check_every: int = 1000,
) -> Rollout:
    """Simulate an agent's open loop for ``steps`` steps.

    Args:
        agent: SWG agents modulate rest lengths; LIL/MLP agents need ``inputs``.
        state: start state (its ``step`` sets the SWG clock); default: at rest at t = 0.
        inputs: (steps + 1,) per-step task input u for LIL/MLP agents (value in force at each step;
            already multiplied by the task's input scale).
        wind: (2,) constant force on every movable mass [N], or (steps + 1, 2) per step.
        displacement: (B, M, 2) initial displacement of the movable masses [m] when ``state`` is None.
    """
    body = agent.body
    k0 = 0 if state is None else state.step
    if isinstance(agent.brain, SineWaveGenerator):
        rest = swg_rest_lengths(body, agent.brain, k0, steps + 1)
        ext = None
    else:
        if inputs is None or inputs.shape[0] != steps + 1:
            raise ValueError(f"a {type(agent.brain).__name__} agent needs inputs of length steps + 1 = {steps + 1}")
        rest = body.l.expand(steps + 1, -1)
        ext = brain_forces(agent, inputs.to(body.l.dtype).unsqueeze(-1)).unsqueeze(1)  # (T+1, 1, M, 2)
    ext = _add_wind(body, ext, wind, steps)
    if state is None:
        state = body.initial_state(
            1 if displacement is None else displacement.shape[0],
            rest_length=rest[0],
            external_force=None if ext is None else ext[0],
            displacement=displacement,
        )
    rec = _Recorder(steps, state, body.topology.n_springs)
    rec.put(0, state, rest[0], None if ext is None else ext[0])
    for i in range(1, steps + 1):
        state = body.step(state, rest[i], None if ext is None else ext[i])
        rec.put(i, state, rest[i], None if ext is None else ext[i])
        if i % check_every == 0:
            body.check_finite(state)
    body.check_finite(state)
    return rec.result(state)


@torch.no_grad()
def simulate_closed_loop(
    body: MSDN,
    feedback: FeedbackLayer,
    steps: int,
    *,
    state: BodyState | None = None,
    wind: torch.Tensor | None = None,
    displacement: torch.Tensor | None = None,
    check_every: int = 1000,
) -> Rollout:
    """Closed loop: the rest length at step k+1 is ``feedback.rest_length(body.l, state_k)``.

    The start state defaults to rest (base rest lengths, optionally displaced).
    """
    ext = _add_wind(body, None, wind, steps)
    if state is None:
        state = body.initial_state(
            1 if displacement is None else displacement.shape[0],
            external_force=None if ext is None else ext[0],
            displacement=displacement,
        )
    rec = _Recorder(steps, state, body.topology.n_springs)
    rec.put(0, state, body.l.expand_as(state.length), None if ext is None else ext[0])
    for i in range(1, steps + 1):
        rest = feedback.rest_length(body.l, state)
        state = body.step(state, rest, None if ext is None else ext[i])
        rec.put(i, state, rest, None if ext is None else ext[i])
        if i % check_every == 0:
            body.check_finite(state)
    body.check_finite(state)
    return rec.result(state)


def _add_wind(body: MSDN, ext: torch.Tensor | None, wind: torch.Tensor | None, steps: int) -> torch.Tensor | None:
    if wind is None:
        return ext
    w = torch.as_tensor(wind, dtype=body.l.dtype)
    if w.dim() == 1:
        w = w.expand(steps + 1, 2)
    if w.shape != (steps + 1, 2):
        raise ValueError(f"wind must be (2,) or ({steps + 1}, 2), got {tuple(w.shape)}")
    force = w[:, None, None, :].expand(steps + 1, 1, body.n_movable, 2)
    return force if ext is None else ext + force

