"""The update loop every training runs: measure, let the guard judge, step, carry on.

A training family (the trainer's tasks, Lissajous switching, closed-loop schemes 1–3, MNIST drawing and readout)
describes one update as an :class:`Objective`; a population of B same-topology trainings
(:mod:`bptsb_ros.workflows.population`) describes one update of all its members as a :class:`BatchedObjective`.
:class:`UpdateLoop` owns the :class:`~bptsb_ros.training.guard.UpdateGuard` of a training, or one per member of a
population (built here, nowhere else), and runs, for each update ``i``:

1. the scheduled rate divisions of update ``i`` (``decay_at``: the published step-decay schedule);
2. ``objective.measure(i)`` → :class:`Measured`: a loss tensor to back-propagate (autograd), or a loss value
   measured together with its gradients (the fused path), and the simulation's divergence message if any; a
   batched objective's ``measure(i, active)`` → one :class:`Measured` per member, each a value with its gradients
   (one backward for all the members still training);
3. every callback's ``on_measured(i, m)`` (:mod:`bptsb_ros.training.callbacks`: what happens between measuring
   and judging, e.g. marking the parameters as having completed a window);
4. each member's verdict by its own guard (:meth:`UpdateGuard.backward_and_review` for a tensor — it zeroes the
   gradients and back-propagates a finite loss —, :meth:`UpdateGuard.review` for a measured value): a rejection
   restores that member's parameters alone and divides that member's rates alone. A failure with nothing to undo
   raises :class:`LoopStopped` in a training alone; in a population the member stops (it is masked out of the
   later updates, its guard judges no more) and every callback's ``on_stopped(stop)`` hears of it, the others go
   on;
5. the step of the accepted: ``objective.step()`` when accepted (the optimiser's step and the projection onto
   θ ≥ 0, or the fused update); a batched objective's ``step(accepted)`` every update (the members' mask);
6. ``objective.advance(finite)``: carry the window's final state on only if it stayed finite (a batched
   objective: one flag per member);
7. every callback's ``on_update(i)`` (progress, checkpoints, saved states, epoch bookkeeping).

The loop imports no task, figure or file code: what a training does around its updates are callback objects.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

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
    """One update's measurement (of a training, or of one member of a population).

    ``loss``: a scalar tensor the loop back-propagates (autograd path), or None with ``fused`` True and ``value``
    the loss measured together with its gradients (``grads_finite``: they are finite) — the fused path, or a
    population's one backward for all its members. ``failure``: the simulation's divergence message (the loss is
    then not used).
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


class BatchedObjective(Protocol):
    """What a population of B trainings implements for :meth:`UpdateLoop.batched`: member b is one training."""

    def measure(self, update: int, active: Sequence[bool]) -> Sequence[Measured]:
        """Simulate and measure update ``update`` of every member: one :class:`Measured` per member, a value with
        its gradients (``fused``). ``active[b]``: member b still trains (a stopped member's gradients must not be
        computed, and its entry is not read)."""

    def step(self, accepted: Sequence[bool]) -> None:
        """Apply the update of the members ``accepted`` marks (called every update; the others keep their
        parameters)."""

    def advance(self, finite: Sequence[bool]) -> None:
        """After the verdicts: ``finite[b]``: member b still trains and its window stayed finite."""


class LoopStopped(RuntimeError):
    """A numerical failure the guard cannot undo (no update since the start or the last restore) stopped the loop
    at ``update`` — or, in a population, stopped ``member`` (None in a training alone); ``measured`` is that
    update's measurement and ``decision`` the guard's verdict."""

    def __init__(self, update: int, measured: Measured, decision: GuardDecision, member: int | None = None) -> None:
        who = "" if member is None else f"member {member}, "
        super().__init__(f"{who}update {update}: {measured.failure or decision.reason}; nothing to undo")
        self.update = update
        self.measured = measured
        self.decision = decision
        self.member = member

    def report(self, ranges: str) -> str:
        """The failure as a trainer reports it: the simulation's message, or the loss (or the verdict's reason) with
        the parameter ranges ``ranges``; then that the guard had nothing to undo."""
        m = self.measured
        why = m.failure or (f"loss is {m.value}" if self.decision.reason == "non-finite loss" else self.decision.reason)
        where = "" if m.failure else f"; {ranges}"
        return f"{why}{where}; the guard has nothing to undo (no update since the start or the last restore)"


class Callback:
    """A callback of :meth:`UpdateLoop.run` (ready-made ones: :mod:`bptsb_ros.training.callbacks`): every hook does
    nothing unless overridden."""

    def on_measured(self, update: int, measured: Any) -> None:
        """Update ``update`` was measured (``measured``: a :class:`Measured`, or a population's list of them); the
        guard has not judged it yet."""

    def on_stopped(self, stop: LoopStopped) -> None:
        """A member of a population stopped (``stop.member``, at ``stop.update``): its guard had nothing to undo.
        It is masked already; the others go on. (A training alone raises ``stop`` instead.)"""

    def on_update(self, update: int) -> None:
        """Update ``update`` is over (accepted or rejected: the loss curve has its entry)."""


