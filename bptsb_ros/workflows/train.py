"""The BPTSB training loop: truncated windows, per-parameter learning rates, projection onto
non-negative body parameters, the update guard (:mod:`bptsb_ros.training.guard`), checkpoints, metrics,
progress. With a run directory (``bptsb train --out``) it writes checkpoints, metrics and plots there; without
one it trains in memory and writes nothing (the Python API, :func:`bptsb_ros.train`)."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import yaml

from bptsb_ros.agent import Agent, body_backend, build_agent
from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.body.threads import configure_threads
from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.config import ConfigError, ExperimentConfig
from bptsb_ros.files.run_dir_lock import dir_is_empty, hold_run_dir
from bptsb_ros.files.safe_write import json_text, write_atomic
from bptsb_ros.tasks import get_task
from bptsb_ros.training.callbacks import (
    LastGoodCheckpoints,
    LossCallback,
    ProgressBar,
    SimSteps,
    optimizer_and_task_state,
)
from bptsb_ros.training.checkpoint import CheckpointError, checkpoint_path, read_checkpoint, save_checkpoint
from bptsb_ros.training.feedback_fit import fit_feedback
from bptsb_ros.training.fused import fused_training
from bptsb_ros.training.guard import RESET_AFTER, UpdateGuard
from bptsb_ros.training.loop import GuardRules, LoopStopped, Measured, UpdateLoop
from bptsb_ros.training.optim import make_optimizer, step_decay_updates
from bptsb_ros.training.resume_checks import ResumeStateError, check_resume_checkpoint


class TrainingDiverged(RuntimeError):
    """Training stopped because the simulation or the loss diverged."""


@dataclass
class TrainResult:
    """What :func:`train` returns.

    Attributes:
        run_dir: the run directory written, or None (trained in memory).
        losses: the loss curve, one entry per update (a rejected update repeats the previous entry).
        metrics: the content of ``metrics.json`` (loss, guard, timing, ``evaluation``, ``feedback_fit``).
        files: the files written (empty in memory).
        agent: the trained agent (its feedback layer fitted for SWG agents).
        state: the body state where training ended (B = 1; SWG tasks: on the trained cycle), or None for
            episodic tasks.
    """

    run_dir: Path | None
    losses: list[float]
    metrics: dict[str, Any]
    files: list[Path] = field(default_factory=list)
    agent: Agent | None = None
    state: BodyState | None = None

#: ``callback(update, loss)`` of :func:`train`: the update's index and its entry of the loss curve
UpdateCallback = Callable[[int, float], None]


def train(
    cfg: ExperimentConfig,
    run_dir: str | Path | None,
    *,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    init_from: str | Path | None = None,
    callback: UpdateCallback | None = None,
) -> TrainResult:
    """Train ``cfg``'s agent, writing checkpoint.pt, config.yaml, metrics.json and plots to ``run_dir``.

    ``run_dir`` None trains in memory: nothing is written (no checkpoint, no plots, no ``diverged.json``), and
    the trained agent is in the result as it is with a run directory. ``callback(update, loss)`` is called
    after every update with its index and its entry of the loss curve.

    ``run_dir`` must not hold anything yet unless ``resume`` (continue the run saved there; a missing run
    is an error that creates nothing) or ``overwrite`` (replace it). The checkpoint only ever holds
    parameters that completed a training window without divergence ("last good"): a checkpoint due
    after update i is written once window i+1 ran with those parameters, and a run that diverges writes
    its last good state (also with ``checkpoint_every: 0``) before it stops.

    Every update goes through the :class:`~bptsb_ros.training.guard.UpdateGuard`: window i's loss, measured with
    the parameters the previous update produced, is judged before the step from it; a diverged window, a
    non-finite loss or gradient, or (``training.reject_factor`` > 0) a loss above factor × the previous loss (the
    mean of the last 5 once there are 5) restores the parameters and optimiser state from before the previous
    update and skips the step; after ``training.reject_patience`` rejections (two good updates in a row reset the
    count) every learning rate is divided by 10. A rejected update repeats the previous entry of the loss curve;
    the events are in ``metrics.json`` (``guard``). A numerical failure that no restore can undo (no update since
    the start or the last restore) ends the training as diverged.

    ``init_from``: a trained run directory of the same task and body whose parameters and carried body state
    this training continues from (additional training, e.g. headwind switching after forward locomotion); the
    optimiser and the losses start afresh. Ignored when resuming.

    Raises:
        ConfigError: ``run_dir`` holds a run (neither ``resume`` nor ``overwrite``), the config differs
            from the resumed run's, or ``resume`` without a run directory.
        CheckpointError: ``resume`` without a readable checkpoint.
        TrainingDiverged: the simulation or the loss diverged and the guard had nothing to undo, or the
            final evaluation diverged.
        RunDirLocked: another bptsb process holds ``run_dir`` (:mod:`bptsb_ros.files.run_dir_lock`).
    """
    if run_dir is None:
        if resume:
            raise ConfigError("resume continues a run saved in a run directory; give one")
        return _train_locked(cfg, None, resume=False, overwrite=overwrite, progress=progress, init_from=init_from,
                             callback=callback)
    run_dir = Path(run_dir)
    if resume and not run_dir.is_dir():
        read_checkpoint(run_dir)  # raises before creating anything: a missing run leaves nothing behind
    if run_dir.exists() and not run_dir.is_dir():
        raise ConfigError(f"--out {run_dir} exists and is not a directory")
    with hold_run_dir(run_dir):  # RunDirLocked: another bptsb process works in run_dir; nothing was touched
        return _train_locked(cfg, run_dir, resume=resume, overwrite=overwrite, progress=progress,
                             init_from=init_from, callback=callback)


def _train_locked(cfg: ExperimentConfig, run_dir: Path | None, *, resume: bool, overwrite: bool, progress: bool,
                  init_from: str | Path | None, callback: UpdateCallback | None) -> TrainResult:
    """:func:`train` once this process holds ``run_dir``'s lock (``run_dir`` None: in memory, nothing to lock)."""
    payload = None
    if run_dir is not None:
        if resume:
            payload = read_checkpoint(run_dir)
        elif not overwrite and not dir_is_empty(run_dir):
            raise ConfigError(f"--out {run_dir} already holds a run (or other files); continue it with --resume, "
                              "replace it with --force, or choose another directory")
    title = f"train {cfg.name or cfg.task}"

    def phase(what: str) -> None:  # the phases around the bar take seconds each: one line says which one runs
        if progress:
            print(f"{title}: {what} ...", file=sys.stderr, flush=True)

    phase("building the agent, the task and the optimiser")  # torch's optimisers import torch._dynamo: seconds
    threads = configure_threads(1, body_backend(cfg.training.backend))  # every task trains one small body: one thread
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    task = get_task(cfg.task)(agent, cfg)
    optimizer = make_optimizer(agent, cfg.training)
    start = 0
    if payload is not None and run_dir is not None:
        _check_resumable(payload["config"], agent.config, run_dir)
        try:  # untrusted data: the state this very training could have saved, before any of it is used
            start = check_resume_checkpoint(payload, agent, task, optimizer, task.num_updates(),
                                            patience=cfg.training.reject_patience, reset_after=RESET_AFTER)
        except ResumeStateError as err:
            raise CheckpointError(f"cannot resume from {checkpoint_path(run_dir)}: {err}") from None
        for name, module in agent.modules().items():
            module.load_state_dict(payload["modules"][name])
        extra = payload["extra"]
        optimizer.load_state_dict(extra["optimizer"])
        try:
            task.load_state_dict(extra["task_state"])
        except (ValueError, TypeError, KeyError) as err:  # e.g. a random generator's state numpy refuses
            raise CheckpointError(f"cannot resume from {checkpoint_path(run_dir)}: extra.task_state: {err}") from None
    elif init_from is not None:
        payload = read_checkpoint(init_from)
        if payload["config"].get("task") != cfg.task:
            raise ConfigError(f"cannot continue from {init_from}: it trained task {payload['config'].get('task')!r}, "
                              f"not {cfg.task!r}")
        try:
            for name, module in agent.modules().items():
                if name in payload["modules"]:
                    module.load_state_dict(payload["modules"][name])
        except RuntimeError as err:  # shapes differ: another body or brain
            raise ConfigError(f"cannot continue from {init_from}: its agent differs ({err})") from None
        if "task_state" in payload["extra"]:
            task.load_state_dict(payload["extra"]["task_state"])
    if run_dir is not None:
        write_atomic(run_dir / "config.yaml", yaml.safe_dump(agent.config, sort_keys=False))

    total = task.num_updates()
    tc = cfg.training
    loop = UpdateLoop(optimizer, GuardRules(factor=tc.reject_factor, patience=tc.reject_patience),
                      log=lambda line: bar.write(line))
    guard = loop.guard
    if resume:
        extra = payload["extra"]
        if "guard" in extra:
            guard.load_state_dict(extra["guard"])
        else:  # a checkpoint from before the guard: its losses, nothing to undo
            guard.history[:] = [float(x) for x in extra["losses"]]
            guard.count = int(extra.get("rejections", 0))
    losses = guard.history  # the loss curve: a rejected update repeats the previous entry
    fused, backend = None, tc.backend
    if tc.backend == "fused" and not task.fused_episodes:
        fused, why = ((None, "the projection reset is not in the fused kernel (clamp only)")
                      if tc.projection != "clamp" else fused_training(task, optimizer, adjoint=tc.adjoint))
        if fused is None:
            backend = "numba"
            print(f"training.backend fused: {why}; training on the numba path instead", file=sys.stderr)
    fallback = {"backend_fallback": why} if backend != tc.backend else {}
    task.prepare()
    t_start = time.perf_counter()
    bar = ProgressBar(total, title, losses, enabled=progress, start=start, log_every=tc.log_every)
    steps = SimSteps(getattr(task, "steps_per_update", tc.update_steps))
    # checkpoints hold parameters that completed a window without divergence (written when due and good)
    kept = LastGoodCheckpoints(run_dir, agent, agent.modules, optimizer_and_task_state(optimizer, task), guard,
                               start=start, every=tc.checkpoint_every)

    def checkpoint(update: int, **more: Any) -> None:
        if run_dir is None:
            return
        save_checkpoint(run_dir, agent, {"optimizer": optimizer.state_dict(), "task_state": task.state_dict(),
                                         "losses": losses, "update": update, "guard": guard.state_dict(), **more})

    def diverged(update: int, why: str) -> TrainingDiverged:
        """Write the last good state (parameters that completed a window), record the failure, build the error."""
        if run_dir is None:
            return TrainingDiverged(f"update {update}: {why} (trained in memory: nothing was written)")
        if kept.save_good():
            note = (f"the last good checkpoint, update {kept.good_update}, is kept: parameters that completed a "
                    "window without diverging")
        elif (run_dir / "checkpoint.pt").is_file():
            note = "the earlier checkpoint is kept"
        else:
            note = "no checkpoint was saved: no window completed"
        report = {"update": update, "error": why, "losses": losses, "parameters": agent.body.parameter_ranges(),
                  "last_good_update": kept.good_update, "guard": guard.summary()}
        write_atomic(run_dir / "diverged.json", json.dumps(report, indent=2))
        return TrainingDiverged(f"update {update}: {why} ({note}; details in {run_dir / 'diverged.json'})")

    decay_at = set(step_decay_updates(total)) if tc.lr_decay else set()  # the published switching schedule
    objective = _TaskUpdates(task, optimizer, fused, tc.projection)
    callbacks = [steps, bar, *([LossCallback(callback, losses)] if callback is not None else []), kept]

    try:
        try:
            loop.run(objective, range(start, total), decay_at=decay_at, callbacks=callbacks)
        except LoopStopped as stop:
            raise diverged(stop.update, stop.report(agent.body.parameter_ranges())) from None
    finally:
        bar.close()
    elapsed = time.perf_counter() - t_start

    metrics = training_metrics(cfg, guard, elapsed, steps.steps, threads, backend, **fallback)
    try:
        with torch.no_grad():
            if isinstance(agent.brain, SineWaveGenerator) and agent.feedback is not None:
                phase(f"fitting the feedback layer on {cfg.feedback.fit_time:g} s of open-loop motion")
                metrics["feedback_fit"] = fit_feedback(agent, cfg.feedback, getattr(task, "state", None), cfg.seed)
                task.feedback_fitted = True
            phase("evaluating the trained agent")
            metrics["evaluation"] = task.evaluate()
    except SimulationDiverged as err:  # the final parameters never completed a window: keep the last good ones
        raise diverged(total, f"evaluation: {err}") from None
    if run_dir is not None:
        phase(f"writing the checkpoint, metrics and plots to {run_dir}")
    checkpoint(total, feedback_fitted=getattr(task, "feedback_fitted", False))
    files = [] if run_dir is None else write_outputs(run_dir, task, metrics)
    state = getattr(task, "state", None)
    return TrainResult(run_dir, losses, metrics, files, agent,
                       state.detach() if isinstance(state, BodyState) else None)


