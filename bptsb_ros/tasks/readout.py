"""MNIST classification by reading the body's states out (paper, supplement "MNIST classification by reading
states out"): LIL brain → initial displacement of the movable masses except the CMP → 1 s of transient
dynamics from rest, no external force → the positions of the movable masses every 0.1 s (10 snapshots,
20·N_mov numbers) → a linear readout → softmax cross-entropy. The "only brain" system is two linear layers.

Everything is batched: one batch of images is one simulation.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from bptsb_ros import __version__
from bptsb_ros.brains.fnn import LinearInputLayer
from bptsb_ros.files.safe_write import atomic_writer
from bptsb_ros.files.untrusted_yaml import bounded_repr
from bptsb_ros.tasks.drawing import N_PIXELS, ImageToBody, SystemSpec, iterate_batches
from bptsb_ros.training.guard import RESET_AFTER, WINDOW
from bptsb_ros.training.loop import GuardRules, LoopStopped, Measured, UpdateLoop
from bptsb_ros.training.resume_checks import (
    ResumeStateError,
    check_guard,
    check_modules,
    check_torch_optimizer,
    check_whole,
)

N_CLASSES = 10
#: Adam learning rates for the readout experiment. The paper gives none for it; plain SGD with the drawing
#: task's rates (k 1e4, d 1e3, l 1, brain 1, readout 1) makes the cross-entropy non-finite in the first epoch.
READOUT_LR = {"k": 1.0, "d": 0.1, "l": 1e-2, "brain": 1e-2, "readout": 1e-2}


@dataclass(frozen=True)
class ReadoutSpec:
    """A readout system: ``shape`` None is the brain-only two-layer linear network (784 → hidden → 10).

    transient_s: release time [s]; every_s: sampling interval of the states [s] (paper: 1 s, 0.1 s).
    """

    shape: str | None = "double_circle"
    nodes: int = 33
    hidden: int = 32
    transient_s: float = 1.0
    every_s: float = 0.1
    dt: float = 0.01
    displacement_scale: float = 0.05
    lr: dict[str, float] = field(default_factory=lambda: dict(READOUT_LR))
    optimizer: str = "adam"

    @property
    def name(self) -> str:
        return "only brain" if self.shape is None else f"{self.shape}-{self.nodes}"


class ReadoutSystem(nn.Module):
    """LIL → body → states every ``every_s`` for ``transient_s`` → linear readout → 10 logits."""

    def __init__(self, spec: ReadoutSpec, seed: int = 0) -> None:
        super().__init__()
        self.spec = spec
        self.every = int(round(spec.every_s / spec.dt))
        self.steps = int(round(spec.transient_s / spec.dt))
        if self.steps % self.every:
            raise ValueError("transient_s must be a whole number of sampling intervals")
        gen = torch.Generator().manual_seed(seed)
        if spec.shape is None:
            self.system = None
            self.brain = LinearInputLayer(N_PIXELS, spec.hidden, generator=gen)
            n_features = spec.hidden
        else:
            self.system = ImageToBody(SystemSpec(brain="lil", shape=spec.shape, nodes=spec.nodes, dt=spec.dt,
                                                 displacement_scale=spec.displacement_scale), seed)
            self.brain = self.system.brain
            n_features = (self.steps // self.every) * 2 * self.system.body.n_movable
        self.readout = nn.Linear(n_features, N_CLASSES)
        with torch.no_grad():  # the paper's LIL initialisation, N(0, 1), scaled by 1/√fan-in for the readout
            self.readout.weight.copy_(torch.randn(self.readout.weight.shape, generator=gen) / n_features**0.5)
            self.readout.bias.zero_()

    @property
    def n_features(self) -> int:
        return self.readout.in_features

    def states(self, x: torch.Tensor, adjoint: bool = True) -> torch.Tensor:
        """(B, 784) → (B, n_features): the stored body states (or the hidden layer of the brain-only net)."""
        if self.system is None:
            return self.brain(x)
        r = self.system.release(self.system.displacement(x), self.steps, adjoint=adjoint, states=True)
        return r[:, self.every:: self.every].reshape(x.shape[0], -1)  # snapshots at 0.1, 0.2, ..., 1.0 s

    def forward(self, x: torch.Tensor, adjoint: bool = True) -> torch.Tensor:
        return self.readout(self.states(x, adjoint))


def make_optimizer(model: ReadoutSystem) -> torch.optim.Optimizer:
    lr = model.spec.lr
    groups = [{"params": list(model.brain.parameters()), "lr": lr["brain"]},
              {"params": list(model.readout.parameters()), "lr": lr["readout"]}]
    if model.system is not None:
        body = model.system.body
        groups += [{"params": [body.k], "lr": lr["k"]}, {"params": [body.d], "lr": lr["d"]},
                   {"params": [body.l], "lr": lr["l"]}]
    groups = [g for g in groups if g["lr"] > 0]
    cls = torch.optim.SGD if model.spec.optimizer == "sgd" else torch.optim.Adam
    return cls(groups, lr=groups[0]["lr"])


@dataclass
class ReadoutLog:
    losses: list[float] = field(default_factory=list)  # batch cross-entropy per update; a rejected one repeats
    epoch_accuracy: list[float] = field(default_factory=list)  # test accuracy after each epoch
    wall_s: float = 0.0
    guard: dict[str, Any] = field(default_factory=dict)  # the update guard's summary (rules, events, rates)


def train_readout(model: ReadoutSystem, x: np.ndarray, y: np.ndarray, *, epochs: int, batch: int = 50,
                  seed: int = 0, test: tuple[np.ndarray, np.ndarray] | None = None, reject_factor: float = 0.0,
                  reject_window: int = WINDOW, log: Callable[[str], None] | None = None,
                  checkpoint: str | Path | None = None, identity: Mapping[str, Any] | None = None) -> ReadoutLog:
    """Softmax cross-entropy through the body (BPTSB), every update through the
    :class:`~bptsb_ros.training.guard.UpdateGuard` (see :func:`train_drawing`): a non-finite loss or gradient
    is undone, and with ``reject_factor`` > 0 also a loss above ``reject_factor`` × the mean of the last
    ``reject_window`` batch losses. 0 (default): no spike rule — the paper and the published-code facts give
    MNIST none, and the time-series rule (10 × the mean of the last 5) rejects ordinary hard minibatches once the
    loss is small (it froze both N_mov 65 readouts of a 50-epoch run).

    ``checkpoint``: a file the training's state is written to after every epoch (the model, the optimiser, the
    guard, the batch order's generator, the test accuracies so far, the time spent; read back with
    ``weights_only``), and continued from when it exists: the epochs after it are the ones an uninterrupted run
    would have made, bit for bit. ``identity``: what the training must match to continue from the file (e.g. the
    seed, the data, the epochs); a file saved with another identity is refused, never overwritten.

    Raises:
        FloatingPointError: a non-finite loss or gradient the guard cannot undo.
        ValueError: ``checkpoint`` is unreadable, another training's or not a state this training could have saved
            (one line naming the file and the entry; the file is kept).
    """
    opt = make_optimizer(model)
    loop = UpdateLoop(opt, GuardRules(factor=reject_factor, window=reject_window), log=log)
    gen = np.random.default_rng(seed)
    objective = _ReadoutBatches(model, opt, torch.as_tensor(x), torch.as_tensor(y))
    out = ReadoutLog(losses=loop.losses)
    t0 = time.perf_counter()
    updates, done, spent = 0, 0, 0.0
    ident = {**dict(identity or {}), "model": model.spec.name, "spec": repr(model.spec), "version": __version__,
             "epochs": epochs, "batch": batch, "seed": seed,
             "n_train": len(y), "n_test": 0 if test is None else len(test[1]), "reject_factor": reject_factor,
             "reject_window": reject_window}
    if checkpoint is not None and Path(checkpoint).exists():
        done, updates, spent = _resume(Path(checkpoint), ident, model, opt, loop, gen, out)
        if log:
            log(f"{model.spec.name}: continuing after epoch {done}/{epochs} from {checkpoint}")
    for epoch in range(done, epochs):
        objective.batches = iterate_batches(len(y), batch, gen)  # the epoch's permutation, drawn as it starts
        objective.first = updates
        try:
            loop.run(objective, range(updates, updates + len(objective.batches)))
        except LoopStopped as stop:
            raise FloatingPointError(f"{model.spec.name}: {stop.decision.reason} of the readout loss in epoch "
                                     f"{epoch + 1} with nothing to undo") from None
        updates += len(objective.batches)
        if test is not None:
            out.epoch_accuracy.append(accuracy(model, *test))
            if log:
                log(f"{model.spec.name}: epoch {epoch + 1}/{epochs} test accuracy {100 * out.epoch_accuracy[-1]:.2f} %")
        if checkpoint is not None:
            _save_epoch(Path(checkpoint), ident, epoch + 1, updates, spent + time.perf_counter() - t0, model, opt,
                        loop, gen, out)
    out.wall_s = spent + time.perf_counter() - t0
    out.guard = loop.guard.summary()
    return out


#: the layout of a readout training's epoch checkpoint (raised when it changes)
CHECKPOINT_FORMAT = 1


def _save_epoch(path: Path, identity: dict[str, Any], epochs_done: int, updates: int, spent_s: float,
                model: ReadoutSystem, opt: torch.optim.Optimizer, loop: UpdateLoop, gen: np.random.Generator,
                out: ReadoutLog) -> None:
    """The training's state after ``epochs_done`` epochs, written atomically (plain data and tensors)."""
    payload = {"format": CHECKPOINT_FORMAT, "identity": identity, "epochs_done": epochs_done, "updates": updates,
               "spent_s": spent_s, "model": model.state_dict(), "optimizer": opt.state_dict(),
               "guard": loop.guard.state_dict(), "batch_order": gen.bit_generator.state,
               "epoch_accuracy": list(out.epoch_accuracy)}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path) as f:
        torch.save(payload, f)


