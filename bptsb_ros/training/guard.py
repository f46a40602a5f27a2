"""The update guard of the authors' time-series trainings (expanded NARMA, memory task), used by every trainer
of the package: a bad update is undone, and repeated bad updates divide every learning rate by 10. The spike
rule (``factor``) is the published time-series code's; trainings the facts give no spike rule (Lissajous, the
MNIST readout) run with ``factor`` 0, checking numerical failures only.

Order of one update ``i`` (as in the published time-series code):

1. The trainer measures the loss ``L_i`` with the current parameters θ_i — those the last applied update
   produced — and, if ``L_i`` is finite, back-propagates it.
2. :meth:`UpdateGuard.review` judges ``L_i`` *before* any step from it. ``L_i`` is therefore the loss after the
   previous applied update: a rejection undoes that update. It is rejected when

   * the simulation diverged, ``L_i`` is not finite, or a gradient is not finite ("numerical failure"), or
   * ``factor > 0`` and ``L_i > factor × reference``, where ``reference`` is the last entry of the loss history
     while that holds fewer than ``window`` (5) entries and the mean of its last ``window`` entries afterwards. The
     comparison is strict: exactly ``factor × reference`` is accepted.

3. A rejection restores the parameters (and ``modules``' state) and the optimiser state saved before the last
   applied update (θ_{i−1}, or the initial parameters), keeps the current learning rates, skips the step, and
   appends the previous history entry again (so a rejected loss never enters the reference). It counts one
   rejection; when the count reaches ``patience`` (5), the learning rate of every parameter group is divided
   by 10 and the count starts again at 0. Two accepted updates in a row after a rejection reset the count to 0.
4. An accepted ``L_i`` joins the history; θ_i and the optimiser state are saved; the trainer then steps.
5. A numerical failure when no update was applied since the start or the last restore cannot be undone (the
   parameters that failed are those a restore would bring back): :attr:`GuardDecision.stop`, and the trainer
   reports the training as diverged.

Every rejection is an event ``{"update", "loss", "reason", "reference", "count", "divided", "rates"}``
(``loss`` None when not finite; ``rates``: every group's learning rate after the event) kept in
:attr:`UpdateGuard.events` and in :meth:`UpdateGuard.summary`, which trainers write to their metrics.
"""

from __future__ import annotations

import copy
import math
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

#: the published code's rule: a loss above 10× the reference is rejected
FACTOR = 10.0
#: rejections before every learning rate is divided by 10
PATIENCE = 5
#: the reference is the mean of this many last history entries (the last entry while there are fewer)
WINDOW = 5
#: accepted updates in a row that reset the rejection count
RESET_AFTER = 2
#: every learning rate is multiplied by this after ``patience`` rejections
DIVISION = 0.1

NUMERICAL = ("diverged", "non-finite loss", "non-finite gradient")
_IMMUTABLE = (int, float, complex, bool, str, bytes, type(None))


def copy_state(tree: Any) -> Any:
    """A deep copy of a state tree — dicts, lists and tuples of tensors, numpy arrays and plain values, as
    ``state_dict()`` methods return them — made as ``copy.deepcopy`` makes it (tensors detached clones, arrays
    copies, a dict's type and ``_metadata`` kept, any other object deep-copied) without deepcopy's per-object
    dispatch and memo: the guard and the trainer copy the parameters after every update, and for a small body
    deepcopy's bookkeeping cost more than the copies themselves. Unlike deepcopy it does not keep two references
    to one tensor as one (tied weights become two clones), which ``load_state_dict`` does not mind."""
    if isinstance(tree, torch.Tensor):
        return tree.detach().clone()
    if isinstance(tree, _IMMUTABLE):
        return tree
    if type(tree) in (dict, OrderedDict):  # other mappings (defaultdict, Counter...) go to deepcopy
        out = type(tree)((key, copy_state(value)) for key, value in tree.items())
        if hasattr(tree, "_metadata"):  # nn.Module.state_dict's versions, read by load_state_dict
            out._metadata = copy.deepcopy(tree._metadata)  # type: ignore[attr-defined]
        return out
    if type(tree) in (list, tuple):
        return type(tree)(copy_state(value) for value in tree)
    if isinstance(tree, np.ndarray):
        return tree.copy()
    return copy.deepcopy(tree)


@dataclass(frozen=True)
class GuardDecision:
    """The verdict on one update: ``accepted`` (the trainer steps now) or a rejection with its ``reason``
    (``diverged``, ``non-finite loss``, ``non-finite gradient``, ``loss spike``); ``divided``: the learning rates
    were divided by 10; ``stop``: a numerical failure with nothing to undo — the training cannot continue."""

    accepted: bool
    reason: str | None = None
    divided: bool = False
    stop: bool = False


