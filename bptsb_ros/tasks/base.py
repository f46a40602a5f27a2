"""The task interface the trainer drives."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import torch

from bptsb_ros.agent import Agent
from bptsb_ros.body.adjoint import Window, rollout_window
from bptsb_ros.body.clock import step_times
from bptsb_ros.body.msdn import BodyState
from bptsb_ros.config import ExperimentConfig
from bptsb_ros.sim.rollout import swg_rest_lengths


class Task(ABC):
    """One experiment of the paper.

    The trainer calls ``update_loss(i)`` for i in range(``num_updates()``): the task simulates one
    truncated window (or one episode) with gradients attached and returns the loss; state carried
    between windows lives in the task (detached). ``evaluate()`` reports the paper's metric.
    """

    name: str = ""
    #: one line naming the paper's metric and setting, printed beside the measured value
    paper_reference: str = ""
    #: the training loss and its unit, as the loss figure's axis names it (e.g. "trajectory MSE [m²]")
    loss_label: str = "loss [task units]"
    #: True when the task runs each of its episodes as one compiled autograd node itself (``training.backend:
    #: fused``, e.g. the NARMA task's held-force window); the trainer then keeps its autograd update
    fused_episodes: bool = False
    #: what the trainer's fused path (:mod:`bptsb_ros.training.fused`) offers this task: ``"lissajous"`` or
    #: ``"locomotion"`` (its window fused with its loss), ``"episodes"`` (the task fuses its own episodes), or None
    fused_window: str | None = None

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


class SwgWindowTask(Task):
    """A continuous task driven by an SWG: truncated windows of ``training.update_steps`` steps, the
    body state carried from window to window (detached), the SWG clock running on."""

    def __init__(self, agent: Agent, cfg: ExperimentConfig) -> None:
        super().__init__(agent, cfg)
        self.window = cfg.training.update_steps
        body = agent.body
        self.state: BodyState = body.initial_state(1, rest_length=swg_rest_lengths(body, agent.brain, 0, 1)[0]).detach()

    def num_updates(self) -> int:
        return max(1, int(round(self.cfg.sim_time / (self.window * self.agent.dt))))

    def window_forces(self, first_step: int) -> torch.Tensor | None:
        """(W, M, 2) external force [N] in force at steps first_step+1 .. first_step+W, or None (default)."""
        del first_step
        return None

    def run_window(self) -> Window:
        """Simulate the next window with gradients; the carried state advances only if it stayed finite."""
        body = self.agent.body
        rest = swg_rest_lengths(body, self.agent.brain, self.state.step + 1, self.window)
        win = rollout_window(body, self.state, rest, self.window_forces(self.state.step),
                             adjoint=self.cfg.training.adjoint)
        final = win.final.detach()
        body.check_finite(final)
        self.state = final
        return win

    def window_times(self, first_step: int) -> torch.Tensor:
        """(W,) float64 times [s] of the steps first_step+1 .. first_step+W (float64 so that a target's phase
        ω·t stays exact at large t; cast the target, not the time, to the model dtype)."""
        return step_times(first_step + 1, self.window, self.agent.dt)

    def state_dict(self) -> dict[str, Any]:
        s = self.state
        return {"r": s.r, "v": s.v, "a": s.a, "length": s.length, "step": s.step}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.state = BodyState(state["r"], state["v"], state["a"], state["length"], int(state["step"]))