def _resume(path: Path, identity: dict[str, Any], model: ReadoutSystem, opt: torch.optim.Optimizer,
            loop: UpdateLoop, gen: np.random.Generator, out: ReadoutLog) -> tuple[int, int, float]:
    """Load the epoch checkpoint ``path`` into the training; (epochs done, updates done, seconds spent). The file
    is untrusted: it must be a state this very training could have saved (:func:`_check_state`) before any of it
    is used."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - a damaged or foreign file: one line naming it, the file kept
        raise ValueError(f"{path}: not a readable readout checkpoint ({type(err).__name__}); move it away to "
                         "train afresh") from None
    try:
        _check_identity(state, identity)
        done, updates, spent = _check_state(state, identity, model, opt, loop)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        loop.guard.load_state_dict(state["guard"])
        gen.bit_generator.state = state["batch_order"]
    except _OtherTraining as err:
        raise ValueError(f"{path} holds another training ({err}); move it away or write elsewhere") from None
    except Exception as err:  # noqa: BLE001 - whatever the checks missed is still one line, the file kept
        first = str(err).splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"{path}: {first}; move it away to train afresh") from None
    out.epoch_accuracy[:] = [float(a) for a in state["epoch_accuracy"]]
    return done, updates, spent


class _OtherTraining(Exception):
    """The checkpoint was saved by a training of another identity (the message: the first entry that differs)."""


def _check_identity(state: Any, identity: dict[str, Any]) -> None:
    if not isinstance(state, dict) or not _same(state.get("format"), CHECKPOINT_FORMAT):
        raise ResumeStateError(f"not a readout checkpoint of format {CHECKPOINT_FORMAT}")
    saved = state.get("identity")
    saved = saved if isinstance(saved, dict) else {}
    differ = sorted(str(k) for k in set(identity) | set(saved) if not _same(saved.get(k), identity.get(k)))
    if differ:
        k = differ[0]
        raise _OtherTraining(f"{k} {bounded_repr(saved.get(k), 80)}, not {bounded_repr(identity.get(k), 80)}")


def _same(a: Any, b: Any) -> bool:
    """``a == b`` for plain data, False where the comparison is not a plain True (a tensor, say)."""
    try:
        return type(a) is type(b) and bool(a == b) is True
    except Exception:  # noqa: BLE001 - an ambiguous comparison is a difference
        return False


#: Adam's per-parameter state (``torch.optim.Adam`` after a step; ``max_exp_avg_sq`` with ``amsgrad``)
_ADAM_STATE = {"step", "exp_avg", "exp_avg_sq"}


def _check_state(state: dict[str, Any], identity: dict[str, Any], model: ReadoutSystem, opt: torch.optim.Optimizer,
                 loop: UpdateLoop) -> tuple[int, int, float]:
    """The checks of :mod:`bptsb_ros.training.resume_checks` on a readout checkpoint, against the training built
    afresh: the model's entries, shapes, fixed buffers, finiteness and k, d, l ≥ 0; the optimiser's groups, rates
    and moments; the guard's history (one loss per update), events, counters and saved parameters; one update per
    batch of every epoch done; one test accuracy in [0, 1] per epoch done; a PCG64 generator state."""
    for key in ("epochs_done", "updates", "spent_s", "model", "optimizer", "guard", "batch_order", "epoch_accuracy"):
        if key not in state:
            raise ResumeStateError(f"the checkpoint lacks {key!r}")
    done = check_whole(state["epochs_done"], "epochs_done", 0, identity["epochs"])
    per_epoch = -(-identity["n_train"] // identity["batch"])
    updates = check_whole(state["updates"], "updates", done * per_epoch, done * per_epoch)
    spent = state["spent_s"]
    if not isinstance(spent, float) or not 0 <= spent < float("inf"):
        raise ResumeStateError(f"spent_s is {bounded_repr(spent, 40)}, not a time ≥ 0 [s]")
    # the brain is also the system's (one module, two names): its second name is trained too, not a fixed buffer
    trained = [f"model.{name}" for name, _ in model.named_parameters(remove_duplicate=False)]
    try:
        check_modules(state, {"model": model}, "", fitted=trained)
    except ResumeStateError as err:  # entries named from the checkpoint's top: model.readout.weight
        raise ResumeStateError(str(err).removeprefix(".")) from None
    params = [p for g in opt.param_groups for p in g["params"]]
    body = model.system.body if model.system is not None else None
    kdl = {i: n for i, p in enumerate(params) for n in "kdl" if body is not None and p is getattr(body, n)}
    for name in kdl.values():
        _non_negative(state["model"][f"system.body.{name}"], f"model.system.body.{name}")
    rates0 = [float(g["lr"]) for g in opt.param_groups]

    def check_optimizer(saved: Any, where: str) -> None:
        check_torch_optimizer(saved, opt, rates0, updates, where)
        if isinstance(opt, torch.optim.Adam):
            for index, entry in saved["state"].items():
                want = _ADAM_STATE | ({"max_exp_avg_sq"} if opt.param_groups[0].get("amsgrad") else set())
                if set(entry) != want:
                    raise ResumeStateError(f"{where}.state[{index}] holds {sorted(entry)}, not Adam's {sorted(want)}")

    check_optimizer(state["optimizer"], "optimizer")
    check_guard(state["guard"], "guard", patience=loop.guard.patience, reset_after=RESET_AFTER, params=params,
                updates=updates, check_optimizer=check_optimizer)
    for i, name in kdl.items():
        _non_negative(state["guard"]["saved"]["params"][i], f"guard.saved.params[{i}] (the body's {name})")
    acc, tested = state["epoch_accuracy"], done if identity["n_test"] else 0
    if not isinstance(acc, list) or len(acc) != tested or not all(
            isinstance(a, float) and 0 <= a <= 1 for a in acc):
        raise ResumeStateError(f"epoch_accuracy is not {tested} accuracies in [0, 1] (one per epoch tested)")
    _check_pcg64(state["batch_order"])
    return done, updates, spent


def _non_negative(value: torch.Tensor, where: str) -> None:
    if bool((value < 0).any()):
        raise ResumeStateError(f"{where} has a negative value; k, d and l are ≥ 0")


def _check_pcg64(order: Any) -> None:
    """A numpy PCG64 bit generator's state: ``{"bit_generator": "PCG64", "state": {"state", "inc"},
    "has_uint32", "uinteger"}`` with 128-bit state and increment, and a buffered 32-bit word."""
    where = "batch_order"
    if not isinstance(order, dict) or order.get("bit_generator") != "PCG64" or set(order) != {
            "bit_generator", "state", "has_uint32", "uinteger"}:
        raise ResumeStateError(f"{where} is not the state of a PCG64 generator")
    inner = order["state"]
    if not isinstance(inner, dict) or set(inner) != {"state", "inc"}:
        raise ResumeStateError(f"{where}.state is not a PCG64 state (state and inc)")
    for key in ("state", "inc"):
        value = inner[key]
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 2**128:
            raise ResumeStateError(f"{where}.state.{key} is not a 128-bit whole number")
    check_whole(order["has_uint32"], f"{where}.has_uint32", 0, 1)
    check_whole(order["uinteger"], f"{where}.uinteger", 0, 2**32 - 1)


class _ReadoutBatches:
    """The readout training's update (an :class:`~bptsb_ros.training.loop.Objective`): the cross-entropy of one
    batch of the epoch's ``batches`` (update ``first + j`` reads batch ``j``)."""

    def __init__(self, model: ReadoutSystem, opt: torch.optim.Optimizer, xt: torch.Tensor, yt: torch.Tensor) -> None:
        self.model, self.opt, self.xt, self.yt = model, opt, xt, yt
        self.batches: list[np.ndarray] = []
        self.first = 0

    def measure(self, update: int) -> Measured:
        idx = self.batches[update - self.first]
        return Measured(nn.functional.cross_entropy(self.model(self.xt[idx]), self.yt[idx]))

    def step(self) -> None:
        self.opt.step()
        if self.model.system is not None:
            self.model.system.body.clamp_parameters_()

    def advance(self, finite: bool) -> None:
        del finite


@torch.no_grad()
def accuracy(model: ReadoutSystem, x: np.ndarray, y: np.ndarray, batch: int = 1000) -> float:
    """Fraction of images whose largest logit is their label (one simulation per chunk of ``batch``)."""
    xt = torch.as_tensor(x)
    pred = torch.cat([model(xt[i: i + batch], adjoint=False).argmax(1) for i in range(0, len(y), batch)])
    return float((pred.numpy() == np.asarray(y)).mean())
