"""Trained Lissajous agents shared by the autonomy experiments: the single-curve SWG agent (preliminary
training, feedback layer fitted) and its state on the trained limit cycle, ready for populations."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.msdn import BodyState
from bptsb_ros.experiments.common import packaged_config
from bptsb_ros.tasks.switching import CURVE_1, Curve


@contextmanager
def torch_threads(n: int = 1) -> Iterator[None]:
    """Run a block with ``n`` torch threads (restored after). The paper's bodies are tiny: on a shared
    machine more threads than free cores make each step 50× slower (measured: 0.7 ms → 53 ms per step of a
    2-row batch on 2 busy cores), and one thread is as fast as two for batches up to ~1,000 rows."""
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def single_threaded(fn: Callable[..., None]) -> Callable[..., None]:
    """Decorator: run an experiment with one torch thread (see :func:`torch_threads`)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with torch_threads(1):
            return fn(*args, **kwargs)

    return wrapper


@dataclass
class TrainedAgent:
    """agent: parameters frozen; state: the body state (B = 1) where training ended, on the trained cycle;
    metrics: the training run's metrics.json content."""

    agent: Agent
    state: BodyState
    metrics: dict[str, Any]
    run_dir: Path

    @property
    def period(self) -> int:
        """Steps per SWG period."""
        return int(round(2 * math.pi / self.agent.brain.omega / self.agent.dt))

    @property
    def amplitude(self) -> float:
        cfg = self.agent.config
        return float(cfg["lissajous"]["amplitude_fraction"]) * float(cfg["body"]["size"])

    @property
    def omega(self) -> float:
        return float(self.agent.brain.omega)


def train_single_curve(run_dir: Path, *, sim_time: float, seed: int, curve: Curve = CURVE_1,
                       fit_time: float = 100.0, eval_periods: int = 10, progress: bool = False,
                       extra: Mapping[str, Any] | None = None) -> TrainedAgent:
    """Preliminary training: SWG + double-circle (N_mov 13) drawing ``curve`` with the paper's single-curve
    learning rates (config/lissajous_single.yaml), the FL fitted; the agent and its final state."""
    from bptsb_ros.workflows.train import train

    cfg = packaged_config("lissajous_single", {
        "sim_time": sim_time, "feedback.fit_time": fit_time, "lissajous.eval_periods": eval_periods,
        "lissajous.alpha": curve.alpha, "lissajous.beta": curve.beta, "lissajous.delta": curve.delta,
        **(extra or {})}, seed=seed)
    res = train(cfg, run_dir, overwrite=True, progress=progress)  # the experiment (or its job) owns run_dir
    return load_trained(run_dir, res.metrics)


def load_trained(run_dir: Path, metrics: dict[str, Any]) -> TrainedAgent:
    """Agent and final training state of a finished run directory."""
    from bptsb_ros.training.checkpoint import load_agent, read_checkpoint

    agent = load_agent(run_dir)
    s = read_checkpoint(run_dir)["extra"]["task_state"]
    state = BodyState(s["r"], s["v"], s["a"], s["length"], int(s["step"]))
    return TrainedAgent(agent, state, metrics, Path(run_dir))


def repeat_state(state: BodyState, batch: int) -> BodyState:
    """A (1, ...) state repeated to ``batch`` identical rows."""
    return BodyState(*(x.expand(batch, *x.shape[1:]).clone() for x in (state.r, state.v, state.a, state.length)),
                     state.step)


