"""Offline simulation: one loop (:func:`simulate_commands`: given rest lengths and external forces per
step) used by the open loop of agents (SWG rest lengths, brain forces from an input series), the closed
loop (feedback layer) and ``bptsb simulate``. Every step is ``MSDN.step``, the function the live node
also runs.

Command convention (as ``MSDN.step``): the command used to go from step k to k+1 is the one "in
force at step k+1"; row 0 holds the start state with the command in force at step 0, from which a(0)
is computed. An open-loop SWG command at step k is l·(1 + A sin(ω k Δt + φ)); a closed-loop command
at step k+1 is l·(1 + W·[s_k, 1]) from the state at step k. A task input held for τ steps follows
:func:`held_inputs`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch

from bptsb_ros.agent import Agent, brain_forces
from bptsb_ros.body.msdn import MSDN, BodyState, SimulationDiverged
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

    def state(self, i: int, step: int) -> BodyState:
        return BodyState(self.r[i], self.v[i], self.a[i], self.length[i], step)

    def result(self, final: BodyState) -> Rollout:
        return Rollout(self.r, self.v, self.a, self.length, self.rest, self.ext, final)


def swg_rest_lengths(body: MSDN, swg: SineWaveGenerator, first_step: int, count: int) -> torch.Tensor:
    """(count, E) SWG rest lengths at steps first_step .. first_step+count-1 (exact clock phase)."""
    return swg.rest_length_at_steps(body.l, torch.arange(first_step, first_step + count), body.dt)


PROGRESS_EVERY = 100  # steps between calls of a ``progress`` callback
SeriesT = TypeVar("SeriesT", np.ndarray, torch.Tensor)


def held_inputs(u: SeriesT, tau: int, steps: int) -> SeriesT:
    """Inputs u (K,), each held for ``tau`` steps → the (steps + 1,) input in force at steps 0..steps.

    Step 0 and steps 1..τ carry u_0, steps jτ+1..(j+1)τ carry u_j: step k carries u[max(k − 1, 0) // τ]
    (the NARMA episodes' rule). Needs K ≥ (steps − 1) // τ + 1 inputs; returns the type of ``u``.
    """
    if tau < 1:
        raise ValueError(f"tau must be >= 1, got {tau}")
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    needed = max(steps - 1, 0) // tau + 1
    if u.shape[0] < needed:
        raise ValueError(f"{steps} steps held for tau = {tau} need {needed} inputs, got {u.shape[0]}")
    index = np.maximum(np.arange(steps + 1) - 1, 0) // tau
    if isinstance(u, torch.Tensor):
        return u[torch.from_numpy(index).to(u.device)]
    return np.asarray(u)[index]


def wind_forces(body: MSDN, wind: torch.Tensor | None, steps: int) -> torch.Tensor | None:
    """Wind (2,) constant or (steps + 1, 2) per step [N] → (steps + 1, 1, M, 2) force on every movable mass."""
    return _add_wind(body, None, wind, steps)


@torch.no_grad()
def simulate_commands(
    body: MSDN,
    steps: int,
    rest_lengths: torch.Tensor,
    external_forces: torch.Tensor | None = None,
    *,
    state: BodyState | None = None,
    displacement: torch.Tensor | None = None,
    velocity: torch.Tensor | None = None,
    check_every: int = 1000,
    progress: Callable[[int], None] | None = None,
) -> Rollout:
    """Simulate ``steps`` steps under given commands: the core loop of every offline simulation.

    Args:
        rest_lengths: (steps + 1, E) or (steps + 1, B, E) rest length in force at steps 0..steps [m].
        external_forces: (steps + 1, B, M, 2) brain + wind force on the movable masses in force at
            steps 0..steps [N] (B may be 1), or None.
        state: start state; default: the layout at t = 0 (plus ``displacement`` (B, M, 2) [m], with
            ``velocity`` (B, M, 2) [m/s]), its a(0) from r(0), v(0), ``rest_lengths[0]``, ``external_forces[0]``.
            Row 0 of the rollout is the start state with ``rest_lengths[0]`` and ``external_forces[0]``.
        check_every: steps between divergence checks (a failed check names the first bad step).
        progress: called with the number of steps done every 100 steps and at the end.

    Raises:
        SimulationDiverged: on NaN/inf or blow-up, naming the first bad step.
    """
    if rest_lengths.shape[0] != steps + 1:
        raise ValueError(f"rest_lengths must have steps + 1 = {steps + 1} rows, got {rest_lengths.shape[0]}")
    if external_forces is not None and external_forces.shape[0] != steps + 1:
        raise ValueError(f"external_forces must have steps + 1 = {steps + 1} rows, got {external_forces.shape[0]}")
    rest = rest_lengths.unbind(0)
    ext = None if external_forces is None else external_forces.unbind(0)
    if state is None:
        batches = [1]
        if displacement is not None:
            batches.append(displacement.shape[0])
        if velocity is not None and velocity.dim() == 3:
            batches.append(velocity.shape[0])
        if rest_lengths.dim() == 3:
            batches.append(rest_lengths.shape[1])
        if external_forces is not None:
            batches.append(external_forces.shape[1])
        state = body.initial_state(max(batches), rest_length=rest[0], external_force=None if ext is None else ext[0],
                                   displacement=displacement, velocity=velocity)
    if body.uses_kernel(state.r):
        return _run_windows(body, steps, state, rest_lengths, external_forces, check_every, progress)
    return _run(body, steps, state, rest[0], lambda i, _prev: rest[i], ext, check_every, progress)


def _run_windows(
    body: MSDN,
    steps: int,
    state: BodyState,
    rest_lengths: torch.Tensor,
    external_forces: torch.Tensor | None,
    check_every: int,
    progress: Callable[[int], None] | None,
) -> Rollout:
    """:func:`_run` for commands known in advance, a window of steps per kernel call (numba backend).

    The kernel computes each step exactly as a one-step call does (``MSDN.step``), so the rows are the
    same bits as the step-by-step loop's (tests/body/test_kernel.py); windows end at every progress and
    divergence-check boundary.
    """
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if check_every < 1:
        raise ValueError(f"check_every must be >= 1, got {check_every}")
    rec = _Recorder(steps, state, body.topology.n_springs)
    rec.put(0, state, rest_lengths[0], None if external_forces is None else external_forces[0])
    ends = sorted({*range(PROGRESS_EVERY, steps, PROGRESS_EVERY), *range(check_every, steps, check_every), steps})
    checked, lo = 0, 0
    for hi in ends:
        if hi == lo:
            continue
        ext = None if external_forces is None else external_forces[lo + 1: hi + 1]
        r, v, a, length = body.kernel_window(state.r, state.v, state.a, rest_lengths[lo + 1: hi + 1], ext)
        rec.r[lo + 1: hi + 1], rec.v[lo + 1: hi + 1], rec.a[lo + 1: hi + 1] = r, v, a
        rec.length[lo + 1: hi + 1] = length
        rec.rest[lo + 1: hi + 1] = rest_lengths[lo + 1: hi + 1] if rest_lengths.dim() == 3 \
            else rest_lengths[lo + 1: hi + 1].unsqueeze(1)
        if ext is not None:
            rec.ext[lo + 1: hi + 1] = ext
        state = BodyState(r[-1], v[-1], a[-1], length[-1], state.step + hi - lo)
        if hi % check_every == 0 or hi == steps:
            _check_rows(body, rec, checked, hi, state)
            checked = hi + 1
        if progress is not None and (hi % PROGRESS_EVERY == 0 or hi == steps):
            progress(hi)
        lo = hi
    if steps == 0:
        _check_rows(body, rec, 0, 0, state)
    return rec.result(state)


def _run(
    body: MSDN,
    steps: int,
    state: BodyState,
    rest0: torch.Tensor,
    rest_at: Callable[[int, BodyState], torch.Tensor],
    ext: Sequence[torch.Tensor] | None,
    check_every: int,
    progress: Callable[[int], None] | None,
) -> Rollout:
    """The loop: row 0 = ``state`` with ``rest0``, ext[0]; step i uses ``rest_at(i, state_{i-1})`` and ext[i]."""
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    if check_every < 1:
        raise ValueError(f"check_every must be >= 1, got {check_every}")
    rec = _Recorder(steps, state, body.topology.n_springs)
    rec.put(0, state, rest0, None if ext is None else ext[0])
    checked = 0  # rows 0..checked-1 are known finite
    for i in range(1, steps + 1):
        rest = rest_at(i, state)
        force = None if ext is None else ext[i]
        state = body.step(state, rest, force)
        rec.put(i, state, rest, force)
        if i % check_every == 0 or i == steps:
            _check_rows(body, rec, checked, i, state)
            checked = i + 1
        if progress is not None and (i % PROGRESS_EVERY == 0 or i == steps):
            progress(i)
    if steps == 0:
        _check_rows(body, rec, 0, 0, state)
    return rec.result(state)


def _check_rows(body: MSDN, rec: _Recorder, first: int, last: int, state: BodyState) -> None:
    """Divergence check of rows first..last (``state`` is row last): on failure, the first bad row raises."""
    try:
        body.check_finite(state)
    except SimulationDiverged:
        offset = state.step - last
        for j in range(first, last + 1):
            body.check_finite(rec.state(j, offset + j))
        raise


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
    progress: Callable[[int], None] | None = None,
) -> Rollout:
    """Simulate an agent's open loop for ``steps`` steps (its commands, then :func:`simulate_commands`).

    Args:
        agent: SWG agents modulate rest lengths; LIL/MLP agents need ``inputs``.
        state: start state (its ``step`` sets the SWG clock); default: at rest at t = 0.
        inputs: (steps + 1,) per-step task input u for LIL/MLP agents (value in force at each step;
            already multiplied by the task's input scale), e.g. from :func:`held_inputs`.
        wind: (2,) constant force on every movable mass [N], or (steps + 1, 2) per step.
        displacement: (B, M, 2) initial displacement of the movable masses [m] when ``state`` is None.
        progress: called with the number of steps done every 100 steps and at the end.
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
    return simulate_commands(body, steps, rest, _add_wind(body, ext, wind, steps), state=state,
                             displacement=displacement, check_every=check_every, progress=progress)


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
    progress: Callable[[int], None] | None = None,
    handover: SineWaveGenerator | None = None,
    handover_steps: int = 0,
) -> Rollout:
    """Closed loop: the rest length at step k+1 is ``feedback.rest_length(body.l, state_k)``.

    The start state defaults to rest (base rest lengths, optionally displaced); row 0 records the
    base rest lengths. ``progress`` as in :func:`simulate_open_loop`.

    ``handover``: a transition period from this SWG to the FL (the paper's discussion): over the first
    ``handover_steps`` steps the control signal is (1 − α)·SWG(t) + α·FL(state), α = i / handover_steps
    rising linearly from 0 at the start to 1 (SWG clock from ``state.step``); then the FL alone.
    """
    ext = _add_wind(body, None, wind, steps)
    forces = None if ext is None else ext.unbind(0)
    if state is None:
        state = body.initial_state(
            1 if displacement is None else displacement.shape[0],
            external_force=None if forces is None else forces[0],
            displacement=displacement,
        )
    if handover is None or handover_steps <= 0:
        def rest_at(_i: int, prev: BodyState) -> torch.Tensor:
            return feedback.rest_length(body.l, prev)
    else:
        k0 = state.step

        def rest_at(i: int, prev: BodyState) -> torch.Tensor:
            alpha = min(i / handover_steps, 1.0)
            mix = alpha * feedback.signal(prev) + (1 - alpha) * handover.signal_at_steps([k0 + i], body.dt)
            return body.l * (1 + mix)
    return _run(body, steps, state, body.l.expand_as(state.length), rest_at, forces, check_every, progress)


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
