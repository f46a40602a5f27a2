"""Lissajous switching by wind (paper, supplement "Behavioral switching" and "Switching timing").

A trained single-curve SWG agent gets additional BPTSB training in which a binary wind F_wind ∈ {0, 1}
(a constant force in +x on every movable mass) blows on and off at random times; without wind the target
is curve 1, with wind curve 2, displaced in x ("The target trajectory was displaced in the x-direction when
there was wind"; the paper gives no amount: :func:`wind_offset` uses the CMP's mean x shift that the wind
itself causes in the trained single-curve agent).

Switch times (supplement, Eq. for t_wind): t_wind = t0 + (2π/ω)·n/100 with n ∈ [0, 99]: each wind segment
lasts a whole number of periods drawn from ``hold_periods`` plus n/100 of a period; ``timing="random"``
draws n afresh at every switch, ``timing="fixed"`` uses n = 0.

Wind force: the paper's (F_wind, 0) [N]. ``published=True`` gives what the authors' published code did:
(15·F_wind, +1), a constant +1 N upward whenever wind is enabled (see published-code-facts.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.clock import step_times
from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.config import LearningRates, TrainingConfig
from bptsb_ros.sim.batched import wind_force
from bptsb_ros.sim.rollout import swg_rest_lengths
from bptsb_ros.training.callbacks import EveryUpdate
from bptsb_ros.training.loop import GuardRules, LoopStopped, Measured, UpdateLoop
from bptsb_ros.training.optim import make_optimizer, step_decay_updates

#: the paper's learning rates for switching (supplementary table, "Lissajous curves (switching)")
SWITCHING_LR = LearningRates(k=1e3, d=1e2, l=1e0, amplitude=1e0, phase=1e1)
#: the published code's wind magnitude while the second curve was active
PUBLISHED_WIND = 15.0


@dataclass(frozen=True)
class Curve:
    """A Lissajous curve x = X cos(α ω t), y = Y sin(β ω t + δ)."""

    alpha: float
    beta: float
    delta: float

    def __str__(self) -> str:
        d = self.delta / math.pi
        ds = "0" if d == 0 else ("π" if d == 1 else f"{d:g}π")
        return f"({self.alpha:g},{self.beta:g},{ds})"

    def target(self, t: np.ndarray | torch.Tensor, amplitude: float, omega: float,
               shift_x: float = 0.0) -> np.ndarray | torch.Tensor:
        """(T, 2) target [m] at times t (T,) [s], displaced by ``shift_x`` [m] in x."""
        lib = torch if isinstance(t, torch.Tensor) else np
        return lib.stack([amplitude * lib.cos(self.alpha * omega * t) + shift_x,
                          amplitude * lib.sin(self.beta * omega * t + self.delta)], -1)


CURVE_1 = Curve(1, 2, 0.0)
CURVE_SWITCH = Curve(2, 1, math.pi / 2)
CURVE_TIMING = Curve(1, 3, 0.0)


def wind_vector(f_wind: np.ndarray | torch.Tensor | float, *, published: bool = False) -> torch.Tensor:
    """F_wind (...) → force (..., 2) [N] on every movable mass: (F, 0), or the published (15·F, 1)."""
    f = torch.as_tensor(f_wind, dtype=torch.float64)
    if published:
        return torch.stack([PUBLISHED_WIND * f, torch.ones_like(f)], -1)
    return torch.stack([f, torch.zeros_like(f)], -1)


def switch_targets(curve_off: Curve, curve_on: Curve, amplitude: float, omega: float, shift_x: float):
    """target(t (T,), wind (T,)) → (T, 2): curve_off without wind, curve_on displaced by shift_x with wind."""

    def target(t, wind):
        off = curve_off.target(t, amplitude, omega)
        on = curve_on.target(t, amplitude, omega, shift_x)
        w = wind[:, None] > 0.5
        return torch.where(w, on, off) if isinstance(t, torch.Tensor) else np.where(w, on, off)

    return target


@torch.no_grad()
def wind_offset(agent: Agent, state: BodyState, f_wind: float = 1.0, periods: int = 10, *,
                published: bool = False) -> float:
    """Mean x shift [m] of the CMP caused by a constant wind: mean CMP x over ``periods`` periods with the
    wind minus without (both after ``periods`` periods of transient), the trained open loop from ``state``."""
    from bptsb_ros.sim.batched import run_population

    body = agent.body
    steps = 2 * periods * int(round(2 * math.pi / agent.brain.omega / body.dt))
    batch = BodyState(*(x.expand(2, *x.shape[1:]) for x in (state.r, state.v, state.a, state.length)), state.step)
    wind = wind_vector(torch.tensor([0.0, f_wind]), published=published).to(body.l.dtype)
    pop = run_population(body, steps, batch, swg=agent.brain, wind=wind)
    x = pop.tracked[steps // 2:, :, 0, 0].double()
    return float(x[:, 1].mean() - x[:, 0].mean())


@dataclass
class SwitchingTraining:
    """losses: one per update (a rejected update repeats the previous entry); guard: the guard's summary."""

    losses: list[float]
    state: BodyState
    schedule: np.ndarray
    guard: dict[str, Any] = field(default_factory=dict)
    #: the spring-stiffness learning rate in force at each update (the ÷10 schedule and the guard's cuts show here)
    lr_k: list[float] = field(default_factory=list)


