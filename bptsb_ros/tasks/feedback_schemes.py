"""Simultaneous training for a closed loop (paper, supplement "Simultaneous training for a closed loop"):
three ways to train the feedback layer (FL) together with the body, on the Lissajous task.

* Scheme 1: no SWG; the closed loop (body + FL, rest length l·(1 + W·[s_k, 1])) is trained from scratch by
  BPTSB, the FL starting from random weights. Gradients flow through the feedback (plain autograd: the rest
  length depends on the state, which the hand-derived window adjoint does not cover).
* Scheme 2: after the preliminary SWG training and one regression of the FL, the SWG, the body and the FL
  (still open loop: the SWG drives the body) are trained by BPTSB with L = L_traj + α·L_FB, α = 0.1, where
  L_FB is the MSE between the FL's output from the state at step k and the SWG's signal at step k+1; then the
  loop is closed.
* Scheme 3: after the preliminary training, the SWG and the body are trained by BPTSB on L_traj, and the FL
  is re-fitted by ridge regression (input noise σ as in the FL fit) after every update, on the states of the
  last ``fit_windows`` windows; then the loop is closed.

Learning rates: the paper's "Lissajous curves (closed-loop)" row (k 1e4, d 1e3, l 1e0, A 1e0, φ 1e1); the
paper gives none for the FL weights: :data:`FL_LR` (our choice, stated in the results).

Every update goes through the :class:`~bptsb_ros.training.guard.UpdateGuard`: a diverged window, a non-finite loss
or gradient (or, with ``reject_factor`` > 0, a loss spike) undoes the previous update (parameters, optimiser state
and, in scheme 3, the fitted FL), the window's body state is carried on only if it stayed finite, and five
rejections divide every rate by 10. The authors' Lissajous trainings had no spike rule: ``reject_factor`` is 0 by
default. A failure the guard cannot undo stops the scheme (``SchemeTraining.diverged``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.clock import step_times
from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.brains import fit_ridge
from bptsb_ros.config import LearningRates, TrainingConfig
from bptsb_ros.sim.rollout import swg_rest_lengths
from bptsb_ros.training.loop import GuardRules, LoopStopped, Measured, UpdateLoop
from bptsb_ros.training.optim import make_optimizer

#: the paper's learning rates for the closed-loop schemes (supplementary table, "Lissajous curves (closed-loop)")
CLOSED_LOOP_LR = LearningRates(k=1e4, d=1e3, l=1e0, amplitude=1e0, phase=1e1)
#: learning rate of the FL weights in schemes 1 and 2 (not in the paper's table)
FL_LR = 1e0
#: the weight α of L_FB in scheme 2 (paper: 0.1)
ALPHA_FB = 0.1

Target = Callable[[torch.Tensor], torch.Tensor]  # times (W,) [s] → (W, 2) [m]


@dataclass
class SchemeTraining:
    """losses: one per update done (a rejected update repeats the previous entry); diverged: the update at which
    the simulation, the loss or the gradients failed with nothing for the guard to undo (training stopped there;
    the agent holds the parameters of the last accepted update), or None; guard: the guard's summary."""

    losses: list[float]
    state: BodyState
    diverged: int | None = None
    guard: dict[str, Any] = field(default_factory=dict)


def _optimizer(agent: Agent, lr: LearningRates, with_swg: bool, with_fl: bool) -> torch.optim.Optimizer:
    for module in agent.modules().values():
        module.requires_grad_(False)
    agent.body.requires_grad_(True)
    if with_swg:
        agent.brain.requires_grad_(True)
    if with_fl:
        agent.feedback.requires_grad_(True)
    opt = make_optimizer(agent, TrainingConfig(lr=lr)) if with_swg else torch.optim.SGD(
        [{"params": [agent.body.k], "lr": lr.k}, {"params": [agent.body.d], "lr": lr.d},
         {"params": [agent.body.l], "lr": lr.l}], lr=lr.k)
    if not with_swg:  # the SWG stays frozen
        agent.brain.requires_grad_(False)
    if with_fl:
        opt.add_param_group({"params": [agent.feedback.weight], "lr": FL_LR})
    return opt


def _divergence(body, state: BodyState) -> str | None:
    """None when the state is finite and bounded, else the simulation's error message."""
    try:
        body.check_finite(state.detach())
    except SimulationDiverged as err:
        return str(err)
    return None


def _finish(agent: Agent) -> None:
    for module in agent.modules().values():
        module.requires_grad_(False)


class _SchemeWindow:
    """One scheme's update as an :class:`~bptsb_ros.training.loop.Objective`: ``window_loss(state)`` → (loss, final
    state) of the window from ``state``; the window's final state is carried on only if it stayed finite."""

    def __init__(self, agent: Agent, opt: torch.optim.Optimizer, state: BodyState,
                 window_loss: Callable[[BodyState], tuple[torch.Tensor, BodyState]],
                 before_step: Callable[[BodyState], None] | None = None,
                 after_step: Callable[[], None] | None = None) -> None:
        self.agent, self.opt, self.state = agent, opt, state
        self.window_loss, self.before_step, self.after_step = window_loss, before_step, after_step
        self.final: BodyState | None = None

    def measure(self, update: int) -> Measured:
        del update
        loss, self.final = self.window_loss(self.state)
        return Measured(loss, failure=_divergence(self.agent.body, self.final))

    def step(self) -> None:
        if self.before_step is not None:
            self.before_step(self.state)
        self.opt.step()
        self.agent.body.clamp_parameters_()
        if self.after_step is not None:
            self.after_step()

    def advance(self, finite: bool) -> None:
        if finite:
            self.state = self.final.detach()