class UpdateLoop:
    """The guarded update loop over ``optimizer``'s parameters.

    Args:
        optimizer: the training's optimiser (its groups' rates are what the guard and ``decay_at`` divide).
        rules: the guard's rules.
        modules: further modules the guard saves and restores with the parameters (e.g. a refitted FL).
        log: one line per rejection.

    :meth:`batched` builds the loop of a population instead: one guard per member.
    """

    def __init__(self, optimizer: torch.optim.Optimizer, rules: GuardRules = GuardRules(), *,
                 modules: Mapping[str, nn.Module] | None = None, log: Callable[[str], None] | None = None) -> None:
        self._setup([optimizer], rules, modules, [log], batched=False)

    @classmethod
    def batched(cls, optimizers: Sequence[Any], rules: GuardRules = GuardRules(), *,
                log: Callable[[int, str], None] | None = None) -> UpdateLoop:
        """The loop of a population: member b's guard over ``optimizers[b]`` (a torch optimiser, or what the guard
        handles as one: ``param_groups`` — views of the member's parameters, its rates — and ``state_dict`` /
        ``load_state_dict`` of its optimiser state), every member with the same ``rules``; ``log(b, line)``: one
        line per rejection of member b. Run it on a :class:`BatchedObjective`."""
        if not optimizers:
            raise ValueError("UpdateLoop.batched: a population needs at least one member (no optimisers given)")
        loop = cls.__new__(cls)
        logs = [None if log is None else (lambda line, b=b: log(b, line)) for b in range(len(optimizers))]
        loop._setup(list(optimizers), rules, None, logs, batched=True)
        return loop

    def _setup(self, optimizers: list[Any], rules: GuardRules, modules: Mapping[str, nn.Module] | None,
               logs: Sequence[Callable[[str], None] | None], *, batched: bool) -> None:
        self.optimizers = optimizers
        self.is_batched = batched
        #: the guard of each member (a training alone: one)
        self.guards = [UpdateGuard(opt, factor=rules.factor, patience=rules.patience, window=rules.window,
                                   modules=modules, log=log) for opt, log in zip(optimizers, logs)]
        #: the members still training (a population's stopped members are False)
        self.active = [True] * len(optimizers)

    @property
    def guard(self) -> UpdateGuard:
        """The guard of a training alone (a population's loop has one per member: :attr:`guards`)."""
        self._alone("guard")
        return self.guards[0]

    @property
    def losses(self) -> list[float]:
        """The loss curve of a training alone: the guard's history (a rejected update repeats the previous
        entry)."""
        self._alone("losses")
        return self.guards[0].history

    def _alone(self, what: str) -> None:
        if self.is_batched:
            raise AttributeError(f"UpdateLoop.{what} is a training alone's; a population's loop has one per member "
                                 "(guards[b], guards[b].history)")

    def run(self, objective: Objective | BatchedObjective, updates: Iterable[int], *,
            decay_at: Sequence[int] | set[int] = (), callbacks: Sequence[Callback] = ()) -> None:
        """Run ``updates`` (their indices, e.g. ``range(start, total)``) with ``callbacks`` called in their order;
        a training alone raises :class:`LoopStopped`."""
        decays = list(decay_at)
        batched = self.is_batched
        _check_objective(objective, batched)
        for i in updates:
            for _ in range(decays.count(i)):
                for optimizer in self.optimizers:
                    divide_rates_(optimizer, 10.0)
            if batched:
                measured: Any = objective.measure(i, self.active)  # type: ignore[call-arg]
                members = measured
            else:
                measured = objective.measure(i)  # type: ignore[call-arg]
                members = (measured,)
            for callback in callbacks:
                callback.on_measured(i, measured)
            accepted = [False] * len(self.guards)
            for b in [b for b, live in enumerate(self.active) if live]:
                m = members[b]
                guard = self.guards[b]
                if m.fused:
                    decision = guard.review(i, m.value, grads_finite=m.grads_finite, diverged=m.failure)
                else:
                    decision = guard.backward_and_review(i, m.loss, diverged=m.failure)
                if decision.stop:
                    stop = LoopStopped(i, m, decision, member=b if batched else None)
                    if not batched:
                        raise stop
                    self.active[b] = False
                    for callback in callbacks:
                        callback.on_stopped(stop)
                accepted[b] = decision.accepted
            if batched:
                objective.step(accepted)  # type: ignore[call-arg]
                objective.advance([live and m.failure is None  # type: ignore[arg-type]
                                   for live, m in zip(self.active, members)])
            else:
                if accepted[0]:
                    objective.step()  # type: ignore[call-arg]
                objective.advance(measured.failure is None)  # type: ignore[arg-type]
            for callback in callbacks:
                callback.on_update(i)


def _check_objective(objective: Any, batched: bool) -> None:
    """One line when ``objective`` does not fit the loop: a population's loop measures ``measure(i, active)``, a
    training alone's ``measure(i)``."""
    import inspect

    try:
        arity = len(inspect.signature(objective.measure).parameters)
    except (AttributeError, TypeError, ValueError):
        raise TypeError(f"UpdateLoop.run: {type(objective).__name__} has no measure() method") from None
    if arity != (2 if batched else 1):
        want = "a BatchedObjective, measure(update, active)" if batched else "an Objective, measure(update)"
        raise TypeError(f"UpdateLoop.run: this loop runs {want}; {type(objective).__name__}.measure takes {arity} "
                        "arguments")