class UpdateGuard:
    """Undo bad updates of ``optimizer`` (see the module docstring for the exact rules).

    Args:
        optimizer: the trainer's optimiser; its parameters are saved and restored, its groups' rates divided.
        factor: the spike factor (0: no spike check; numerical failures are always rejected).
        patience: rejections before every rate is divided by 10.
        window: the reference is the mean of this many last losses (the published rule: 5; a minibatch
            training may compare with a whole epoch's instead).
        modules: further modules whose whole state is saved and restored with the parameters (e.g. a feedback
            layer fitted outside the optimiser).
        log: called with one line per rejection (e.g. a progress bar's ``write``).
    """

    def __init__(self, optimizer: torch.optim.Optimizer, *, factor: float = FACTOR, patience: int = PATIENCE,
                 window: int = WINDOW, modules: Mapping[str, nn.Module] | None = None,
                 log: Callable[[str], None] | None = None) -> None:
        if factor < 0 or not math.isfinite(factor):
            raise ValueError(f"factor must be finite and >= 0, got {factor}")
        if patience < 1:
            raise ValueError(f"patience must be >= 1, got {patience}")
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.window = int(window)
        self.optimizer = optimizer
        self.factor = float(factor)
        self.patience = int(patience)
        self.modules = dict(modules or {})
        self.log = log
        #: the loss history: accepted losses, a rejected update repeating the previous entry
        self.history: list[float] = []
        self.events: list[dict[str, Any]] = []
        self.count = 0  # rejections since the last reset or division
        self.good_in_a_row = 0
        self.stepped = False  # an update was applied since the start or the last restore
        self._saved = self._snapshot()

    # -- the parameters ------------------------------------------------------------------------------
    def _params(self) -> list[torch.Tensor]:
        return [p for g in self.optimizer.param_groups for p in g["params"]]

    def _snapshot(self) -> dict[str, Any]:
        return {"params": [p.detach().clone() for p in self._params()],
                "optimizer": copy_state(self.optimizer.state_dict()),
                "modules": {name: copy_state(m.state_dict()) for name, m in self.modules.items()}}

    def _restore(self) -> None:
        saved = copy.deepcopy(self._saved)  # load_state_dict may alias the tensors it is given
        rates = [g["lr"] for g in self.optimizer.param_groups]
        with torch.no_grad():
            for name, module in self.modules.items():
                module.load_state_dict(saved["modules"][name])
            for p, value in zip(self._params(), saved["params"]):
                p.copy_(value)
        self.optimizer.load_state_dict(saved["optimizer"])
        for group, lr in zip(self.optimizer.param_groups, rates):  # a division since the save stays
            group["lr"] = lr

    def gradients_finite(self) -> bool:
        """True when every gradient of the optimiser's parameters is finite (None counts as finite)."""
        return all(bool(torch.isfinite(p.grad).all()) for p in self._params() if p.grad is not None)

    def backward_and_review(self, update: int, loss: torch.Tensor | None, *,
                            diverged: str | None = None) -> GuardDecision:
        """Zero the gradients, back-propagate ``loss`` (a scalar; only when it is finite and the simulation did
        not diverge), and :meth:`review` it: the whole guard step of a trainer, before its ``optimizer.step()``."""
        self.optimizer.zero_grad(set_to_none=True)
        value = None if loss is None else float(loss.detach())
        grads_ok = True
        if diverged is None and value is not None and math.isfinite(value):
            loss.backward()
            grads_ok = self.gradients_finite()
        return self.review(update, value, grads_finite=grads_ok, diverged=diverged)

    def rates(self) -> dict[str, float]:
        """Every group's learning rate, by the group's ``name`` (or its index)."""
        return {str(g.get("name", i)): float(g["lr"]) for i, g in enumerate(self.optimizer.param_groups)}

    def reference(self) -> float | None:
        """The loss a new loss is compared with (None while the history is empty)."""
        if not self.history:
            return None
        if len(self.history) < self.window:
            return self.history[-1]
        return sum(self.history[-self.window:]) / self.window

    # -- the verdict ---------------------------------------------------------------------------------
    def review(self, update: int, loss: float | None, *, grads_finite: bool = True,
               diverged: str | None = None) -> GuardDecision:
        """Judge update ``update`` from its loss (None: not measured), before any step from it.

        ``grads_finite``: the gradients of ``loss`` are finite (ignored when the loss is not); ``diverged``: the
        simulation's error message when it diverged. Accepted: the parameters are saved and the caller steps.
        Rejected: the parameters and optimiser state are restored already; the caller skips the step.
        """
        value = None if loss is None else float(loss)
        reference = self.reference()
        if diverged is not None:
            reason = "diverged"
        elif value is None or not math.isfinite(value):
            reason = "non-finite loss"
        elif not grads_finite:
            reason = "non-finite gradient"
        elif self.factor and reference is not None and value > self.factor * reference:
            reason = "loss spike"
        else:
            return self._accept(value)
        if reason in NUMERICAL and not self.stepped:
            return GuardDecision(False, reason, stop=True)
        return self._reject(update, value, reason, reference, diverged)

    def _accept(self, value: float) -> GuardDecision:
        self.history.append(value)
        if self.count:
            self.good_in_a_row += 1
            if self.good_in_a_row >= RESET_AFTER:
                self.count, self.good_in_a_row = 0, 0
        self._saved = self._snapshot()
        self.stepped = True
        return GuardDecision(True)

    def _reject(self, update: int, value: float | None, reason: str, reference: float | None,
                detail: str | None) -> GuardDecision:
        self._restore()
        self.stepped = False
        self.history.append(self.history[-1])  # never empty: an update was applied, so one was accepted
        self.count += 1
        self.good_in_a_row = 0
        count = self.count
        divided = self.count >= self.patience
        if divided:
            for group in self.optimizer.param_groups:
                group["lr"] *= DIVISION
            self.count = 0
        finite = value is not None and math.isfinite(value)
        event = {"update": int(update), "loss": value if finite else None, "reason": reason,
                 "reference": reference, "count": count, "divided": divided, "rates": self.rates()}
        if detail:
            event["detail"] = detail[:300]
        self.events.append(event)
        if self.log is not None:
            shown = f"loss {value:.4g}" if finite else ("no loss" if value is None else f"loss {value}")
            ref = "" if reference is None else f", reference {reference:.4g}"
            line = (f"update {update}: rejected ({reason}, {shown}{ref}): parameters and optimiser state restored, "
                    f"rejection {count} of {self.patience}")
            if divided:
                line += f"; every learning rate divided by 10: {self.rates()}"
            self.log(line)
        return GuardDecision(False, reason, divided=divided)

    # -- reporting and resuming ----------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        """What trainers write to their metrics: the rules, the events, the final rates."""
        return {"factor": self.factor, "patience": self.patience, "window": self.window, "reset_after": RESET_AFTER,
                "rejections": len(self.events), "divisions": sum(bool(e["divided"]) for e in self.events),
                "events": list(self.events), "rates": self.rates()}

    def state_dict(self) -> dict[str, Any]:
        """Everything to continue bit for bit (plain data and tensors: ``weights_only`` loads it)."""
        return {"history": list(self.history), "events": copy.deepcopy(self.events), "count": self.count,
                "good_in_a_row": self.good_in_a_row, "stepped": self.stepped, "saved": copy.deepcopy(self._saved)}

    def mark(self) -> dict[str, Any]:
        """This moment's state in O(1): lengths of the history and the events (both only grow while training) and
        a reference to the saved parameters (replaced, never changed in place). :meth:`state_at` turns it into
        this moment's :meth:`state_dict` later — a trainer marks every update and needs a state only to save
        one, and copying a history of 40,000 losses and thousands of events every update made training slow
        down as it went."""
        return {"history": len(self.history), "events": len(self.events), "count": self.count,
                "good_in_a_row": self.good_in_a_row, "stepped": self.stepped, "saved": self._saved}

    def state_at(self, mark: Mapping[str, Any]) -> dict[str, Any]:
        """The :meth:`state_dict` of the moment ``mark`` (from :meth:`mark`) was taken."""
        if mark["history"] > len(self.history) or mark["events"] > len(self.events):
            raise ValueError("the mark is from a longer history than this guard's (taken before a load_state_dict?)")
        return {"history": list(self.history[:mark["history"]]), "events": copy.deepcopy(self.events[:mark["events"]]),
                "count": mark["count"], "good_in_a_row": mark["good_in_a_row"], "stepped": mark["stepped"],
                "saved": copy.deepcopy(mark["saved"])}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.history[:] = [float(x) for x in state["history"]]  # in place: callers may hold the list
        self.events = copy.deepcopy(list(state["events"]))
        self.count = int(state["count"])
        self.good_in_a_row = int(state["good_in_a_row"])
        self.stepped = bool(state["stepped"])
        self._saved = copy.deepcopy(dict(state["saved"]))
