"""Lissajous curve drawing (paper, "Lissajous curve drawing task"): the CMP of a double-circle body
driven by an SWG must trace x = X cos(α ω t), y = Y sin(β ω t + δ), X = Y = diameter/20, ω = 2π.

Training: truncated windows of ``update_steps`` steps (100 = one SWG period), MSE between the CMP
and the target over the window, state carried over detached. The SWG clock runs continuously
(identical to the published per-window reset when the window is one period).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.msdn import BodyState
from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop, swg_rest_lengths
from bptsb_ros.tasks.base import Task


def lissajous_target(t: torch.Tensor, x_amp: float, y_amp: float, alpha: float, beta: float, delta: float,
                     omega: float) -> torch.Tensor:
    """Target CMP position (T, 2) [m] at times t (T,) [s]."""
    return torch.stack([x_amp * torch.cos(alpha * omega * t), y_amp * torch.sin(beta * omega * t + delta)], dim=-1)


def shift_min_mse(traj: np.ndarray, target_fn, t0: float, dt: float, shifts: int) -> float:
    """Minimum over time shifts s = 0..shifts of the MSE between traj (T, 2) and target(t + s·dt).

    The paper's closed-loop error: a closed loop keeps the shape but may drift in phase.
    """
    t = t0 + dt * np.arange(traj.shape[0])
    return float(min(np.mean((traj - target_fn(t + s * dt)) ** 2) for s in range(shifts + 1)))


def windowed_shift_error(traj: np.ndarray, target_fn, t0: float, dt: float, period: int) -> float:
    """Mean over whole periods of the per-period minimum-over-shifts MSE (the paper's closed-loop error).

    traj: (T, 2) CMP positions at times t0 + k·dt; period: steps per target period.
    """
    errs = [shift_min_mse(traj[s:s + period + 1], target_fn, t0 + s * dt, dt, period)
            for s in range(0, traj.shape[0] - period, period)]
    if not errs:
        raise ValueError(f"need more than one period ({period} steps) of trajectory, got {traj.shape[0]} rows")
    return float(np.mean(errs))


class LissajousTask(Task):
    name = "lissajous"
    paper_reference = (
        "paper: double-circle N_mov=13, SWG, (α,β,δ)=(1,2,0), X=Y=size/20, update every 100 steps; "
        "metric: CMP trajectory MSE vs target (the paper shows trajectories, no number); the closed-loop "
        "error is the per-period minimum over time shifts (paper: larger than the SWG's)"
    )

    def __init__(self, agent, cfg) -> None:
        super().__init__(agent, cfg)
        body = agent.body
        if body.cmp_local < 0:
            raise ValueError("the Lissajous task needs a body with a central mass point")
        self.window = cfg.training.update_steps
        lc = cfg.lissajous
        amp = lc.amplitude_fraction * cfg.body.size
        self.target_args = (amp, amp, lc.alpha, lc.beta, lc.delta, cfg.brain.omega)
        self.state: BodyState = body.initial_state(1, rest_length=swg_rest_lengths(body, agent.brain, 0, 1)[0])
        self.state = self.state.detach()

    def target(self, t: torch.Tensor) -> torch.Tensor:
        return lissajous_target(t, *self.target_args)

    def target_np(self, t: np.ndarray) -> np.ndarray:
        return self.target(torch.as_tensor(t, dtype=torch.float64)).numpy()

    def num_updates(self) -> int:
        return max(1, int(round(self.cfg.sim_time / (self.window * self.agent.dt))))

    def update_loss(self, index: int) -> tuple[torch.Tensor, dict[str, float]]:
        body, swg = self.agent.body, self.agent.brain
        k0 = self.state.step
        rest = swg_rest_lengths(body, swg, k0 + 1, self.window)
        win = rollout_window(body, self.state, rest, adjoint=self.cfg.training.adjoint)
        t = torch.arange(k0 + 1, k0 + 1 + self.window, dtype=rest.dtype) * body.dt
        loss = ((win.r[:, 0, body.cmp_local] - self.target(t)) ** 2).mean()
        self.state = win.final.detach()
        body.check_finite(self.state)
        return loss, {}

    def state_dict(self) -> dict[str, Any]:
        s = self.state
        return {"r": s.r, "v": s.v, "a": s.a, "length": s.length, "step": s.step}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.state = BodyState(state["r"], state["v"], state["a"], state["length"], int(state["step"]))

    # -- evaluation ------------------------------------------------------------------------------
    def evaluate(self) -> dict[str, Any]:
        agent = self.agent
        body = agent.body
        period = int(round(2 * np.pi / self.cfg.brain.omega / body.dt))
        steps = self.cfg.lissajous.eval_periods * period
        roll = simulate_open_loop(agent, steps, state=self.state)
        cmp = roll.r[:, 0, body.cmp_local].double().numpy()
        t = (self.state.step + np.arange(steps + 1)) * body.dt
        open_mse = float(np.mean((cmp - self.target_np(t)) ** 2))
        out: dict[str, Any] = {
            "metric": "trajectory_mse",
            "trajectory_mse": open_mse,
            "trajectory_mse_shift_min": self._windowed_shift_error(cmp, t[0], period),
            "target_mean_square": float(np.mean(self.target_np(t) ** 2)),
            "eval_steps": steps,
            "paper_reference": self.paper_reference,
        }
        self._eval = {"t": t, "open": cmp}
        if agent.feedback is not None and getattr(self, "feedback_fitted", False):
            closed = simulate_closed_loop(body, agent.feedback, steps, state=roll.final)
            ccmp = closed.r[:, 0, body.cmp_local].double().numpy()
            tc = t[-1] + body.dt * np.arange(steps + 1)
            closed_err = self._windowed_shift_error(ccmp, tc[0], period)
            out["closed_loop_shift_min_mse"] = closed_err
            out["closed_over_open"] = closed_err / max(out["trajectory_mse_shift_min"], 1e-30)
            self._eval.update({"tc": tc, "closed": ccmp})
        return out

    def _windowed_shift_error(self, traj: np.ndarray, t0: float, period: int) -> float:
        return windowed_shift_error(traj, self.target_np, t0, self.agent.body.dt, period)

    def plots(self, out_dir: Path) -> list[Path]:
        from bptsb_ros.analysis.plots import plot_lissajous

        if not hasattr(self, "_eval"):
            self.evaluate()
        e = self._eval
        path = out_dir / "lissajous.png"
        curves = {"open loop (SWG)": e["open"]}
        if "closed" in e:
            curves["closed loop (FL), next run"] = e["closed"]
        plot_lissajous(path, e["t"], curves, self.target_np(e["t"]))
        return [path]
