"""Workloads more than one benchmark measures: one NARMA training update as its trainer builds it.

``bench/suite.py`` times it alone (the NARMA task rows), ``bench/gang_speed.py`` runs several at once in a gang.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch


def narma_task_update(overrides: Mapping[str, Any], seed: int = 0) -> tuple[Any, Callable[[], None]]:
    """``config/narma.yaml`` with ``overrides`` built as its trainer builds it (seeded): ``(task, update)``, where
    ``update()`` is one training update of the task (loss, backward, SGD step, k/d/l projection)."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.experiments.common import packaged_config
    from bptsb_ros.tasks.narma import NarmaTask
    from bptsb_ros.training.optim import make_optimizer

    cfg = packaged_config("narma", dict(overrides), seed=seed)
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    task = NarmaTask(agent, cfg)
    opt = make_optimizer(agent, cfg.training)
    index = 0

    def update() -> None:
        nonlocal index
        loss, _ = task.update_loss(index)
        index += 1
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        agent.body.clamp_parameters_()

    return task, update
