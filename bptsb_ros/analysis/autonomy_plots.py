"""Figures of the autonomy experiments (paper Fig. 4(b,c) and the supplement's SWG figures): perturbation
return rates, wind switching, bifurcation diagram, switching timing."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bptsb_ros.analysis.plots import _save, plt

WIND_COLOURS = {0: "tab:blue", 1: "tab:orange"}


def plot_perturbation(path: Path, sigmas: np.ndarray, rates: dict[str, np.ndarray], *, closed_traj: np.ndarray,
                      closed_ok: np.ndarray, dt: float, t0: float, target: Callable[[np.ndarray], np.ndarray],
                      seeds: int, period: int) -> Path:
    """(b) a closed-loop run that returned and one that did not (CMP after the perturbation), (c) return rate
    vs σ. closed_traj: (T+1, B, 2) rows σ_j·seeds + i; closed_ok: (B,) bool."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), gridspec_kw={"width_ratios": [1, 1.3]})
    ax = axes[0]
    t = t0 + dt * np.arange(closed_traj.shape[0])
    tgt = target(t[-period - 1:])
    ax.plot(tgt[:, 0], tgt[:, 1], "k--", lw=1.2, label="target")
    ok = np.flatnonzero(closed_ok[seeds:])  # perturbed rows only
    bad = np.flatnonzero(~closed_ok[seeds:])
    tail = slice(-3 * period - 1, None)
    for rows, colour, label in ((ok, "tab:blue", "returned"), (bad, "tab:purple", "did not return")):
        if rows.size:
            b = seeds + int(rows[len(rows) // 2])
            sigma = (b // seeds) / 10
            xy = closed_traj[tail, b]
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, label=f"{label} (σ = {sigma:.1f})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("(b) closed loop after a perturbation\n(last 3 periods)")
    ax.legend(frameon=False, fontsize=8)
    ax = axes[1]
    styles = ["o-", "s-", "^--"]
    for (label, rate), st in zip(rates.items(), styles, strict=False):
        ax.plot(sigmas, rate, st, label=label, ms=4)
    ax.set_xlabel("perturbation σ [m]")
    ax.set_ylabel("return rate")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title("(c) return rate (E / E_orig < 2)")
    ax.grid(alpha=0.3)
    ax.legend(frameon=False, fontsize=8)
    return _save(fig, path)
