"""Lissajous curve drawing (paper, "Lissajous curve drawing task"): the CMP of a double-circle body
driven by an SWG must trace x = X cos(α ω t), y = Y sin(β ω t + δ), X = Y = diameter/20, ω = 2π.

Training: truncated windows of ``update_steps`` steps (100 = one SWG period), MSE between the CMP
and the target over the window, state carried over detached. The SWG clock runs continuously
(identical to the published per-window reset when the window is one period).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop
from bptsb_ros.tasks.base import SwgWindowTask


def lissajous_target(t: torch.Tensor, x_amp: float, y_amp: float, alpha: float, beta: float, delta: float,
                     omega: float) -> torch.Tensor:
    """Target CMP position (T, 2) [m] at times t (T,) [s]."""
    return torch.stack([x_amp * torch.cos(alpha * omega * t), y_amp * torch.sin(beta * omega * t + delta)], dim=-1)


def target_from_config(config: dict[str, Any]):
    """The Lissajous target of an experiment config (dict): (time (T,) [s] as np or torch → (T, 2) [m]), and
    the period in steps."""
    lc, brain, body = config["lissajous"], config["brain"], config["body"]
    amp = float(lc["amplitude_fraction"]) * float(body["size"])
    omega = float(brain["omega"])
    args = (amp, amp, float(lc["alpha"]), float(lc["beta"]), float(lc["delta"]), omega)

    def target(t):
        if isinstance(t, torch.Tensor):
            return lissajous_target(t, *args)
        return lissajous_target(torch.as_tensor(t, dtype=torch.float64), *args).numpy()

    return target, int(round(2 * np.pi / omega / float(body["dt"])))


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


class LissajousTask(SwgWindowTask):
    name = "lissajous"
    fused_window = "lissajous"
    loss_label = "trajectory MSE [m²]"
    paper_reference = (
        "paper: double-circle N_mov=13, SWG, (α,β,δ)=(1,2,0), X=Y=size/20, update every 100 steps; "
        "metric: CMP trajectory MSE vs target (the paper shows trajectories, no number); the closed-loop "
        "error is the per-period minimum over time shifts (paper: larger than the SWG's)"
    )

    def __init__(self, agent, cfg) -> None:
        super().__init__(agent, cfg)
        if agent.body.cmp_local < 0:
            raise ValueError("the Lissajous task needs a body with a central mass point")
        self.target, self.period = target_from_config(agent.config)

    def update_loss(self, index: int) -> tuple[torch.Tensor, dict[str, float]]:
        k0 = self.state.step
        win = self.run_window()
        cmp = win.r[:, 0, self.agent.body.cmp_local]
        loss = ((cmp - self.target(self.window_times(k0)).to(cmp.dtype)) ** 2).mean()
        return loss, {}

    # -- evaluation ------------------------------------------------------------------------------
    def evaluate(self) -> dict[str, Any]:
        agent = self.agent
        body = agent.body
        period = self.period
        steps = self.cfg.lissajous.eval_periods * period
        roll = simulate_open_loop(agent, steps, state=self.state)
        cmp = roll.r[:, 0, body.cmp_local].double().numpy()
        t = (self.state.step + np.arange(steps + 1)) * body.dt
        open_mse = float(np.mean((cmp - self.target(t)) ** 2))
        out: dict[str, Any] = {
            "metric": "trajectory_mse",
            "trajectory_mse": open_mse,
            "trajectory_mse_shift_min": self._windowed_shift_error(cmp, t[0], period),
            "target_mean_square": float(np.mean(self.target(t) ** 2)),
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
        return windowed_shift_error(traj, self.target, t0, self.agent.body.dt, period)


def windowed_shift_error_batch(traj: np.ndarray, target: np.ndarray, period: int) -> np.ndarray:
    """:func:`windowed_shift_error` for a whole population at once.

    Args:
        traj: (T, B, 2) CMP positions [m] at times t0 + k·dt, k = 0..T−1 (NaN rows give NaN).
        target: (T + period, 2) target at the same times, extended by ``period`` steps (for the shifts).
        period: steps per target period.

    Returns:
        (B,) mean over whole periods of the per-period minimum over shifts s = 0..period of the MSE [m²].
    """
    n_rows, batch = traj.shape[0], traj.shape[1]
    if target.shape[0] < n_rows + period:
        raise ValueError(f"target needs {n_rows + period} rows (traj + period), got {target.shape[0]}")
    starts = list(range(0, n_rows - period, period))
    if not starts:
        raise ValueError(f"need more than one period ({period} steps) of trajectory, got {n_rows} rows")
    j = np.arange(period + 1)
    shifts = np.arange(period + 1)
    errs = np.empty((len(starts), batch))
    for w, s0 in enumerate(starts):
        x = traj[s0:s0 + period + 1]  # (J, B, 2)
        g = target[s0 + shifts[:, None] + j[None, :]]  # (S, J, 2)
        # mean_j |x_j − g_{j+s}|² = (Σ|x|² − 2 Σ x·g + Σ|g|²) / (2J)   (mean over rows and both coordinates)
        cross = np.einsum("jbc,sjc->sb", x, g)
        mse = ((x ** 2).sum((0, 2))[None, :] - 2 * cross + (g ** 2).sum((1, 2))[:, None]) / (2 * (period + 1))
        errs[w] = mse.min(0)
    return errs.mean(0)


#: the paper's success criterion of a perturbation run (Methods): E / E_orig < RETURN_RATIO
RETURN_RATIO = 2.0


def returned(error: np.ndarray, error_orig: float | np.ndarray) -> np.ndarray:
    """The paper's "successful return" (Methods, Lissajous): E / E_orig < 2; a NaN error (diverged) fails."""
    e = np.asarray(error, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.isfinite(e) & (e < RETURN_RATIO * np.asarray(error_orig, dtype=np.float64))
