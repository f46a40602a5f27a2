"""MNIST drawing (paper: main text "Division of functional roles", Methods "MNIST classification and drawing
task"): an image goes through the brain to the initial displacement of every movable mass except the CMP; the
body is released from rest and its CMP draws; the loss is the MSE between the CMP's trajectory and the label's
target digit (:mod:`bptsb_ros.tasks.digits`).

Everything is batched: a batch of images is one simulation (B bodies), a label-map grid is one simulation.

Shapes: images x (B, 784) in [0, 1]; displacements (B, M, 2) [m] with the CMP row zero; a drawing
(B, T + 1, 2) [m]: the CMP position relative to its rest position (the origin) at steps 0..T.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.msdn import MSDN
from bptsb_ros.body.shapes import build_shape
from bptsb_ros.brains.fnn import LinearInputLayer, MLPBrain
from bptsb_ros.tasks.digits import load_targets, padded_targets
from bptsb_ros.training.callbacks import EveryUpdate
from bptsb_ros.training.guard import FACTOR
from bptsb_ros.training.loop import GuardRules, LoopStopped, Measured, UpdateLoop

N_PIXELS = 784
#: the paper's learning rates for MNIST (supplement table): k, d, l and the LIL/MLP, plain SGD
PAPER_LR = {"k": 1e4, "d": 1e3, "l": 1.0, "brain": 1.0}
#: metres of initial displacement per unit of brain output, per brain. The rule: the untrained brain places
#: the masses ≈ 0.2-0.4 m (size/20-size/10) from rest on MNIST images. The LIL's N(0, 1) weights give outputs
#: of ≈ 8 (‖x‖ ≈ 9 for an MNIST image), hence 0.05 m (mean |displacement| 0.32 m, multiple-circle of 17 masses); the
#: Xavier MLP's outputs are ≈ 0.2 already, hence 1 (mean |displacement| 0.20 m).
DISPLACEMENT_SCALE = {"lil": 0.05, "mlp": 1.0}


@dataclass(frozen=True)
class SystemSpec:
    """One brain-body system of the MNIST experiments.

    brain: ``lil`` (784 → out, W, b ~ N(0, 1)) or ``mlp`` (784 → hidden → hidden → out, ReLU, Xavier).
    shape, nodes: the body (``nodes`` counts every mass, fixed ones included; the paper counts movable masses:
        its multiple-circle N_mov = 17 / 65 are ``nodes`` 37 / 101, ``body.shapes.nodes_for_movable``).
    displacement_scale: metres of initial displacement per unit of brain output [m].
    lr: learning rates per parameter kind (k, d, l, brain); optimizer ``sgd`` (the paper) or ``adam``.

    ``displacement_scale`` is ours (the paper does not say how brain outputs become metres); by default it is
    chosen per brain so that both untrained brains place the masses a similar distance from rest on MNIST
    images (:data:`DISPLACEMENT_SCALE`).
    """

    brain: str = "mlp"
    shape: str = "multiple_circle"
    nodes: int = 37
    size: float = 4.0
    hidden: int = 128
    dt: float = 0.01
    displacement_scale: float | None = None
    optimizer: str = "sgd"
    lr: dict[str, float] = field(default_factory=lambda: dict(PAPER_LR))
    dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.brain not in ("lil", "mlp"):
            raise ValueError(f"brain must be 'lil' or 'mlp', got {self.brain!r}")
        if self.displacement_scale is None:
            object.__setattr__(self, "displacement_scale", DISPLACEMENT_SCALE[self.brain])
        if self.optimizer not in ("sgd", "adam"):
            raise ValueError(f"optimizer must be 'sgd' or 'adam', got {self.optimizer!r}")
        unknown = set(self.lr) - {"k", "d", "l", "brain"}
        if unknown:
            raise ValueError(f"lr: unknown keys {sorted(unknown)}; use k, d, l, brain")

    @property
    def torch_dtype(self) -> torch.dtype:
        return {"float32": torch.float32, "float64": torch.float64}[self.dtype]

    @property
    def name(self) -> str:
        """Short id: ``mlp-multiple_circle-37``."""
        return f"{self.brain}-{self.shape}-{self.nodes}"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> SystemSpec:
        return SystemSpec(**data)


def build_brain(kind: str, n_out: int, *, hidden: int = 128, generator: torch.Generator | None = None,
                dtype: torch.dtype = torch.float32) -> nn.Module:
    """The paper's LIL or MLP from 784 pixels to ``n_out``."""
    if kind == "lil":
        return LinearInputLayer(N_PIXELS, n_out, generator=generator, dtype=dtype)
    return MLPBrain(N_PIXELS, n_out, hidden=hidden, generator=generator, dtype=dtype)


