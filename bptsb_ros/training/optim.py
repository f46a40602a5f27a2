"""Optimisers with one learning rate per parameter kind (paper: separate rates for k, d, l, A, φ and
the FNN weights) and the projection that keeps body parameters non-negative."""

from __future__ import annotations

import torch

from bptsb_ros.agent import Agent
from bptsb_ros.brains import SineWaveGenerator
from bptsb_ros.config import TrainingConfig


def parameter_groups(agent: Agent, cfg: TrainingConfig) -> list[dict]:
    """Optimiser groups named after the learning-rate keys; a zero rate freezes that kind."""
    lr = cfg.lr
    body = agent.body
    groups = [
        {"name": "k", "params": [body.k], "lr": lr.k},
        {"name": "d", "params": [body.d], "lr": lr.d},
        {"name": "l", "params": [body.l], "lr": lr.l},
    ]
    brain = agent.brain
    if isinstance(brain, SineWaveGenerator):
        groups += [
            {"name": "amplitude", "params": [brain.amplitude], "lr": lr.amplitude},
            {"name": "phase", "params": [brain.phase], "lr": lr.phase},
        ]
    else:
        groups.append({"name": "brain", "params": list(brain.parameters()), "lr": lr.brain})
    return [g for g in groups if g["lr"] > 0]


def make_optimizer(agent: Agent, cfg: TrainingConfig) -> torch.optim.Optimizer:
    groups = parameter_groups(agent, cfg)
    if not groups:
        raise ValueError("every learning rate is zero: nothing to train")
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(groups, lr=groups[0]["lr"])
    return torch.optim.Adam(groups, lr=groups[0]["lr"])



def step_decay_updates(updates: int, milestones: tuple[float, ...] = (0.8, 0.9), min_updates: int = 1000) -> list[int]:
    """Update indices (0-based) at which every learning rate is divided (the published code's schedule for its
    switching trainings: ÷10 at 80 % and again at 90 % of the training windows, only when there are more than
    ``min_updates`` of them): ``int(m · updates)`` for each milestone m; none for ``updates <= min_updates``.

    Raises ValueError for a milestone outside (0, 1)."""
    if any(not 0 < m < 1 for m in milestones):
        raise ValueError(f"learning-rate milestones must lie in (0, 1), got {milestones}")
    return [] if updates <= min_updates else [int(m * updates) for m in milestones]


def divide_rates_(optimizer: torch.optim.Optimizer, factor: float) -> None:
    """Divide every group's learning rate by ``factor`` in place (on top of what the guard may have cut)."""
    for group in optimizer.param_groups:
        group["lr"] /= factor
