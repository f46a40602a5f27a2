"""The task interface the trainer drives."""

from __future__ import annotations

from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any

import torch

from bptsb_ros.agent import Agent
from bptsb_ros.config import ExperimentConfig


class Task(ABC):
    """One experiment of the paper.

    The trainer calls ``update_loss(i)`` for i in range(``num_updates()``): the task simulates one
    truncated window (or one episode) with gradients attached and returns the loss; state carried
    between windows lives in the task (detached). ``evaluate()`` reports the paper's metric.
    """

    name: str = ""
    #: one line naming the paper's metric and setting, printed beside the measured value
    paper_reference: str = ""

    def __init__(self, agent: Agent, cfg: ExperimentConfig) -> None:
        self.agent = agent
        self.cfg = cfg

    @abstractmethod
    def num_updates(self) -> int: ...

    @abstractmethod
    def update_loss(self, index: int) -> tuple[torch.Tensor, dict[str, float]]: ...

    @abstractmethod
    def evaluate(self) -> dict[str, Any]:
        """The paper's metric (and related numbers) for the current agent, without gradients."""

    def prepare(self) -> None:  # noqa: B027 - optional hook, most tasks need none
        """Work before the first update that is not training (e.g. a warm-up run); idempotent."""

    def state_dict(self) -> dict[str, Any]:
        """Carried simulation state, for resuming."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        del state

    def plots(self, out_dir: Path) -> list[Path]:
        """Task figures written after training; returns the paths."""
        del out_dir
        return []