class ImageToBody(nn.Module):
    """Brain + body: image → initial displacement of the movable masses except the CMP → released body."""

    def __init__(self, spec: SystemSpec, seed: int = 0) -> None:
        super().__init__()
        self.spec = spec
        gen = torch.Generator().manual_seed(seed)
        dtype = spec.torch_dtype
        topo = build_shape(spec.shape, spec.nodes, spec.size)
        # published: k ~ U(1, 100), d ~ U(0, 10), U(0, 5) for bodies of 50 masses or more
        d_hi = 5.0 if topo.n_masses >= 50 else 10.0
        self.body = MSDN(topo, dt=spec.dt, d_init=(0.0, d_hi), generator=gen, dtype=dtype)
        m = self.body.n_movable
        self.cmp = self.body.cmp_local
        self.register_buffer("driven", torch.tensor([i for i in range(m) if i != self.cmp], dtype=torch.long))
        self.brain = build_brain(spec.brain, 2 * (m - 1), hidden=spec.hidden, generator=gen, dtype=dtype)

    @property
    def n_driven(self) -> int:
        """Masses the brain places: every movable mass except the CMP."""
        return int(self.driven.numel())

    def brain_output(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 784) → (B, 2(M−1)) brain output (what the paper's PCA calls the brain's output)."""
        return self.brain(x.to(self.body.k.dtype))

    def displacement(self, x: torch.Tensor) -> torch.Tensor:
        """(B, 784) → (B, M, 2) initial displacements [m]; the CMP's row is zero (it starts at rest, fixed)."""
        out = self.brain_output(x) * self.spec.displacement_scale
        disp = out.new_zeros(out.shape[0], self.body.n_movable, 2)
        return disp.index_copy(1, self.driven, out.view(out.shape[0], -1, 2))

    def release(self, displacement: torch.Tensor, steps: int, *, adjoint: bool = True,
                states: bool = False) -> torch.Tensor:
        """Release the body from ``displacement`` (B, M, 2) at rest and run ``steps`` steps.

        Returns the CMP drawing (B, steps + 1, 2) [m] (relative to its rest position), or with ``states``
        the positions of every movable mass (B, steps + 1, M, 2) [m].
        """
        body = self.body
        state = body.initial_state(displacement.shape[0], displacement=displacement)
        rest = body.l.expand(steps, -1)
        win = rollout_window(body, state, rest, adjoint=adjoint)
        r = torch.cat([state.r.unsqueeze(0), win.r], 0).transpose(0, 1)  # (B, T+1, M, 2)
        if states:
            return r
        return r[:, :, self.cmp] - body.positions0[body.topology.cmp_index]

    def draw(self, x: torch.Tensor, steps: int, *, adjoint: bool = True) -> torch.Tensor:
        """(B, 784) images → (B, steps + 1, 2) CMP drawings [m]."""
        return self.release(self.displacement(x), steps, adjoint=adjoint)


