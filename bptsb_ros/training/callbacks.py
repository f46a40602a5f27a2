"""What a training does around its updates, as objects :class:`~bptsb_ros.training.loop.UpdateLoop` calls: progress,
the caller's per-update function, the last-good checkpoints. Training code never imports a task's or a figure's
module to do these; a family passes the callbacks it wants to :meth:`UpdateLoop.run`.

Each callback may implement :meth:`Callback.on_measured` (after an update's measurement, before the guard's
verdict) and :meth:`Callback.on_update` (after the update, accepted or rejected); the loop calls them in the order
given.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from bptsb_ros.training.checkpoint import save_checkpoint
from bptsb_ros.training.guard import UpdateGuard, copy_state
from bptsb_ros.training.loop import Callback, Measured

__all__ = ["Callback", "EveryUpdate", "LastGoodCheckpoints", "LossCallback", "ProgressBar", "SimSteps",
           "optimizer_and_task_state"]


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
    line every 10 s instead of a live bar when stderr is not a terminal; nothing when not ``enabled``."""

    def __init__(self, total: int, title: str, losses: list[float], *, enabled: bool, start: int = 0,
                 log_every: int = 1) -> None:
        from tqdm import tqdm

        interactive = sys.stderr.isatty()
        self.bar = tqdm(total=total, desc=title, unit="upd", dynamic_ncols=interactive, disable=not enabled,
                        file=sys.stderr, mininterval=0.1 if interactive else 10.0)
        self.bar.update(start)
        self.losses, self.log_every = losses, max(1, log_every)

    def write(self, line: str) -> None:
        """A line above the bar (the guard's rejections)."""
        self.bar.write(line, file=sys.stderr)

    def on_update(self, update: int) -> None:
        self.bar.update(1)
        if update % self.log_every == 0:
            self.bar.set_postfix(loss=f"{self.losses[-1]:.4g}")

    def close(self) -> None:
        self.bar.close()


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