def _run_scheme(agent: Agent, objective: _SchemeWindow, updates: int, reject_factor: float,
                modules: dict[str, torch.nn.Module] | None = None) -> SchemeTraining:
    loop = UpdateLoop(objective.opt, GuardRules(factor=reject_factor), modules=modules)
    diverged = None
    try:
        loop.run(objective, range(updates))
    except LoopStopped as stop:
        diverged = stop.update
    _finish(agent)
    return SchemeTraining(loop.losses, objective.state, diverged, loop.guard.summary())


def train_scheme1(agent: Agent, target: Target, updates: int, *, window: int = 100, lr: LearningRates = CLOSED_LOOP_LR,
                  init_std: float = 0.1, seed: int = 0, reject_factor: float = 0.0) -> SchemeTraining:
    """Scheme 1: closed loop from scratch; the FL starts from W ~ N(0, init_std²) (bias included) on the springs the
    SWG drives, and zero on the others. The FL stands in for the SWG, so it drives no spring the SWG does not: its
    ``driven`` mask becomes its own AND the SWG's (the masked rows get no gradient, so they stay zero)."""
    body, fb = agent.body, agent.feedback
    with torch.no_grad():
        fb.driven.logical_and_(agent.brain.driven)
        fb.weight.normal_(0.0, init_std, generator=torch.Generator().manual_seed(seed))
        fb.weight.mul_(fb.driven.unsqueeze(-1))
    opt = _optimizer(agent, lr, with_swg=False, with_fl=True)

    def window_loss(state: BodyState) -> tuple[torch.Tensor, BodyState]:
        cmp = []
        s = state
        for _i in range(window):
            s = body.step(s, fb.rest_length(body.l, s))
            cmp.append(s.r[0, body.cmp_local])
        t = step_times(state.step + 1, window, body.dt)  # float64: the target's phase stays exact
        return ((torch.stack(cmp) - target(t).to(body.l.dtype)) ** 2).mean(), s

    return _run_scheme(agent, _SchemeWindow(agent, opt, body.initial_state(1).detach(), window_loss), updates,
                       reject_factor)


def train_scheme2(agent: Agent, state: BodyState, target: Target, updates: int, *, window: int = 100,
                  lr: LearningRates = CLOSED_LOOP_LR, alpha: float = ALPHA_FB,
                  reject_factor: float = 0.0) -> SchemeTraining:
    """Scheme 2: BPTSB through SWG + body + FL (open loop), L = L_traj + α·L_FB; the FL as fitted before."""
    body, swg, fb = agent.body, agent.brain, agent.feedback
    opt = _optimizer(agent, lr, with_swg=True, with_fl=True)

    def window_loss(state: BodyState) -> tuple[torch.Tensor, BodyState]:
        first = state.step + 1
        rest = swg_rest_lengths(body, swg, first, window)
        win = rollout_window(body, state, rest)
        t = step_times(first, window, body.dt)
        l_traj = ((win.r[:, 0, body.cmp_local] - target(t).to(body.l.dtype)) ** 2).mean()
        # the FL's output from the state at step k against the SWG signal in force at step k+1
        lengths = torch.cat([state.length, win.length[:-1, 0]])  # (W, E): steps first−1 .. first+W−2
        l_fb = ((fb.signal_from_features(lengths) - swg.signal_at_steps(torch.arange(first, first + window), body.dt))
                ** 2).mean()
        return l_traj + alpha * l_fb, win.final

    return _run_scheme(agent, _SchemeWindow(agent, opt, state.detach(), window_loss), updates, reject_factor)


def train_scheme3(agent: Agent, state: BodyState, target: Target, updates: int, *, window: int = 100,
                  lr: LearningRates = CLOSED_LOOP_LR, noise: float = 0.08, fit_windows: int = 10,
                  seed: int = 0, reject_factor: float = 0.0) -> SchemeTraining:
    """Scheme 3: BPTSB on SWG + body (L_traj), the FL re-fitted by ridge regression after every accepted update on
    the last ``fit_windows`` accepted windows' (state k, SWG signal k+1) pairs with input noise σ = ``noise``."""
    body, swg, fb = agent.body, agent.brain, agent.feedback
    opt = _optimizer(agent, lr, with_swg=True, with_fl=False)
    rng = np.random.default_rng(seed)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    lengths: list[torch.Tensor] = []  # the measured window's lengths (W, 1, E), for the refit

    def window_loss(state: BodyState) -> tuple[torch.Tensor, BodyState]:
        first = state.step + 1
        rest = swg_rest_lengths(body, swg, first, window)
        win = rollout_window(body, state, rest)
        t = step_times(first, window, body.dt)
        lengths[:] = [win.length]
        return ((win.r[:, 0, body.cmp_local] - target(t).to(body.l.dtype)) ** 2).mean(), win.final

    def keep_pairs(state: BodyState) -> None:  # before the step: the SWG signal of the parameters just measured
        first = state.step + 1
        with torch.no_grad():
            xs.append(torch.cat([state.length, lengths[0][:-1, 0]]).double().numpy())
            ys.append(swg.signal_at_steps(torch.arange(first, first + window), body.dt).double().numpy())

    def refit() -> None:
        nonlocal xs, ys
        xs, ys = xs[-fit_windows:], ys[-fit_windows:]
        x = np.concatenate(xs)
        weights, _ = fit_ridge(x + noise * rng.standard_normal(x.shape), np.concatenate(ys))
        fb.load_fit(weights)

    objective = _SchemeWindow(agent, opt, state.detach(), window_loss, keep_pairs, refit)
    return _run_scheme(agent, objective, updates, reject_factor, modules={"feedback": fb})  # a restore brings the FL
