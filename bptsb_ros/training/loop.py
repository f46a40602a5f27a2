"""The update loop every single-agent training runs: measure, let the guard judge, step, carry on.

A training family (the trainer's tasks, Lissajous switching, closed-loop schemes 1–3, MNIST drawing and readout)
describes one update as an :class:`Objective`; :class:`UpdateLoop` owns the
:class:`~bptsb_ros.training.guard.UpdateGuard` (built here and, for each member of a population, in
:mod:`bptsb_ros.workflows.population`: nowhere else) and runs, for each update ``i``:

1. the scheduled rate divisions of update ``i`` (``decay_at``: the published step-decay schedule);
2. ``objective.measure(i)`` → :class:`Measured`: a loss tensor to back-propagate (autograd), or a loss value
   measured together with its gradients (the fused path), and the simulation's divergence message if any;
3. every callback's ``on_measured(i, m)`` (:mod:`bptsb_ros.training.callbacks`: what happens between measuring
   and judging, e.g. marking the parameters as having completed a window);
4. the guard's verdict (:meth:`UpdateGuard.backward_and_review` for a tensor — it zeroes the gradients and
   back-propagates a finite loss —, :meth:`UpdateGuard.review` for a measured value); a failure with nothing to
   undo raises :class:`LoopStopped`;
5. accepted: ``objective.step()`` (the optimiser's step and the projection onto θ ≥ 0, or the fused update);
6. ``objective.advance(finite)``: carry the window's final state on only if it stayed finite;
7. every callback's ``on_update(i)`` (progress, checkpoints, epoch bookkeeping).

The loop imports no task, figure or file code: what a training does around its updates are callback objects.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import torch
from torch import nn

from bptsb_ros.training.guard import FACTOR, PATIENCE, WINDOW, GuardDecision, UpdateGuard
from bptsb_ros.training.optim import divide_rates_


@dataclass(frozen=True)
class GuardRules:
    """The guard's rules for one training (see :mod:`bptsb_ros.training.guard`): the spike ``factor`` (0: numerical
    failures only), the rejections before a rate division (``patience``) and the reference ``window``."""

    factor: float = FACTOR
    patience: int = PATIENCE
    window: int = WINDOW


@dataclass
class Measured:
    """One update's measurement.

    ``loss``: a scalar tensor the loop back-propagates (autograd path), or None with ``fused`` True and ``value``
    the loss measured together with its gradients (``grads_finite``: they are finite). ``failure``: the
    simulation's divergence message (the loss is then not used).
    """

    loss: torch.Tensor | None = None
    value: float | None = None
    grads_finite: bool = True
    failure: str | None = None
    fused: bool = False


class Objective(Protocol):
    """What a training family implements for :class:`UpdateLoop`."""

    def measure(self, update: int) -> Measured:
        """Simulate and measure update ``update`` with the current parameters."""

    def step(self) -> None:
        """Apply the accepted update: the optimiser's step and the projection (or the fused update)."""

    def advance(self, finite: bool) -> None:
        """After the verdict: carry the measured window's final state on if it stayed ``finite``."""


class Callback:
    """A callback of :meth:`UpdateLoop.run` (ready-made ones: :mod:`bptsb_ros.training.callbacks`): both hooks do
    nothing unless overridden."""

    def on_measured(self, update: int, measured: Measured) -> None:
        """Update ``update`` was measured (``measured``); the guard has not judged it yet."""

    def on_update(self, update: int) -> None:
        """Update ``update`` is over (accepted or rejected: the loss curve has its entry)."""


class LoopStopped(RuntimeError):
    """A numerical failure the guard cannot undo (no update since the start or the last restore) stopped the loop
    at ``update``; ``measured`` is that update's measurement and ``decision`` the guard's verdict."""

    def __init__(self, update: int, measured: Measured, decision: GuardDecision) -> None:
        super().__init__(f"update {update}: {measured.failure or decision.reason}; nothing to undo")
        self.update = update
        self.measured = measured
        self.decision = decision


class UpdateLoop:
    """The guarded update loop over ``optimizer``'s parameters.

    Args:
        optimizer: the training's optimiser (its groups' rates are what the guard and ``decay_at`` divide).
        rules: the guard's rules.
        modules: further modules the guard saves and restores with the parameters (e.g. a refitted FL).
        log: one line per rejection.
    """

    def __init__(self, optimizer: torch.optim.Optimizer, rules: GuardRules = GuardRules(), *,
                 modules: Mapping[str, nn.Module] | None = None, log: Callable[[str], None] | None = None) -> None:
        self.optimizer = optimizer
        self.guard = UpdateGuard(optimizer, factor=rules.factor, patience=rules.patience, window=rules.window,
                                 modules=modules, log=log)

    @property
    def losses(self) -> list[float]:
        """The loss curve: the guard's history (a rejected update repeats the previous entry)."""
        return self.guard.history

    def run(self, objective: Objective, updates: Iterable[int], *, decay_at: Sequence[int] | set[int] = (),
            callbacks: Sequence[Callback] = ()) -> None:
        """Run ``updates`` (their indices, e.g. ``range(start, total)``) with ``callbacks`` called in their order;
        raises :class:`LoopStopped`."""
        decays = list(decay_at)
        for i in updates:
            for _ in range(decays.count(i)):
                divide_rates_(self.optimizer, 10.0)
            m = objective.measure(i)
            for callback in callbacks:
                callback.on_measured(i, m)
            if m.fused:
                decision = self.guard.review(i, m.value, grads_finite=m.grads_finite, diverged=m.failure)
            else:
                decision = self.guard.backward_and_review(i, m.loss, diverged=m.failure)
            if decision.stop:
                raise LoopStopped(i, m, decision)
            if decision.accepted:
                objective.step()
            objective.advance(m.failure is None)
            for callback in callbacks:
                callback.on_update(i)
