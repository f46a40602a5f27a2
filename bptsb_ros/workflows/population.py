"""Independent trainings of one held-window task (expanded NARMA, the memory task) as one batched training.

A *population* is B trainings whose agents share a topology: an LIL brain and a body without ground, trained
with ``training.backend: fused`` on episodes of the same length. Member b is the training :func:`~bptsb_ros.
workflows.train.train` runs for its config — the same initial agent (its seed), the same input stream (its
task's generator), the same loss, its own update guard and learning rates — but the population keeps every
member's k, d, l (B, E), LIL weights (B, O, 1) and biases (B, O) stacked, so one update is one brain forward
(a batched matrix product), one lane-kernel window of B lanes (``body/held_window.py``'s
:func:`~bptsb_ros.body.held_window.population_readout`), one autograd backward and one optimiser step for all of
them. A training alone spends most of an update in torch's per-call overhead; here that overhead is shared.

The population runs on the trainer's update loop (:meth:`~bptsb_ros.training.loop.UpdateLoop.batched` over
:class:`_PopulationUpdates`), which gives each member its own :class:`~bptsb_ros.training.guard.UpdateGuard` over
a view of the member's slices (:class:`_MemberOptimizer`): the rules, the events and the rate divisions are those
of a training alone. A member that diverges beyond what its guard can undo stops (its run directory gets
``diverged.json``, written by a callback); the others go on. Progress and the periodic save of the population's
state are callbacks too.

Written per member, as :func:`train` writes them: ``checkpoint.pt`` (resumable by ``train(resume=True)``),
``config.yaml``, ``metrics.json`` and the plots. The optimiser step is torch's SGD / Adam arithmetic, element
for element, and a lane of the kernel is the solo window: members equal their solo trainings bit for bit
(tests/workflows/test_population.py: float32 and float64, SGD and Adam, with rejections and rate divisions).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml

from bptsb_ros.agent import Agent, build_agent, force_inputs
from bptsb_ros.body.held_window import PopulationWindow, held_window_unsupported, lanes_unsupported, population_readout
from bptsb_ros.body.msdn import SimulationDiverged, diverged_message, parameter_ranges
from bptsb_ros.body.threads import configure_threads
from bptsb_ros.brains import LinearInputLayer
from bptsb_ros.config import ConfigError, ExperimentConfig
from bptsb_ros.files.run_dir_lock import dir_is_empty, hold_run_dir
from bptsb_ros.files.safe_write import atomic_writer, write_atomic
from bptsb_ros.sim.inputs import brain_input
from bptsb_ros.tasks.base import Task
from bptsb_ros.tasks.narma import NarmaTask
from bptsb_ros.training.callbacks import Periodically, ProgressBar
from bptsb_ros.training.checkpoint import save_checkpoint
from bptsb_ros.training.guard import RESET_AFTER, UpdateGuard
from bptsb_ros.training.loop import Callback, GuardRules, LoopStopped, Measured, UpdateLoop
from bptsb_ros.training.optim import make_optimizer
from bptsb_ros.training.resume_checks import (
    ResumeStateError,
    check_finite,
    check_guard,
    check_like,
    check_rate,
    check_tensor,
    check_whole,
)
from bptsb_ros.workflows.train import (
    TrainingDiverged,
    TrainResult,
    flatten_config,
    training_metrics,
    write_outputs,
)

__all__ = ["MemberFailure", "population_unsupported", "train_population"]

#: config keys that may differ between members (everything else must be equal)
MEMBER_KEYS = {"seed", "name", "narma.delay", "narma.target", "narma.order", "narma.eval_seed"}


@dataclass
class MemberFailure:
    """A member that stopped: its index and the error its solo training would have raised."""

    index: int
    error: TrainingDiverged


def population_unsupported(cfgs: Sequence[ExperimentConfig]) -> str | None:
    """Why ``cfgs`` cannot train as one population (one phrase), or None when they can."""
    if not cfgs:
        return "there are no trainings"
    first = cfgs[0]
    if first.task != "narma":
        return f"task {first.task!r} is not a held-window task (narma)"
    if first.brain.type != "lil":
        return f"brain {first.brain.type!r} is not an LIL"
    tc = first.training
    if tc.backend != "fused" or not tc.adjoint:
        return "training.backend is not fused with the adjoint"
    if tc.projection != "clamp" or tc.lr_decay:
        return "only the clamp projection without a learning-rate schedule is batched"
    if tc.optimizer not in ("sgd", "adam"):
        return f"optimizer {tc.optimizer!r}"
    if tc.checkpoint_every:
        return "training.checkpoint_every > 0 (members write their checkpoint at the end; the population its state)"
    base = {k: v for k, v in flatten_config(first.model_dump(mode="json")).items() if k not in MEMBER_KEYS}
    for i, cfg in enumerate(cfgs[1:], 1):
        other = {k: v for k, v in flatten_config(cfg.model_dump(mode="json")).items() if k not in MEMBER_KEYS}
        if other != base:
            diff = sorted(k for k in base.keys() | other.keys() if base.get(k) != other.get(k))
            return f"training {i} differs from the first in {', '.join(diff)}"
    return None


@dataclass
class _Group:
    """One learning-rate group of every member: its stacked parameters (B, ...) and their optimiser state."""

    name: str
    params: list[torch.Tensor]
    exp_avg: list[torch.Tensor] = field(default_factory=list)
    exp_avg_sq: list[torch.Tensor] = field(default_factory=list)


class _MemberOptimizer:
    """Member b's part of the population's optimiser, as :class:`UpdateGuard` handles an optimiser: its
    ``param_groups`` (views of the stacked parameters, the member's rates), and :meth:`state_dict` /
    :meth:`load_state_dict` of its optimiser state (Adam's moments and step count; SGD has none)."""

    def __init__(self, groups: list[_Group], steps: torch.Tensor, index: int, rates: dict[str, float]) -> None:
        self._groups, self._steps, self._b = groups, steps, index
        self.param_groups = [{"name": g.name, "params": [p[index] for p in g.params], "lr": rates[g.name]}
                             for g in groups]

    def state_dict(self) -> dict[str, Any]:
        b = self._b
        return {"param_groups": [{"lr": g["lr"]} for g in self.param_groups], "step": float(self._steps[b]),
                "exp_avg": [[t[b] for t in g.exp_avg] for g in self._groups],
                "exp_avg_sq": [[t[b] for t in g.exp_avg_sq] for g in self._groups]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        b = self._b
        for group, saved in zip(self.param_groups, state["param_groups"]):
            group["lr"] = saved["lr"]
        self._steps[b] = state["step"]
        with torch.no_grad():
            for g, m, v in zip(self._groups, state["exp_avg"], state["exp_avg_sq"]):
                for t, x in zip(g.exp_avg, m):
                    t[b].copy_(x)
                for t, x in zip(g.exp_avg_sq, v):
                    t[b].copy_(x)


#: the stacked parameters of a population, by attribute
STACKED = ("k", "d", "l", "weight", "bias")


class _Population:
    """The stacked parameters of B agents of one topology (an LIL brain each) and their optimiser."""

    def __init__(self, agents: Sequence[Agent], cfg: ExperimentConfig) -> None:
        body = agents[0].body
        self.body, self.cfg = body, cfg
        self.mask = force_inputs(body)
        # the hyperparameters of the optimiser train() builds (torch's defaults), and what this step implements
        defaults = make_optimizer(agents[0], cfg.training).defaults
        plain = {"weight_decay": 0, "maximize": False, "amsgrad": False, "momentum": 0, "dampening": 0,
                 "nesterov": False}
        odd = {k: defaults[k] for k, v in plain.items() if k in defaults and defaults[k] != v}
        if odd:
            raise ValueError(f"cannot train as one population: optimiser settings {odd}")
        self.betas, self.eps = defaults.get("betas", (0.9, 0.999)), float(defaults.get("eps", 1e-8))

        def stack(get: Any) -> torch.Tensor:
            return torch.stack([get(a).detach() for a in agents]).clone().requires_grad_(True)

        self.k, self.d, self.l = (stack(lambda a, n=n: getattr(a.body, n)) for n in ("k", "d", "l"))
        self.weight = stack(lambda a: a.brain.weight)
        self.bias = stack(lambda a: a.brain.bias)
        named = {"k": [self.k], "d": [self.d], "l": [self.l], "brain": [self.weight, self.bias]}
        lr = cfg.training.lr
        self.rates0 = {name: float(getattr(lr, name)) for name in named}
        self.adam = cfg.training.optimizer == "adam"
        self.groups = [_Group(name, ps) for name, ps in named.items() if self.rates0[name] > 0]
        if self.adam:
            for g in self.groups:
                g.exp_avg = [torch.zeros_like(p, requires_grad=False) for p in g.params]
                g.exp_avg_sq = [torch.zeros_like(p, requires_grad=False) for p in g.params]
        self.steps = torch.zeros(len(agents), dtype=torch.float64)
        self.members = [_MemberOptimizer(self.groups, self.steps, b, self.rates0) for b in range(len(agents))]

    def params(self) -> list[torch.Tensor]:
        return [p for g in self.groups for p in g.params]

    def forward(self, u: np.ndarray, targets: np.ndarray, washout: int,
                train_end: int) -> tuple[torch.Tensor, PopulationWindow]:
        """The episode of every member for inputs u (B, K) and targets (B, K): the losses (B,) [m²]
        (differentiable) and the window (final states, soundness)."""
        body, n = self.body, self.cfg.narma
        dtype = body.l.dtype
        x = brain_input(torch.as_tensor(u, dtype=dtype).unsqueeze(-1), n)  # (B, K, 1)
        out = torch.baddbmm(self.bias.unsqueeze(1), x, self.weight.transpose(1, 2))  # (B, K, O)
        blocks = out.new_zeros((*out.shape[:2], body.n_movable, 2))
        blocks[:, :, self.mask, :] = out.view(*out.shape[:2], -1, 2)
        r0 = body.positions0[body.movable_index].expand(len(u), -1, -1)
        v0 = torch.zeros_like(r0)
        a0, _ = body.acceleration(r0, v0, self.l, blocks[:, 0], k=self.k, d=self.d)
        win = population_readout(body, r0, v0, a0, self.k, self.d, self.l, blocks, n.tau, body.cmp_local, 1)
        y = torch.as_tensor(targets, dtype=dtype)
        sl = slice(washout, train_end)
        return ((win.y[:, sl] - y[:, sl]) ** 2).mean(dim=1), win

    def gradients_finite(self) -> np.ndarray:
        """(B,) bool: every gradient of member b is finite."""
        ok = np.ones(self.k.shape[0], dtype=bool)
        for p in self.params():
            if p.grad is not None:
                ok &= torch.isfinite(p.grad).reshape(p.shape[0], -1).all(dim=1).numpy()
        return ok

    def step(self, accepted: np.ndarray) -> None:
        """One SGD or Adam step of the accepted members (each at its own rates), then k, d, l clamped to ≥ 0."""
        acc = torch.as_tensor(accepted)
        b1, b2 = self.betas
        with torch.no_grad():
            if self.adam:
                self.steps += acc.double()
                # as torch's Adam: the bias corrections in Python floats from the member's step count
                # (a member that has not stepped yet does not step now: 1 keeps its unused row finite)
                counts = self.steps.tolist()
                bc1 = [1 - b1 ** s if s else 1.0 for s in counts]
                bc2_sqrt = torch.tensor([(1 - b2 ** s) ** 0.5 if s else 1.0 for s in counts], dtype=torch.float64)
            for gi, g in enumerate(self.groups):
                rates = [m.param_groups[gi]["lr"] for m in self.members]
                for pi, p in enumerate(g.params):
                    view = (-1,) + (1,) * (p.dim() - 1)
                    keep = acc.view(view)
                    grad = torch.where(keep, p.grad, torch.zeros((), dtype=p.dtype))
                    if self.adam:
                        m, v = g.exp_avg[pi], g.exp_avg_sq[pi]
                        m.copy_(torch.where(keep, m.lerp(grad, 1 - b1), m))
                        v.copy_(torch.where(keep, torch.addcmul(v * b2, grad, grad, value=1 - b2), v))
                        denom = (v.sqrt() / bc2_sqrt.to(p.dtype).view(view)).add_(self.eps)
                        step = torch.tensor([-lr / c for lr, c in zip(rates, bc1)], dtype=torch.float64)
                        new = p + (step.to(p.dtype).view(view) * m) / denom  # addcdiv: (value · m) / denom
                    else:  # add_(grad, alpha=−lr) is one fused multiply-add, as addcmul is
                        new = torch.addcmul(p, grad, torch.tensor(rates, dtype=torch.float64).neg().to(p.dtype)
                                            .view(view))
                    p.copy_(torch.where(keep, new, p))
            for p in (self.k, self.d, self.l):
                p.clamp_(min=0.0)

    def write_back(self, b: int, agent: Agent) -> None:
        """Member b's parameters into its agent."""
        with torch.no_grad():
            for src, dst in ((self.k, agent.body.k), (self.d, agent.body.d), (self.l, agent.body.l),
                             (self.weight, agent.brain.weight), (self.bias, agent.brain.bias)):
                dst.copy_(src[b])

    def torch_optimizer_state(self, agent: Agent, member_state: dict[str, Any]) -> dict[str, Any]:
        """A member's optimiser state (:meth:`_MemberOptimizer.state_dict`) as the state_dict of the torch optimiser
        ``train`` builds for ``agent`` (so ``train(resume=True)`` continues the member's run)."""
        opt = make_optimizer(agent, self.cfg.training)
        for group, saved in zip(opt.param_groups, member_state["param_groups"]):
            group["lr"] = saved["lr"]
        if self.adam and member_state["step"] > 0:
            for group, m_list, v_list in zip(opt.param_groups, member_state["exp_avg"], member_state["exp_avg_sq"]):
                for p, m, v in zip(group["params"], m_list, v_list):
                    opt.state[p] = {"step": torch.tensor(member_state["step"]),
                                    "exp_avg": m.detach().clone(), "exp_avg_sq": v.detach().clone()}
        return opt.state_dict()


class _PopulationUpdates:
    """One update of every member for :meth:`UpdateLoop.batched`: each member's inputs from its own stream, one
    batched episode, one backward of the members still training whose loss is finite (their gradients), and the
    step of the accepted members."""

    def __init__(self, pop: _Population, tasks: Sequence[NarmaTask], steps_per_update: int) -> None:
        self.pop, self.tasks, self.steps_per_update = pop, tasks, steps_per_update

    def measure(self, update: int, active: Sequence[bool]) -> list[Measured]:
        pop, n = self.pop, self.pop.cfg.narma
        u = np.stack([t.rng.uniform(0.0, 1.0, n.n_inputs) for t in self.tasks])  # each member's own stream
        y = np.stack([t.target(x) for t, x in zip(self.tasks, u)])
        for p in pop.params():
            p.grad = None
        loss, win = pop.forward(u, y, n.washout, n.train_end)
        values = loss.detach().double().numpy()
        finite = np.isfinite(values) & win.sound & np.asarray(active, dtype=bool)
        torch.where(torch.as_tensor(finite), loss, torch.zeros((), dtype=loss.dtype)).sum().backward()
        grads_ok = pop.gradients_finite()
        out = []
        for b, live in enumerate(active):
            failure = None
            if live and not win.sound[b]:
                failure = diverged_message(self.steps_per_update, pop.body.dt, _ranges(pop, b))
            out.append(Measured(value=float(values[b]) if failure is None else None,
                                grads_finite=bool(grads_ok[b]), failure=failure, fused=True))
        return out

    def step(self, accepted: Sequence[bool]) -> None:
        self.pop.step(np.asarray(accepted, dtype=bool))

    def advance(self, finite: Sequence[bool]) -> None:
        del finite  # each member's task draws its own inputs; no state is carried between updates


def _ranges(pop: _Population, b: int) -> str:
    """Member b's ``k in [lo, hi], d in [..], l in [..]`` (:meth:`MSDN.parameter_ranges`)."""
    return parameter_ranges(pop.k[b], pop.d[b], pop.l[b])


def train_population(cfgs: Sequence[ExperimentConfig], run_dirs: Sequence[str | Path | None], *,
                     overwrite: bool = False, progress: bool = True, desc: str = "population",
                     state_path: str | Path | None = None, save_every_s: float = 600.0,
                     stale_state: str = "refuse") -> tuple[list[TrainResult | None], list[MemberFailure]]:
    """Train every config of ``cfgs`` (one member each) as one population; member b writes to ``run_dirs[b]``
    (None: in memory) what :func:`~bptsb_ros.workflows.train.train` writes.

    ``state_path``: the whole population's state is saved there every ``save_every_s`` wall seconds, and a
    population started with a state file there continues from it to the numbers of an uninterrupted run (its
    member directories may then hold the files of the interrupted attempt); a state of other configs is refused,
    or with ``stale_state="discard"`` removed first (for a caller that owns the file). The file is removed once
    every member's files are written. Members write their checkpoint at the end only.

    Returns ``(results, failures)``: ``results[b]`` the member's :class:`TrainResult` (None where it failed);
    ``failures`` the members that diverged beyond their guard, with the error their solo training raises.

    Raises:
        ValueError: the configs cannot train as one population (:func:`population_unsupported`), or the body
            has no lane kernel (ground).
        ConfigError: a run directory holds something and ``overwrite`` is False; the state at ``state_path`` is
            another population's or unreadable.
        RunDirLocked: another process holds one of the run directories.
    """
    why = population_unsupported(cfgs)
    if why:
        raise ValueError(f"cannot train as one population: {why}")
    if len(run_dirs) != len(cfgs):
        raise ValueError(f"{len(cfgs)} configs but {len(run_dirs)} run directories")
    if stale_state not in ("refuse", "discard"):
        raise ValueError(f"stale_state must be 'refuse' or 'discard', got {stale_state!r}")
    state = None if state_path is None else Path(state_path)
    resuming = False
    if state is not None and state.is_file():
        resuming = _state_matches(state, cfgs)
        if not resuming and stale_state == "discard":
            state.unlink()
    with ExitStack() as stack:
        dirs: list[Path | None] = []
        for d in run_dirs:
            if d is None:
                dirs.append(None)
                continue
            path = Path(d)
            stack.enter_context(hold_run_dir(path))
            if not overwrite and not resuming and not dir_is_empty(path):
                raise ConfigError(f"{path} already holds a run (or other files); replace it with overwrite or "
                                  "choose another directory")
            dirs.append(path)
        results = _train(list(cfgs), dirs, progress=progress, desc=desc, state_path=state, save_every_s=save_every_s)
        if state is not None:
            state.unlink(missing_ok=True)  # every member's own files are written: it is not needed
        return results


def _train(cfgs: list[ExperimentConfig], dirs: list[Path | None], *, progress: bool, desc: str,
           state_path: Path | None, save_every_s: float) -> tuple[list[TrainResult | None], list[MemberFailure]]:
    from bptsb_ros.agent import body_backend

    cfg0 = cfgs[0]
    threads = configure_threads(1, body_backend(cfg0.training.backend))
    agents, tasks = [], []
    for cfg in cfgs:  # each member's agent and task as train() builds them
        torch.manual_seed(cfg.seed)
        agent = build_agent(cfg)
        if not isinstance(agent.brain, LinearInputLayer):
            raise ValueError("cannot train as one population: the brain is not an LIL")
        agents.append(agent)
        tasks.append(NarmaTask(agent, cfg))
        tasks[-1].prepare()
    body = agents[0].body
    why = held_window_unsupported(body) or lanes_unsupported(body)
    if why:
        raise ValueError(f"cannot train as one population: {why}")
    for d, agent in zip(dirs, agents):
        if d is not None:
            write_atomic(d / "config.yaml", yaml.safe_dump(agent.config, sort_keys=False))
    pop = _Population(agents, cfg0)
    tc, n = cfg0.training, cfg0.narma
    # the trainer's update loop, one guard per member (its rules, events and rate divisions a training's alone);
    # its log lines go to the progress bar made below, once the resumed update is known: a guard logs only when it
    # reviews an update, never while the state is loaded
    loop = UpdateLoop.batched(pop.members, GuardRules(factor=tc.reject_factor, patience=tc.reject_patience),
                              log=lambda b, line: bar.write(f"training {b}: {line}"))
    guards, active = loop.guards, loop.active
    failures: list[MemberFailure] = []
    steps_per_update = n.n_inputs * n.tau
    start, before = 0, 0.0  # the update to start at, training seconds of earlier attempts
    if state_path is not None and state_path.is_file():
        start, before = _load_state(state_path, cfgs, pop, guards, tasks, active, failures)

    def median_loss() -> float | None:
        live = [g.history[-1] for g, a in zip(guards, active) if a]
        return float(np.median(live)) if live else None

    bar = ProgressBar(cfg0.epochs, f"{desc} ({len(cfgs)} trainings)", median_loss, enabled=progress, start=start,
                      log_every=tc.log_every, quiet_every_s=60.0, refresh=False)  # refresh: at the next timed one
    if start:
        bar.write(f"{desc}: resuming the population at update {start} of {cfg0.epochs} ({state_path})")

    class Stopped(Callback):
        """A member the guard cannot undo: its ``diverged.json`` and error, as ``train`` words them."""

        def on_stopped(self, stop: LoopStopped) -> None:
            b = stop.member
            assert b is not None
            failures.append(MemberFailure(b, _member_diverged(dirs[b], stop.update, stop.report(_ranges(pop, b)),
                                                              guards[b], _ranges(pop, b))))

    t_start = time.perf_counter()
    callbacks: list[Callback] = [Stopped(), bar]
    if state_path is not None:
        def save(update: int) -> None:
            if update + 1 < cfg0.epochs:
                _save_state(state_path, cfgs, pop, guards, tasks, active, failures, update + 1,
                            before + time.perf_counter() - t_start)

        callbacks.append(Periodically(save_every_s, save, since=t_start))
    try:
        loop.run(_PopulationUpdates(pop, tasks, steps_per_update), range(start, cfg0.epochs), callbacks=callbacks)
    finally:
        bar.close()
    elapsed = before + time.perf_counter() - t_start
    results: list[TrainResult | None] = []
    for b, (cfg, agent, task, guard, d) in enumerate(zip(cfgs, agents, tasks, guards, dirs)):
        if not active[b]:
            results.append(None)
            continue
        pop.write_back(b, agent)
        metrics = training_metrics(cfg, guard, elapsed, cfg.epochs * steps_per_update, threads, tc.backend,
                                   population={"members": len(cfgs), "index": b})
        try:
            with torch.no_grad():
                metrics["evaluation"] = task.evaluate()
        except SimulationDiverged as err:  # as train(): the final parameters never completed a held-out run
            failures.append(MemberFailure(b, _member_diverged(d, cfg.epochs, f"evaluation: {err}", guard,
                                                              agent.body.parameter_ranges())))
            results.append(None)
            continue
        files: list[Path] = []
        if d is not None:
            gstate = guard.state_dict()
            gstate["saved"] = {**gstate["saved"],
                               "optimizer": pop.torch_optimizer_state(agent, gstate["saved"]["optimizer"])}
            save_checkpoint(d, agent, {"optimizer": pop.torch_optimizer_state(agent, pop.members[b].state_dict()),
                                       "task_state": task.state_dict(), "losses": guard.history,
                                       "update": cfg.epochs, "guard": gstate, "feedback_fitted": False})
            files = write_outputs(d, task, metrics)
        results.append(TrainResult(d, guard.history, metrics, files, agent, None))
    return results, failures


STATE_FORMAT = 1


def _save_state(path: Path, cfgs: Sequence[ExperimentConfig], pop: _Population, guards: Sequence[UpdateGuard],
                tasks: Sequence[Task], active: list[bool], failures: list[MemberFailure], update: int,
                seconds: float) -> None:
    """Everything the population needs to go on from ``update`` (plain data and tensors: ``weights_only``)."""
    state = {"format": STATE_FORMAT, "configs": [c.model_dump(mode="json") for c in cfgs], "update": update,
             "seconds": seconds, "params": {n: getattr(pop, n).detach().clone() for n in STACKED},
             "steps": pop.steps.clone(), "moments": [[*g.exp_avg, *g.exp_avg_sq] for g in pop.groups],
             "rates": [[g["lr"] for g in m.param_groups] for m in pop.members],
             "guards": [g.state_dict() for g in guards], "rngs": [t.rng.bit_generator.state for t in tasks],
             "active": list(active), "failures": [[f.index, str(f.error)] for f in failures]}
    with atomic_writer(path) as f:
        torch.save(state, f)


def _read_state(path: Path) -> Any:
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unreadable file is reported the same way
        raise ConfigError(f"{path}: not a readable population state ({type(err).__name__}: {err}); remove it to "
                          "start the population afresh") from None


def _state_matches(path: Path, cfgs: Sequence[ExperimentConfig]) -> bool:
    """The state at ``path`` is of this population (format and every member's config)."""
    try:
        state = _read_state(path)
    except ConfigError:
        return False
    return (isinstance(state, dict) and state.get("format") == STATE_FORMAT
            and state.get("configs") == [c.model_dump(mode="json") for c in cfgs])


def _load_state(path: Path, cfgs: Sequence[ExperimentConfig], pop: _Population, guards: Sequence[UpdateGuard],
                tasks: Sequence[Task], active: list[bool], failures: list[MemberFailure]) -> tuple[int, float]:
    """Restore a state :func:`_save_state` wrote; returns (the update to go on from, seconds trained so far)."""
    state = _read_state(path)
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT or \
            state.get("configs") != [c.model_dump(mode="json") for c in cfgs]:
        raise ConfigError(f"{path} is the state of another population (other trainings or configs); remove it to "
                          "start this one afresh")
    try:  # untrusted data: a state this very population could have saved, before any of it is used
        _check_state(state, cfgs, pop, guards, tasks)
    except ResumeStateError as err:
        raise ConfigError(f"{path} is not a state this population could have saved ({err}); remove it to start the "
                          "population afresh") from None
    with torch.no_grad():
        for n in STACKED:
            getattr(pop, n).copy_(state["params"][n])
        pop.steps.copy_(state["steps"])
        for g, saved in zip(pop.groups, state["moments"]):
            for t, x in zip([*g.exp_avg, *g.exp_avg_sq], saved):
                t.copy_(x)
    for m, rates in zip(pop.members, state["rates"]):
        for group, lr in zip(m.param_groups, rates):
            group["lr"] = lr
    for g, gs in zip(guards, state["guards"]):
        g.load_state_dict(gs)
    for t, rs in zip(tasks, state["rngs"]):
        t.rng.bit_generator.state = rs
    active[:] = state["active"]
    failures.extend(MemberFailure(int(i), TrainingDiverged(msg)) for i, msg in state["failures"])
    return int(state["update"]), float(state["seconds"])


#: longest failure message kept from a state
MAX_MESSAGE = 4000


def _check_state(state: dict, cfgs: Sequence[ExperimentConfig], pop: _Population, guards: Sequence[UpdateGuard],
                 tasks: Sequence[Task]) -> None:
    """Raise :class:`ResumeStateError` unless ``state`` is one :func:`_save_state` could have written for this
    population (:mod:`~bptsb_ros.training.resume_checks`): every entry present with the population's shapes, finite,
    the update within 0 … epochs, each member's rates in (0, its config rate], step counts and loss histories that
    fit the update, its guard's counters within their rules, a random generator state numpy takes, and the stopped
    members exactly those with a recorded failure."""
    n = len(cfgs)
    missing = [k for k in ("update", "seconds", "params", "steps", "moments", "rates", "guards", "rngs", "active",
                           "failures") if k not in state]
    if missing:
        raise ResumeStateError(f"it lacks {', '.join(missing)}")
    update = check_whole(state["update"], "update", 0, cfgs[0].epochs)
    seconds = state["seconds"]
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not 0 <= seconds < float("inf"):
        raise ResumeStateError(f"seconds is {str(seconds)[:40]}, not a time ≥ 0")
    params = state["params"]
    check_like(params, {name: getattr(pop, name).detach() for name in STACKED}, "params")
    check_finite(params, "params")
    for name in ("k", "d", "l"):
        if bool((params[name] < 0).any()):
            raise ResumeStateError(f"params.{name} has a negative value; k, d and l are ≥ 0")
    steps = check_tensor(state["steps"], "steps", (n,), torch.float64)
    for b, count in enumerate(steps.tolist()):
        check_whole(count, f"steps[{b}]", 0, update)
    moments = state["moments"]
    if not isinstance(moments, list) or len(moments) != len(pop.groups):
        raise ResumeStateError(f"moments is not one list per parameter group ({len(pop.groups)})")
    for g, (group, saved) in enumerate(zip(pop.groups, moments)):
        fresh = [*group.exp_avg, *group.exp_avg_sq]
        if not isinstance(saved, list) or len(saved) != len(fresh):
            raise ResumeStateError(f"moments[{g}] is not {len(fresh)} tensors")
        for i, (x, t) in enumerate(zip(saved, fresh)):
            check_tensor(x, f"moments[{g}][{i}]", t.shape, t.dtype)
            check_finite(x, f"moments[{g}][{i}]")
            if i >= len(group.exp_avg) and bool((x < 0).any()):
                raise ResumeStateError(f"moments[{g}][{i}] (Adam's second moment) has a negative value")
    for key in ("rates", "guards", "rngs", "active"):
        if not isinstance(state[key], list) or len(state[key]) != n:
            raise ResumeStateError(f"{key} is not a list of one entry per member ({n})")
    active = state["active"]
    if not all(isinstance(a, bool) for a in active):
        raise ResumeStateError("active is not a list of true or false")
    for b, rates in enumerate(state["rates"]):
        if not isinstance(rates, list) or len(rates) != len(pop.groups):
            raise ResumeStateError(f"rates[{b}] is not one rate per parameter group ({len(pop.groups)})")
        for group, lr in zip(pop.groups, rates):
            check_rate(lr, f"rates[{b}] ({group.name})", pop.rates0[group.name])
    for b, (guard, saved) in enumerate(zip(guards, state["guards"])):
        check_guard(saved, f"guards[{b}]", patience=guard.patience, reset_after=RESET_AFTER,
                    params=[p[b] for g in pop.groups for p in g.params], updates=update if active[b] else None,
                    check_optimizer=lambda s, w, b=b: _check_member_optimizer(s, w, pop, b, update))
        if len(saved["history"]) > update:
            raise ResumeStateError(f"guards[{b}].history holds {len(saved['history'])} losses, more than the "
                                   f"{update} updates")
    for b, (task, rng) in enumerate(zip(tasks, state["rngs"])):
        probe = type(task.rng.bit_generator)()
        try:
            probe.state = rng
        except (ValueError, TypeError, KeyError) as err:
            raise ResumeStateError(f"rngs[{b}] is not a state of the member's random generator ({err})") from None
    failures = state["failures"]
    if not isinstance(failures, list) or not all(
            isinstance(f, (list, tuple)) and len(f) == 2 and isinstance(f[0], int) and not isinstance(f[0], bool)
            and isinstance(f[1], str) and len(f[1]) <= MAX_MESSAGE for f in failures):
        raise ResumeStateError("failures is not a list of [member, message] pairs")
    failed = [f[0] for f in failures]
    stopped = [b for b in range(n) if not active[b]]
    if len(set(failed)) != len(failed) or sorted(failed) != stopped:
        raise ResumeStateError(f"the stopped members {stopped} are not those with a recorded failure "
                               f"{sorted(failed)[:10]}")


def _check_member_optimizer(saved: Any, where: str, pop: _Population, b: int, update: int) -> None:
    """A member's optimiser state as :meth:`_MemberOptimizer.state_dict` makes it (rates, step count, moments)."""
    if not isinstance(saved, dict) or not isinstance(saved.get("param_groups"), list) \
            or len(saved["param_groups"]) != len(pop.groups):
        raise ResumeStateError(f"{where} is not a member's optimiser state ({len(pop.groups)} parameter groups)")
    for group, saved_group in zip(pop.groups, saved["param_groups"]):
        check_rate(saved_group.get("lr") if isinstance(saved_group, dict) else None, f"{where} ({group.name})",
                   pop.rates0[group.name])
    check_whole(saved.get("step"), f"{where}.step", 0, update)
    fresh = pop.members[b].state_dict()
    for key in ("exp_avg", "exp_avg_sq"):
        lists = saved.get(key)
        if not isinstance(lists, list) or len(lists) != len(fresh[key]):
            raise ResumeStateError(f"{where}.{key} is not one list per parameter group")
        for i, (got, want) in enumerate(zip(lists, fresh[key])):
            if not isinstance(got, list) or len(got) != len(want):
                raise ResumeStateError(f"{where}.{key}[{i}] is not {len(want)} tensors")
            for j, (x, t) in enumerate(zip(got, want)):
                check_tensor(x, f"{where}.{key}[{i}][{j}]", t.shape, t.dtype)
                check_finite(x, f"{where}.{key}[{i}][{j}]")


def _member_diverged(run_dir: Path | None, update: int, why: str, guard: UpdateGuard,
                     ranges: str) -> TrainingDiverged:
    """Record a member that cannot continue (``diverged.json``) and build its error, as ``train`` words it."""
    if run_dir is None:
        return TrainingDiverged(f"update {update}: {why} (trained in memory: nothing was written)")
    report = {"update": update, "error": why, "losses": guard.history, "parameters": ranges,
              "last_good_update": None, "guard": guard.summary(), "population": True}
    write_atomic(run_dir / "diverged.json", json.dumps(report, indent=2))
    return TrainingDiverged(f"update {update}: {why} (a population member: no checkpoint is kept; details in "
                            f"{run_dir / 'diverged.json'})")