class DigitTargets:
    """The ten targets, padded: ``padded`` (10, T_max + 1, 2) [m], ``steps`` (10,), ``mask`` (10, T_max + 1)."""

    def __init__(self, dt: float = 0.01, dtype: torch.dtype = torch.float32) -> None:
        padded, steps = padded_targets(load_targets(dt))
        self.padded = torch.as_tensor(padded, dtype=dtype)
        self.steps = torch.as_tensor(steps)
        self.t_max = int(steps.max())
        self.mask = (torch.arange(self.t_max + 1).unsqueeze(0) <= self.steps.unsqueeze(1)).to(dtype)

    def errors(self, drawing: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """Per-sample MSE (B,) [m²] of drawings (B, T + 1, 2) against their labels' targets, over each
        target's own steps 0..T_j and both coordinates (T ≥ every T_j of the batch)."""
        n = min(drawing.shape[1], self.t_max + 1)  # a batch runs only as long as its longest target
        tgt = self.padded[labels, :n]
        mask = self.mask[labels, :n]
        if bool((self.steps[labels] >= n).any()):
            raise ValueError(f"drawings of {n - 1} steps are shorter than some of their labels' targets")
        sq = ((drawing[:, :n] - tgt) ** 2).sum(-1)
        return (sq * mask).sum(1) / (2 * self.mask[labels].sum(1))

    def all_errors(self, drawing: torch.Tensor) -> torch.Tensor:
        """(B, 10): the MSE of every drawing against every digit's target (for label maps)."""
        d = drawing[:, None, : self.t_max + 1]  # (B, 1, T+1, 2)
        sq = ((d - self.padded[None]) ** 2).sum(-1)  # (B, 10, T+1)
        return (sq * self.mask[None]).sum(-1) / (2 * self.mask.sum(-1))[None]


def make_optimizer(system: ImageToBody) -> torch.optim.Optimizer:
    lr = system.spec.lr
    body = system.body
    groups = [{"params": [body.k], "lr": lr.get("k", 0.0)}, {"params": [body.d], "lr": lr.get("d", 0.0)},
              {"params": [body.l], "lr": lr.get("l", 0.0)},
              {"params": list(system.brain.parameters()), "lr": lr.get("brain", 0.0)}]
    groups = [g for g in groups if g["lr"] > 0]
    cls = torch.optim.SGD if system.spec.optimizer == "sgd" else torch.optim.Adam
    return cls(groups, lr=groups[0]["lr"])


@dataclass
class TrainLog:
    losses: list[float] = field(default_factory=list)  # mean batch MSE per update [m²]; a rejected one repeats
    epoch_losses: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    guard: dict[str, Any] = field(default_factory=dict)  # the update guard's summary (rules, events, rates)


def iterate_batches(n: int, batch: int, gen: np.random.Generator) -> list[np.ndarray]:
    order = gen.permutation(n)
    return [order[i: i + batch] for i in range(0, n, batch)]


def train_drawing(system: ImageToBody, x: np.ndarray, y: np.ndarray, *, epochs: int, batch: int = 50,
                  seed: int = 0, max_updates: int | None = None, reject_factor: float = FACTOR,
                  log: Callable[[str], None] | None = None) -> TrainLog:
    """BPTSB over the whole release: each batch of images is one simulation; SGD/Adam on the MSE.

    Every update goes through the :class:`~bptsb_ros.training.guard.UpdateGuard`: a non-finite loss or gradient,
    or a loss above ``reject_factor`` × the previous (the mean of the last 5 once there are 5), undoes the previous
    update; five rejections divide every rate by 10. The spike rule is the published time-series code's; the
    paper and the published-code facts give MNIST none. The drawing trainings keep it as their committed runs used
    it (at most 11 rejected updates per training there, no rate division); the readout runs without it.

    Raises:
        FloatingPointError: a non-finite loss or gradient the guard cannot undo (no update since the start or
            the last restore).
    """
    targets = DigitTargets(system.spec.dt, system.body.k.dtype)
    opt = make_optimizer(system)
    loop = UpdateLoop(opt, GuardRules(factor=reject_factor), log=log)
    gen = np.random.default_rng(seed)
    objective = _DrawingBatches(system, opt, targets, torch.as_tensor(x), torch.as_tensor(y))
    out = TrainLog(losses=loop.losses)
    t0 = time.perf_counter()
    updates = 0
    for epoch in range(epochs):
        objective.batches = iterate_batches(len(y), batch, gen)  # the epoch's permutation, drawn as it starts
        if max_updates is not None:
            objective.batches = objective.batches[:max(0, max_updates - updates)]
        epoch_sum, count = 0.0, 0

        def tally(update: int) -> None:
            nonlocal epoch_sum, count
            idx = objective.batches[update - objective.first]
            epoch_sum += out.losses[-1] * len(idx)
            count += len(idx)

        objective.first = updates
        try:
            loop.run(objective, range(updates, updates + len(objective.batches)), callbacks=(EveryUpdate(tally),))
        except LoopStopped as stop:
            raise FloatingPointError(f"{stop.decision.reason} of the drawing loss at update {stop.update} with "
                                     f"nothing to undo; body {system.body.parameter_ranges()}") from None
        updates += len(objective.batches)
        if count:
            out.epoch_losses.append(epoch_sum / count)
            if log:
                log(f"{system.spec.name}: epoch {epoch + 1}/{epochs} train MSE {epoch_sum / count:.4g} m²")
    out.wall_s = time.perf_counter() - t0
    out.guard = loop.guard.summary()
    return out


class _DrawingBatches:
    """The drawing training's update (an :class:`~bptsb_ros.training.loop.Objective`): the mean drawing error of
    one batch of the epoch's ``batches`` (update ``first + j`` draws batch ``j``)."""

    def __init__(self, system: ImageToBody, opt: torch.optim.Optimizer, targets: DigitTargets, xt: torch.Tensor,
                 yt: torch.Tensor) -> None:
        self.system, self.opt, self.targets, self.xt, self.yt = system, opt, targets, xt, yt
        self.batches: list[np.ndarray] = []
        self.first = 0

    def measure(self, update: int) -> Measured:
        idx = self.batches[update - self.first]
        labels = self.yt[idx]
        steps = int(self.targets.steps[labels].max())
        drawing = self.system.draw(self.xt[idx], steps)
        return Measured(self.targets.errors(drawing, labels).mean())

    def step(self) -> None:
        self.opt.step()
        self.system.body.clamp_parameters_()

    def advance(self, finite: bool) -> None:
        del finite


@torch.no_grad()
def evaluate_drawing(system: ImageToBody, x: np.ndarray, y: np.ndarray, *, batch: int = 500) -> dict[str, Any]:
    """Drawings of every image (one simulation per chunk of ``batch``), per-sample errors, brain outputs.

    Returns ``errors`` (n,) [m²], ``drawings`` (n, T_max + 1, 2) [m], ``brain`` (n, 2(M−1)) brain outputs,
    ``displacement`` (n, M, 2) [m].
    """
    targets = DigitTargets(system.spec.dt, system.body.k.dtype)
    xt, yt = torch.as_tensor(x), torch.as_tensor(y)
    errs, draws, brains, disps = [], [], [], []
    for i in range(0, len(y), batch):
        xb = xt[i: i + batch]
        brain = system.brain_output(xb.to(system.body.k.dtype))
        disp = system.displacement(xb)
        drawing = system.release(disp, targets.t_max, adjoint=False)
        errs.append(targets.errors(drawing, yt[i: i + batch]))
        draws.append(drawing)
        brains.append(brain)
        disps.append(disp)
    return {"errors": torch.cat(errs).double().numpy(), "drawings": torch.cat(draws).double().numpy(),
            "brain": torch.cat(brains).double().numpy(), "displacement": torch.cat(disps).double().numpy()}


@torch.no_grad()
def label_maps(system: ImageToBody, base_displacement: torch.Tensor, *, half_width: float, grid: int,
               masses: list[int] | None = None, chunk: int = 20000) -> dict[str, np.ndarray]:
    """Label maps (paper, Methods): shift one non-central mass by (Δx, Δy) on a grid from its trained initial
    position, release, and label each cell with the digit whose target is closest to the drawing.

    Args:
        base_displacement: (D, M, 2) trained initial displacements, one per original label (D = 10: the
            best test sample of each digit).
        half_width: Δ runs from −half_width to half_width [m] in each direction.
        grid: cells per axis (odd, so Δ = 0 is a cell).
        masses: movable-mass rows to shift (default every one except the CMP).

    All grids (D labels × masses × grid²) are one batched simulation (split into chunks of ``chunk`` bodies
    only to bound memory). Returns ``labels`` (D, P, grid, grid) int (row = Δy, column = Δx), ``deltas``
    (grid,) [m], ``masses`` (P,) movable rows, ``size`` (D, P): the fraction of cells labelled with the
    original label (the label-map size).
    """
    targets = DigitTargets(system.spec.dt, system.body.k.dtype)
    masses = [int(i) for i in system.driven] if masses is None else masses
    n_lab, n_mass = base_displacement.shape[0], len(masses)
    deltas = torch.linspace(-half_width, half_width, grid, dtype=base_displacement.dtype)
    dy, dx = torch.meshgrid(deltas, deltas, indexing="ij")
    shift = torch.stack([dx, dy], -1).reshape(-1, 2)  # (G², 2): row-major over (Δy, Δx)
    disp = base_displacement[:, None, None].repeat(1, n_mass, grid * grid, 1, 1)  # (D, P, G², M, 2)
    for p, mass in enumerate(masses):
        disp[:, p, :, mass] += shift
    flat = disp.reshape(-1, *base_displacement.shape[1:])
    labels = []
    for i in range(0, flat.shape[0], chunk):
        drawing = system.release(flat[i: i + chunk], targets.t_max, adjoint=False)
        labels.append(targets.all_errors(drawing).argmin(1))
    lab = torch.cat(labels).view(n_lab, n_mass, grid, grid).numpy()
    original = np.arange(n_lab)[:, None, None, None]
    return {"labels": lab, "deltas": deltas.double().numpy(), "masses": np.asarray(masses),
            "size": (lab == original).mean(axis=(2, 3))}


def joined_to_cmp(system: ImageToBody) -> np.ndarray:
    """(M,) bool over movable rows: True where a spring joins that mass to the CMP."""
    topo = system.body.topology
    cmp = topo.cmp_index
    partners = {int(j if i == cmp else i) for i, j in topo.springs if cmp in (i, j)}
    return np.asarray([int(m) in partners for m in system.body.movable_index])


def save_system(system: ImageToBody, path, extra: dict[str, Any] | None = None) -> None:
    """Write spec + state_dict (+ JSON-able extras) for ``torch.load(weights_only=True)``."""
    import json

    payload = {"spec": json.dumps(system.spec.to_json()), "state": system.state_dict(),
               "extra": json.dumps(extra or {})}
    from bptsb_ros.files.safe_write import atomic_writer

    with atomic_writer(path) as f:
        torch.save(payload, f)


def load_system(path) -> tuple[ImageToBody, dict[str, Any]]:
    import json

    payload = torch.load(path, weights_only=True)
    system = ImageToBody(SystemSpec.from_json(json.loads(payload["spec"])))
    system.load_state_dict(payload["state"])
    return system, json.loads(payload["extra"])


def rms(values: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(np.square(values)))))