def train_switching(agent: Agent, state: BodyState, schedule: np.ndarray,
                    target: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], *,
                    lr: LearningRates = SWITCHING_LR, window: int = 100, published_wind: bool = False,
                    reject_factor: float = 0.0, backend: str | None = None, lr_decay: bool = False,
                    lr_decay_min_updates: int = 1000,
                    progress: Callable[[int, int, float], None] | None = None) -> SwitchingTraining:
    """Additional BPTSB training of an SWG agent under a wind schedule (in place; SGD, truncated windows).

    schedule: (steps + 1,) F_wind in force at steps state.step .. state.step + steps; the number of updates
    is steps // window. target(t (W,), wind (W,)) → (W, 2) CMP target [m]. Returns the loss of every update
    and the final state (to continue from).

    Every update goes through the :class:`~bptsb_ros.training.guard.UpdateGuard` (a diverged window or a
    non-finite loss or gradient undoes the previous update; the window's state is carried on only if finite).
    ``reject_factor`` 0 (default): no spike rule — the target switches curves with the wind, so a jump of the
    loss is expected here, and the authors' Lissajous training had none.

    ``backend``: ``fused`` runs each window, its loss and gradients as one compiled call and the update as another
    (:mod:`bptsb_ros.training.fused`; equal to rounding); anything else, the autograd path with the body's
    backend. Default: the agent's ``training.backend``.

    ``lr_decay``: the published code's schedule: when there are more than ``lr_decay_min_updates`` updates
    (windows), every learning rate is divided by 10 at update ``int(0.8·updates)`` and again at ``int(0.9·updates)``
    (:func:`~bptsb_ros.training.optim.step_decay_updates`), on top of any cut by the guard.

    Raises:
        SimulationDiverged: a failure the guard cannot undo (no update since the start or the last restore).
    """
    body, swg = agent.body, agent.brain
    for module in agent.modules().values():
        module.requires_grad_(True)
    if agent.feedback is not None:
        agent.feedback.requires_grad_(False)
    opt = make_optimizer(agent, TrainingConfig(lr=lr, update_steps=window))
    loop = UpdateLoop(opt, GuardRules(factor=reject_factor))
    dtype = body.l.dtype
    forces = wind_force(body, wind_vector(torch.as_tensor(schedule), published=published_wind).to(dtype))  # (S+1, M, 2)
    updates = (len(schedule) - 1) // window
    if backend is None:
        backend = str(agent.config.get("training", {}).get("backend", "numba"))
    fused = None
    if backend == "fused":
        from bptsb_ros.training.fused import FusedSwgWindow, GivenTargetLoss

        fused = FusedSwgWindow(body, swg, opt, window, GivenTargetLoss(body.cmp_local))
    decay_at = step_decay_updates(updates, min_updates=lr_decay_min_updates) if lr_decay else []
    objective = _SwitchingWindows(agent, opt, state, schedule, forces, target, window, fused)
    try:
        loop.run(objective, range(updates), decay_at=decay_at, callbacks=() if progress is None else
                 (EveryUpdate(lambda u: progress(u + 1, updates, loop.losses[-1])),))
    except LoopStopped as stop:
        for module in agent.modules().values():
            module.requires_grad_(False)
        raise SimulationDiverged(f"switching update {stop.update}: {stop.measured.failure or stop.decision.reason}; "
                                 "nothing to undo") from None
    for module in agent.modules().values():
        module.requires_grad_(False)
    return SwitchingTraining(loop.losses, objective.state, schedule, loop.guard.summary(), objective.lr_k)


class _SwitchingWindows:
    """The switching training's update (an :class:`~bptsb_ros.training.loop.Objective`): the next window under
    the schedule's wind, its target switching curves with the wind; on the autograd path or fused."""

    def __init__(self, agent: Agent, opt: torch.optim.Optimizer, state: BodyState, schedule: np.ndarray,
                 forces: torch.Tensor, target: Callable, window: int, fused: Any) -> None:
        self.agent, self.opt, self.schedule, self.forces = agent, opt, schedule, forces
        self.target, self.window, self.fused = target, window, fused
        self.k_start = state.step
        self.state = state.detach()
        self.final: BodyState | None = None
        self.lr_k: list[float] = []  # the k group's rate at every update (after the scheduled divisions)
        self.k_group = next((g for g in opt.param_groups if g.get("name") == "k"), opt.param_groups[0])

    def measure(self, update: int) -> Measured:
        del update
        body, swg, window, state = self.agent.body, self.agent.brain, self.window, self.state
        dtype = body.l.dtype
        self.lr_k.append(float(self.k_group["lr"]))
        first = state.step + 1
        rel = first - self.k_start
        ext = self.forces[rel:rel + window].unsqueeze(1)  # (W, 1, M, 2)
        t = step_times(first, window, body.dt)  # float64: the target's phase stays exact at large t
        wind = torch.as_tensor(self.schedule[rel:rel + window], dtype=dtype)
        if self.fused is None:
            rest = swg_rest_lengths(body, swg, first, window)
            win = rollout_window(body, state, rest, ext)
            loss = ((win.r[:, 0, body.cmp_local] - self.target(t, wind).to(dtype)) ** 2).mean()
            self.final = win.final.detach()
            failure = None
            try:
                body.check_finite(self.final)
            except SimulationDiverged as err:
                failure = str(err)
            return Measured(loss, failure=failure)
        # the window, loss and gradients in one compiled call
        self.fused.set_inputs(self.target(t, wind), ext)
        value, grads_ok, self.final, failure = self.fused.run(state)
        self.opt.zero_grad(set_to_none=True)  # as backward_and_review: no stale gradients
        return Measured(value=value, grads_finite=grads_ok, failure=failure, fused=True)

    def step(self) -> None:
        if self.fused is None:
            self.opt.step()
            self.agent.body.clamp_parameters_()
        else:
            self.fused.step()

    def advance(self, finite: bool) -> None:
        if finite:
            self.state = self.final
