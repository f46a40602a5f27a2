"""Checks of a resumed training state (a checkpoint given to ``train --resume``, a population's saved state): it is
untrusted data, read as data (``weights_only``), and before any of it is used it must be a state this very
training could have saved.

What is checked, against the training built afresh from the same config:

* **shapes and types**: every module's state has the same entries, shapes and dtypes as the fresh agent's, and its
  fixed buffers (the body's layout, masses, the SWG's driven springs) equal them; the optimiser's groups are the
  fresh optimiser's (same parameters, same hyperparameters but the rate); its per-parameter state (Adam's moments)
  has the parameters' shapes; the task's carried state has the fresh task's entries and shapes;
* **finiteness**: every number and tensor of the state is finite;
* **ranges**: the update counter is within 0 … the training's updates, and the loss history holds one entry per
  update; every learning rate is > 0 and at most the config's (the guard and the schedule only ever divide it);
  the body's k, d, l are ≥ 0; Adam's step counts are within 0 … the update counter and its second moments ≥ 0; the
  guard's counters are within their rules and its rejection events are the guard's (their entries, finite losses,
  an update within the history, rates > 0); a whole number beyond 2⁶² is refused before it is used.

Every failure is a :class:`ResumeStateError`: one line naming the entry and what is wrong with it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

#: relative slack of "at most the config's rate" (a rate divided by 10 and saved as a float)
RATE_SLACK = 1e-9
#: deepest nesting walked in a state (a real one is < 10 deep)
MAX_DEPTH = 32


class ResumeStateError(ValueError):
    """A resumed state is not one this training could have saved; the message names the entry."""


def check_finite(tree: Any, where: str, depth: int = 0) -> None:
    """Every float and tensor in ``tree`` (dicts, lists, tuples) is finite."""
    if depth > MAX_DEPTH:
        raise ResumeStateError(f"{where} is nested deeper than {MAX_DEPTH} levels")
    if isinstance(tree, torch.Tensor):
        if tree.is_floating_point() and not bool(torch.isfinite(tree).all()):
            raise ResumeStateError(f"{where} holds a value that is not finite (NaN or infinite)")
    elif isinstance(tree, np.ndarray):
        if np.issubdtype(tree.dtype, np.floating) and not np.isfinite(tree).all():
            raise ResumeStateError(f"{where} holds a value that is not finite (NaN or infinite)")
    elif isinstance(tree, float):
        if not math.isfinite(tree):
            raise ResumeStateError(f"{where} is {tree}, not a finite number")
    elif isinstance(tree, Mapping):
        for key, value in tree.items():
            check_finite(value, f"{where}.{key}", depth + 1)
    elif isinstance(tree, (list, tuple)):
        for i, value in enumerate(tree):
            check_finite(value, f"{where}[{i}]", depth + 1)


def check_tensor(value: Any, where: str, shape: Sequence[int], dtype: torch.dtype | None = None) -> torch.Tensor:
    """``value`` is a tensor of ``shape`` (and ``dtype``); returns it."""
    if not isinstance(value, torch.Tensor):
        raise ResumeStateError(f"{where} is {type(value).__name__}, not a tensor")
    if tuple(value.shape) != tuple(shape):
        raise ResumeStateError(f"{where} has shape {tuple(value.shape)}, not {tuple(shape)}")
    if dtype is not None and value.dtype != dtype:
        raise ResumeStateError(f"{where} is {value.dtype}, not {dtype}")
    return value


def check_whole(value: Any, where: str, lo: int, hi: int) -> int:
    """``value`` is a whole number (an int, or a float / 0-d tensor holding one) in ``lo`` … ``hi``."""
    if isinstance(value, torch.Tensor) and value.numel() == 1:
        value = value.item()
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2**62:
        raise ResumeStateError(f"{where} is {_shown(value)}, outside {lo} … {hi}")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or value != int(value):
        raise ResumeStateError(f"{where} is {_shown(value)}, not a whole number")
    if not lo <= value <= hi:
        raise ResumeStateError(f"{where} is {int(value)}, outside {lo} … {hi}")
    return int(value)


def check_rate(value: Any, where: str, at_most: float) -> float:
    """``value`` is a learning rate: a finite number > 0 and at most ``at_most`` (the config's)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ResumeStateError(f"{where} is {_shown(value)}; a learning rate is a finite number > 0")
    if value > at_most * (1 + RATE_SLACK):
        raise ResumeStateError(f"{where} is {value:g}, above the config's {at_most:g} (training only ever divides "
                               "a rate)")
    return float(value)


def check_like(saved: Any, fresh: Any, where: str) -> None:
    """``saved`` has the structure of ``fresh``: the same keys, tensors of the same shapes and dtypes, numbers where
    it has numbers (a whole number where it has an int, or None where it may be None)."""
    if isinstance(fresh, torch.Tensor):
        check_tensor(saved, where, fresh.shape, fresh.dtype)
    elif isinstance(fresh, str):
        if saved != fresh:
            raise ResumeStateError(f"{where} is {_shown(saved)}, not {_shown(fresh)}")
    elif isinstance(fresh, bool):
        if not isinstance(saved, bool):
            raise ResumeStateError(f"{where} is {_shown(saved)}, not true or false")
    elif isinstance(fresh, int) or fresh is None:
        if saved is not None and (isinstance(saved, bool) or not isinstance(saved, int)):
            raise ResumeStateError(f"{where} is {_shown(saved)}, not a whole number")
    elif isinstance(fresh, float):
        if isinstance(saved, bool) or not isinstance(saved, (int, float)):
            raise ResumeStateError(f"{where} is {_shown(saved)}, not a number")
    elif isinstance(fresh, Mapping):
        if not isinstance(saved, Mapping):
            raise ResumeStateError(f"{where} is {type(saved).__name__}, not a mapping")
        missing, extra = set(fresh) - set(saved), set(saved) - set(fresh)
        if missing or extra:
            what = f"lacks {_names(missing)}" if missing else f"has unknown entries {_names(extra)}"
            raise ResumeStateError(f"{where} {what}")
        for key in fresh:
            check_like(saved[key], fresh[key], f"{where}.{key}")


def check_modules(saved: Any, modules: Mapping[str, torch.nn.Module], where: str,
                  fitted: Sequence[str] = ()) -> None:
    """Module states: the fresh modules' entries, shapes and dtypes; their buffers (fixed by the config) equal to
    the fresh ones but those named in ``fitted`` (``module.buffer``: fitted outside training, e.g. a feedback
    layer's weight); finite; the body's k, d, l ≥ 0."""
    if not isinstance(saved, Mapping):
        raise ResumeStateError(f"{where} is {type(saved).__name__}, not a mapping of module states")
    for name, module in modules.items():
        if name not in saved:
            raise ResumeStateError(f"{where} lacks the {name!r} module")
        fresh = module.state_dict()
        check_like(saved[name], fresh, f"{where}.{name}")
        check_finite(saved[name], f"{where}.{name}")
        params = {n for n, _ in module.named_parameters()}
        for key, value in fresh.items():
            if key not in params and f"{name}.{key}" not in fitted and not torch.equal(saved[name][key], value):
                raise ResumeStateError(f"{where}.{name}.{key} differs from the one the config builds (it is fixed by "
                                       "the body and the brain, not trained)")
    body = saved.get("body", {}) if "body" in modules else {}
    for key in ("k", "d", "l"):
        if key in body and bool((body[key] < 0).any()):
            raise ResumeStateError(f"{where}.body.{key} has a negative value ({float(body[key].min()):g}); k, d and "
                                   "l are ≥ 0")


def check_torch_optimizer(saved: Any, fresh: torch.optim.Optimizer, rates0: Sequence[float], update: int,
                          where: str) -> None:
    """A torch optimiser's state_dict: the fresh optimiser's groups (same parameters and hyperparameters), each
    group's rate in (0, its config rate], per-parameter tensors of the parameters' shapes, step counts in
    0 … ``update``, second moments ≥ 0, all finite."""
    if not isinstance(saved, Mapping) or not isinstance(saved.get("param_groups"), list) \
            or not isinstance(saved.get("state"), Mapping):
        raise ResumeStateError(f"{where} is not an optimiser state (param_groups and state)")
    groups = fresh.state_dict()["param_groups"]
    if len(saved["param_groups"]) != len(groups):
        raise ResumeStateError(f"{where} has {len(saved['param_groups'])} parameter groups, the config's optimiser "
                               f"{len(groups)}")
    shapes: dict[int, tuple[int, ...]] = {}
    params = [p for g in fresh.param_groups for p in g["params"]]
    for i, (got, want) in enumerate(zip(saved["param_groups"], groups)):
        name = f"{where}.param_groups[{i}]"
        if not isinstance(got, Mapping):
            raise ResumeStateError(f"{name} is not a mapping")
        missing = set(want) - set(got)
        if missing:
            raise ResumeStateError(f"{name} lacks {_names(missing)}")
        for key, value in want.items():
            if key == "lr":
                check_rate(got.get("lr"), f"{name}.lr ({want.get('name', i)})", rates0[i])
            elif key in got and got[key] != value:
                raise ResumeStateError(f"{name}.{key} is {_shown(got[key])}, not the config's {_shown(value)}")
        shapes.update({index: tuple(params[index].shape) for index in want["params"]})
    for index, state in saved["state"].items():
        name = f"{where}.state[{index}]"
        if index not in shapes or not isinstance(state, Mapping):
            raise ResumeStateError(f"{name} is not the state of one of the optimiser's parameters")
        for key, value in state.items():
            if key == "step":
                check_whole(value, f"{name}.step", 0, update)
            else:
                check_tensor(value, f"{name}.{key}", shapes[index])
                check_finite(value, f"{name}.{key}")
                if key in ("exp_avg_sq", "max_exp_avg_sq") and bool((value < 0).any()):
                    raise ResumeStateError(f"{name}.{key} has a negative value (it is a mean of squares)")


def check_guard(saved: Any, where: str, *, patience: int, reset_after: int, params: Sequence[torch.Tensor],
                updates: int | None, check_optimizer: Any = None) -> None:
    """An :class:`~bptsb_ros.training.guard.UpdateGuard` state_dict: a finite loss history (of ``updates`` entries
    unless None), events, counters within the guard's rules, and saved parameters of the shapes of ``params``
    (``check_optimizer(saved_optimizer_state, where)`` checks the saved optimiser state)."""
    if not isinstance(saved, Mapping):
        raise ResumeStateError(f"{where} is not a guard state")
    for key in ("history", "events", "count", "good_in_a_row", "stepped", "saved"):
        if key not in saved:
            raise ResumeStateError(f"{where} lacks {key!r}")
    history = saved["history"]
    if not isinstance(history, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                for x in history):
        raise ResumeStateError(f"{where}.history is not a list of numbers")
    check_finite(history, f"{where}.history")
    if updates is not None and len(history) != updates:
        raise ResumeStateError(f"{where}.history holds {len(history)} losses, not one per update ({updates})")
    if not isinstance(saved["events"], list):
        raise ResumeStateError(f"{where}.events is not a list of events")
    for i, event in enumerate(saved["events"]):
        check_event(event, f"{where}.events[{i}]", len(history) if updates is None else updates)
    check_whole(saved["count"], f"{where}.count", 0, patience - 1)
    check_whole(saved["good_in_a_row"], f"{where}.good_in_a_row", 0, reset_after - 1)
    if not isinstance(saved["stepped"], bool):
        raise ResumeStateError(f"{where}.stepped is not true or false")
    snap = saved["saved"]
    if not isinstance(snap, Mapping) or not isinstance(snap.get("params"), list):
        raise ResumeStateError(f"{where}.saved is not a saved state of the parameters")
    if len(snap["params"]) != len(params):
        raise ResumeStateError(f"{where}.saved holds {len(snap['params'])} parameters, not {len(params)}")
    for i, (value, p) in enumerate(zip(snap["params"], params)):
        check_tensor(value, f"{where}.saved.params[{i}]", p.shape, p.dtype)
        check_finite(value, f"{where}.saved.params[{i}]")
    if check_optimizer is not None:
        check_optimizer(snap.get("optimizer"), f"{where}.saved.optimizer")


#: an update guard's rejection event: its entries and what each holds (``UpdateGuard._reject``); "detail" may be absent
_EVENT = {"update": "whole", "loss": "number or None", "reason": "text", "reference": "number or None",
          "count": "whole", "divided": "bool", "rates": "rates", "detail": "text"}


def check_event(event: Any, where: str, updates: int) -> None:
    """One rejection event of a guard: the guard's entries (``detail`` optional), the update it rejected within
    0 … ``updates`` − 1, finite losses, a count ≥ 1, text of at most 300 characters, rates > 0 by name."""
    if not isinstance(event, Mapping):
        raise ResumeStateError(f"{where} is not a mapping")
    missing, extra = set(_EVENT) - {"detail"} - set(event), set(event) - set(_EVENT)
    if missing or extra:
        what = f"lacks {_names(missing)}" if missing else f"has unknown entries {_names(extra)}"
        raise ResumeStateError(f"{where} {what}")
    for key, kind in _EVENT.items():
        if key not in event:
            continue
        value, at = event[key], f"{where}.{key}"
        if kind == "whole":
            check_whole(value, at, 0 if key == "update" else 1, updates - 1 if key == "update" else 2**62)
        elif kind == "number or None":
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                      or not math.isfinite(value)):
                raise ResumeStateError(f"{at} is {_shown(value)}, not a finite number or null")
        elif kind == "text":
            if not isinstance(value, str) or len(value) > 300:
                raise ResumeStateError(f"{at} is not a text of at most 300 characters")
        elif kind == "bool":
            if not isinstance(value, bool):
                raise ResumeStateError(f"{at} is {_shown(value)}, not true or false")
        elif not isinstance(value, Mapping) or not all(
                isinstance(r, (int, float)) and not isinstance(r, bool) and math.isfinite(r) and r > 0
                for r in value.values()):
            raise ResumeStateError(f"{at} is not a mapping of learning rates > 0")