class _TaskUpdates:
    """A task's update for :class:`~bptsb_ros.training.loop.UpdateLoop`: ``task.update_loss(i)`` on the autograd
    path (the loss value measured too, for the last-good bookkeeping), or the fused window's loss and gradients in
    one compiled call; a diverged simulation is the measurement's ``failure``."""

    def __init__(self, task: Any, optimizer: torch.optim.Optimizer, fused: Any, projection: str) -> None:
        self.task, self.optimizer, self.fused, self.projection = task, optimizer, fused, projection

    def measure(self, update: int) -> Measured:
        m = Measured(fused=self.fused is not None)
        try:
            if self.fused is None:
                m.loss, _info = self.task.update_loss(update)
                m.value = float(m.loss.detach())
            else:  # loss and gradients in one compiled call, no autograd
                m.value, m.grads_finite = self.fused.update_loss(update)
        except SimulationDiverged as err:
            m.failure = str(err)
        return m

    def step(self) -> None:
        if self.fused is None:
            self.optimizer.step()
            self.task.agent.body.clamp_parameters_(self.projection)
        else:  # SGD of every group and the projection of k, d, l, in place in one call
            self.fused.step()

    def advance(self, finite: bool) -> None:
        del finite  # the task carries its own state (only a finite window's)


def training_metrics(cfg: ExperimentConfig, guard: UpdateGuard, seconds: float, sim_steps: int,
                     threads: dict[str, int], backend: str, **more: Any) -> dict[str, Any]:
    """The training part of ``metrics.json``: the loss curve (the guard's history), the guard's summary, the time
    [s] and its rate [steps/s], ``more`` (e.g. a backend fallback); the caller adds the evaluation."""
    return {"task": cfg.task, "name": cfg.name, "seed": cfg.seed, "loss": guard.history,
            "updates": len(guard.history), "guard": guard.summary(), "train_seconds": seconds, "backend": backend,
            **more, "threads": threads, "train_steps_per_second": sim_steps / seconds if seconds > 0 else None}


