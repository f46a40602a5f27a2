"""Locomotion (paper, "Locomotion task"): a caterpillar robot (10 masses, 24 springs, all movable)
with gravity, air drag and a soft exponential ground, driven by an SWG, must move forward (+x).

Speed = x-velocity averaged over all masses; the loss is the MSE between that speed, averaged over
blocks of ``speed_block`` steps, and a target that grows with training time, v_target = 0.004·t
(t: simulated seconds since training began). Updates every 200 steps; the robot first runs
``warmup_windows`` windows without updates (it settles on the ground).

The published code differed in two ways, both available as options: its loss read each step's
velocity before the velocity update (``locomotion.loss_velocity: before``; ours: ``after``) and its
target ramp was 0.002·t (``locomotion.target_slope: 0.002``; the paper: 0.004).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.sim.inputs import wind_blowing
from bptsb_ros.sim.rollout import Rollout, simulate_closed_loop, simulate_open_loop
from bptsb_ros.tasks.base import SwgWindowTask


def forward_speed(v: torch.Tensor) -> torch.Tensor:
    """Mean x-velocity over all (movable) masses: v (..., M, 2) → (...) [m/s]."""
    return v[..., 0].mean(-1)


def mean_speed(x: np.ndarray, duration: float) -> float:
    """Average forward speed [m/s]: x (T, N) positions of all masses over a run of ``duration`` seconds."""
    centre = np.asarray(x, dtype=np.float64).mean(-1)
    return float((centre[-1] - centre[0]) / duration)


def rollout_speed(rollout: Rollout, dt: float) -> float:
    """Average forward speed [m/s] of batch member 0 of a rollout."""
    return mean_speed(rollout.r[:, 0, :, 0].double().numpy(), rollout.steps * dt)


class LocomotionTask(SwgWindowTask):
    name = "locomotion"
    fused_window = "locomotion"
    loss_label = "speed MSE [m²/s²]"
    paper_reference = (
        "paper: caterpillar 10 masses / 24 springs, SWG, target speed 0.004·t, update every 200 steps; "
        "metric: mean forward speed vs target; closed loop succeeds when speed ≥ 0.7 × open-loop speed "
        "(paper: 8 of 20 agents, 40 %)"
    )

    def __init__(self, agent, cfg) -> None:
        super().__init__(agent, cfg)
        self.block = cfg.locomotion.speed_block  # divides the window (checked by the config)
        self.train_start_step: int | None = None

    def prepare(self) -> None:
        """Run the warm-up windows (no updates) once, before the first update."""
        if self.train_start_step is not None:
            return
        steps = self.cfg.locomotion.warmup_windows * self.window
        if steps:
            self.state = simulate_open_loop(self.agent, steps, state=self.state).final
        self.train_start_step = self.state.step

    def update_loss(self, index: int) -> tuple[torch.Tensor, dict[str, float]]:
        self.prepare()
        k0 = self.state.step
        v_start = self.state.v
        win = self.run_window()
        v = win.v[:, 0]  # (W, M, 2): velocity after the update of steps k0+1 .. k0+W
        if self.cfg.locomotion.loss_velocity == "before":  # the published code: v before each step's update
            v = torch.cat([v_start, v[:-1]])
        speed = forward_speed(v).view(-1, self.block).mean(-1)  # (blocks,)
        block_end = k0 + self.block * torch.arange(1, speed.shape[0] + 1, dtype=speed.dtype)
        if self.cfg.locomotion.target_speed is not None:  # headwind switching: a constant target
            target = torch.full_like(speed, self.cfg.locomotion.target_speed)
        else:
            target = self.cfg.locomotion.target_slope * (block_end - self.train_start_step) * self.agent.dt
        loss = ((speed - target) ** 2).mean()
        return loss, {"speed": float(speed.detach().mean())}

    def window_forces(self, first_step: int) -> torch.Tensor | None:
        """The periodic wind along x on every mass at steps first_step+1 .. first_step+W (None if no wind)."""
        loc = self.cfg.locomotion
        if loc.wind_force == 0:
            return None
        body = self.agent.body
        on = wind_blowing(np.arange(first_step + 1, first_step + 1 + self.window), body.dt, loc.wind_period)
        force = torch.zeros(self.window, body.n_movable, 2, dtype=body.l.dtype)
        force[torch.from_numpy(on), :, 0] = loc.wind_force
        return force

    def target_speed_now(self) -> float:
        if self.cfg.locomotion.target_speed is not None:
            return self.cfg.locomotion.target_speed
        start = self.train_start_step if self.train_start_step is not None else self.state.step
        return self.cfg.locomotion.target_slope * (self.state.step - start) * self.agent.dt

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "train_start": self.train_start_step}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.train_start_step = state["train_start"]

    def evaluate(self) -> dict[str, Any]:
        agent = self.agent
        dt = agent.dt
        steps = int(round(self.cfg.locomotion.eval_time / dt))
        roll = simulate_open_loop(agent, steps, state=self.state)
        open_speed = rollout_speed(roll, dt)
        out: dict[str, Any] = {
            "metric": "mean_forward_speed",
            "mean_forward_speed": open_speed,
            "target_speed_end_of_training": self.target_speed_now(),
            "eval_time": self.cfg.locomotion.eval_time,
            "paper_reference": self.paper_reference,
        }
        t = np.arange(steps + 1) * dt
        self._eval = {"t": t, "open": forward_speed(roll.v[:, 0]).double().numpy()}
        if agent.feedback is not None and getattr(self, "feedback_fitted", False):
            closed = simulate_closed_loop(agent.body, agent.feedback, steps, state=roll.final)
            closed_speed = rollout_speed(closed, dt)
            out["closed_loop_speed"] = closed_speed
            out["closed_over_open"] = closed_speed / open_speed if open_speed else float("nan")
            out["closed_loop_success"] = bool(open_speed > 0 and closed_speed >= 0.7 * open_speed)
            self._eval["closed"] = forward_speed(closed.v[:, 0]).double().numpy()
        return out