def check_resume_checkpoint(payload: Mapping[str, Any], agent: Any, task: Any, optimizer: torch.optim.Optimizer,
                            total: int, *, patience: int, reset_after: int) -> int:
    """A checkpoint given to ``train --resume`` (its ``modules`` and ``extra``) against the training built afresh
    from the same config: ``agent``, ``task`` and ``optimizer`` as yet untouched, ``total`` updates. Returns the
    update to go on from."""
    extra = payload.get("extra")
    if not isinstance(extra, Mapping):
        raise ResumeStateError("extra is not a mapping")
    for key in ("optimizer", "task_state", "update"):
        if key not in extra:
            raise ResumeStateError(f"extra lacks {key!r} (not a checkpoint of a training)")
    update = check_whole(extra["update"], "extra.update", 0, total)
    check_modules(payload.get("modules"), agent.modules(), "modules")
    rates0 = [float(g["lr"]) for g in optimizer.param_groups]
    check_torch_optimizer(extra["optimizer"], optimizer, rates0, update, "extra.optimizer")
    task_state = extra["task_state"]
    check_like(task_state, task.state_dict(), "extra.task_state")
    check_finite(task_state, "extra.task_state")
    if isinstance(task_state, Mapping) and "step" in task_state:
        check_whole(task_state["step"], "extra.task_state.step", 0, 2**62)
    if "guard" in extra:
        params = [p for g in optimizer.param_groups for p in g["params"]]
        check_guard(extra["guard"], "extra.guard", patience=patience, reset_after=reset_after, params=params,
                    updates=update, check_optimizer=lambda s, w: check_torch_optimizer(s, optimizer, rates0, update, w))
    losses = extra.get("losses", [])
    if not isinstance(losses, list) or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                               for x in losses):
        raise ResumeStateError("extra.losses is not a list of numbers")
    check_finite(losses, "extra.losses")
    return update


def _shown(value: Any) -> str:
    from bptsb_ros.files.untrusted_yaml import bounded_repr

    return bounded_repr(value, 60)


def _names(keys: set) -> str:
    return ", ".join(sorted(_shown(k) for k in keys)[:5])