#: keys that may differ between a run and its resumption (durations, logging, the backend: equal to rounding)
RESUMABLE_CHANGES = {"sim_time", "epochs", "name", "training.checkpoint_every", "training.log_every",
                     "training.backend"}


def flatten_config(d: dict, prefix: str = "") -> dict[str, Any]:
    """A nested config dict as ``{"training.lr.k": value, ...}``."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        out.update(flatten_config(v, f"{key}.") if isinstance(v, dict) else {key: v})
    return out


def _check_resumable(saved: dict, new: dict, run_dir: Path) -> None:
    """The config given to --resume may extend the run (sim_time, epochs) but not change the experiment."""
    a, b = flatten_config(saved), flatten_config(new)
    changed = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k) and k not in RESUMABLE_CHANGES)
    if changed:
        raise ConfigError(f"cannot resume {run_dir}: the config differs from the checkpoint's in {', '.join(changed)}")


def write_outputs(run_dir: Path, task, metrics: dict[str, Any]) -> list[Path]:
    """``metrics.json``, the loss plot and the task's figures (:mod:`bptsb_ros.analysis.task_plots`) in ``run_dir``
    (under the figure lock)."""
    from bptsb_ros.analysis.plots import plot_loss
    from bptsb_ros.analysis.style import FIGURES
    from bptsb_ros.analysis.task_plots import task_figures

    write_atomic(run_dir / "metrics.json", json_text(metrics, indent=2))  # strict JSON: NaN is written null
    with FIGURES:
        files = [run_dir / "metrics.json", plot_loss(run_dir / "loss.png", metrics["loss"], task.loss_label,
                                                         metrics["name"])]
        files += task_figures(task, run_dir)
    return files

