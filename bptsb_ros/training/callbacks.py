"""What a training does around its updates, as objects :class:`~bptsb_ros.training.loop.UpdateLoop` calls: progress,
the caller's per-update function, the last-good checkpoints, a state saved every so many seconds. Training code
never imports a task's or a figure's module to do these; a family (or a population) passes the callbacks it wants
to :meth:`UpdateLoop.run`.

Each callback may implement :meth:`Callback.on_measured` (after an update's measurement, before the guard's
verdict), :meth:`Callback.on_stopped` (a population's member stopped) and :meth:`Callback.on_update` (after the
update, accepted or rejected); the loop calls them in the order given.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from bptsb_ros.training.checkpoint import save_checkpoint
from bptsb_ros.training.guard import UpdateGuard, copy_state
from bptsb_ros.training.loop import Callback, Measured

__all__ = ["Callback", "EveryUpdate", "LastGoodCheckpoints", "LossCallback", "Periodically", "ProgressBar",
           "SimSteps", "optimizer_and_task_state"]


class EveryUpdate(Callback):
    """``fn(update)`` after every update."""

    def __init__(self, fn: Callable[[int], None]) -> None:
        self.fn = fn

    def on_update(self, update: int) -> None:
        self.fn(update)


class SimSteps(Callback):
    """Counts the simulated steps: ``per_update`` for every update measured."""

    def __init__(self, per_update: int) -> None:
        self.per_update, self.steps = per_update, 0

    def on_measured(self, update: int, measured: Measured) -> None:
        self.steps += self.per_update


class LossCallback(Callback):
    """``fn(update, loss)`` after every update, ``loss`` the update's entry of the loss curve ``losses``."""

    def __init__(self, fn: Callable[[int, float], None], losses: list[float]) -> None:
        self.fn, self.losses = fn, losses

    def on_update(self, update: int) -> None:
        self.fn(update, float(self.losses[-1]))


class ProgressBar(Callback):
    """A tqdm bar on stderr over ``total`` updates, starting at ``start``, the loss every ``log_every`` updates; a
    line every ``quiet_every_s`` (10 s) instead of a live bar when stderr is not a terminal; nothing when not
    ``enabled``. ``losses``: the loss curve (its last entry is shown), or a function giving the loss to show (None:
    none, e.g. a population's median over the members still training); ``refresh``: show it at once (False: at
    the bar's next timed refresh)."""

    def __init__(self, total: int, title: str, losses: list[float] | Callable[[], float | None], *, enabled: bool,
                 start: int = 0, log_every: int = 1, quiet_every_s: float = 10.0, refresh: bool = True) -> None:
        from tqdm import tqdm

        interactive = sys.stderr.isatty()
        self.bar = tqdm(total=total, desc=title, unit="upd", dynamic_ncols=interactive, disable=not enabled,
                        file=sys.stderr, mininterval=0.1 if interactive else quiet_every_s)
        self.bar.update(start)
        self.losses, self.log_every, self.refresh = losses, max(1, log_every), refresh

    def write(self, line: str) -> None:
        """A line above the bar (the guard's rejections)."""
        self.bar.write(line, file=sys.stderr)

    def on_update(self, update: int) -> None:
        self.bar.update(1)
        if update % self.log_every == 0:
            loss = self.losses() if callable(self.losses) else self.losses[-1]
            if loss is not None:
                self.bar.set_postfix(loss=f"{loss:.4g}", refresh=self.refresh)

    def close(self) -> None:
        self.bar.close()


class Periodically(Callback):
    """``fn(update)`` after an update once ``every_s`` wall seconds have passed since the start (the callback's
    creation, or ``since``, a :func:`time.perf_counter` reading) or since the last call (e.g. saving a long
    training's state)."""

    def __init__(self, every_s: float, fn: Callable[[int], None], *, since: float | None = None) -> None:
        self.every_s, self.fn = every_s, fn
        self.last = time.perf_counter() if since is None else since

    def on_update(self, update: int) -> None:
        if time.perf_counter() - self.last >= self.every_s:
            self.fn(update)
            self.last = time.perf_counter()


class LastGoodCheckpoints(Callback):
    """Checkpoints of parameters that completed a simulation window without diverging.

    Before each update it snapshots what is about to be simulated (``pending``); once that update's loss came back
    finite, the snapshot is ``good``. A checkpoint due every ``every`` updates is written when the next good one
    exists, so a checkpoint never holds parameters that blew the body up; :meth:`save_good` writes the last good one
    (a training that diverged keeps it). ``modules``: the agent's modules; ``extra()``: the optimiser's and task's
    state to save besides; ``guard``: the training's guard (its loss history and state go with each checkpoint).
    In memory (``run_dir`` None) nothing is kept or written.
    """

    def __init__(self, run_dir: Path | None, agent: Any, modules: Callable[[], Mapping[str, nn.Module]],
                 extra: Callable[[], dict[str, Any]], guard: UpdateGuard, *, start: int, every: int) -> None:
        self.run_dir, self.agent, self.modules, self.extra, self.guard = run_dir, agent, modules, extra, guard
        self.every = every
        self.pending = self.snapshot(start)
        self.good: dict[str, Any] | None = None
        self.due = False

    def snapshot(self, update: int) -> dict[str, Any] | None:
        """What a checkpoint at ``update`` holds: the tensors copied (later updates change them in place), the loss
        history and the guard by :meth:`UpdateGuard.mark` (they only grow: copying them every update made training
        quadratic in its length); None in memory."""
        if self.run_dir is None:
            return None
        return {"modules": copy_state({name: m.state_dict() for name, m in self.modules().items()}),
                "extra": copy_state({**self.extra(), "update": update}), "guard": self.guard.mark()}

    def write(self, snap: dict[str, Any]) -> None:
        assert self.run_dir is not None
        state = self.guard.state_at(snap["guard"])
        save_checkpoint(self.run_dir, self.agent, {**snap["extra"], "losses": list(state["history"]), "guard": state},
                        modules=snap["modules"])

    @property
    def good_update(self) -> int | None:
        """The update of the last good snapshot, or None."""
        return None if self.good is None else int(self.good["extra"]["update"])

    def save_good(self) -> bool:
        """Write the last good snapshot; False when there is none."""
        if self.good is None or self.run_dir is None:
            return False
        self.write(self.good)
        return True

    def on_measured(self, update: int, measured: Measured) -> None:
        if measured.value is not None and math.isfinite(measured.value):
            self.good = self.pending
            if self.due and self.good is not None:
                self.write(self.good)
                self.due = False

    def on_update(self, update: int) -> None:
        self.pending = self.snapshot(update + 1)
        self.due = self.due or bool(self.every and (update + 1) % self.every == 0)


def optimizer_and_task_state(optimizer: torch.optim.Optimizer, task: Any) -> Callable[[], dict[str, Any]]:
    """The ``extra`` of :class:`LastGoodCheckpoints` for a task's training: the optimiser's and the task's state."""
    return lambda: {"optimizer": optimizer.state_dict(), "task_state": task.state_dict()}
