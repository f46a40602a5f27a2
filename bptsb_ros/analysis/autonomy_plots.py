"""Figures of the autonomy experiments (paper Fig. 4(b,c) and the supplement's SWG figures): perturbation
return rates, wind switching, bifurcation diagram, switching timing."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from bptsb_ros.analysis.style import (
    BLUE,
    DOUBLE,
    GREEN,
    ORANGE,
    PURPLE,
    TARGET,
    VERMILLION,
    legend_outside,
    plt,
    save,
    size,
    styled,
)

#: the paper's colours: blue without wind (F_wind = 0), orange with it (F_wind = 1)
WIND_COLOURS = {0: BLUE, 1: ORANGE}


@styled
def plot_perturbation(path: Path, sigmas: np.ndarray, rates: dict[str, np.ndarray], *, closed_traj: np.ndarray,
                      closed_ok: np.ndarray, dt: float, t0: float, target: Callable[[np.ndarray], np.ndarray],
                      seeds: int, period: int) -> Path:
    """(b) a closed-loop run that returned and one that did not (CMP after the perturbation), (c) return rate
    vs σ. closed_traj: (T+1, B, 2) rows σ_j·seeds + i; closed_ok: (B,) bool."""
    fig, axes = plt.subplots(1, 2, figsize=size(DOUBLE, 0.45), gridspec_kw={"width_ratios": [1, 1.3]})
    ax = axes[0]
    t = t0 + dt * np.arange(closed_traj.shape[0])
    tgt = target(t[-period - 1:])
    ax.plot(tgt[:, 0], tgt[:, 1], "--", color=TARGET, lw=1.2, label="target")
    ok = np.flatnonzero(closed_ok[seeds:])  # perturbed rows only
    bad = np.flatnonzero(~closed_ok[seeds:])
    tail = slice(-3 * period - 1, None)
    for rows, colour, label in ((ok, BLUE, "returned"), (bad, PURPLE, "did not return")):
        if rows.size:
            b = seeds + int(rows[len(rows) // 2])
            sigma = (b // seeds) / 10
            xy = closed_traj[tail, b]
            ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.0, marker="o", markevery=[len(xy) - 1], ms=5,
                    label=f"{label} (σ = {sigma:.1f}; ● end)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("(b) closed loop after a perturbation\n(last 3 periods)")
    legend_outside(ax, "below", ncol=1)
    ax = axes[1]
    styles = ["o-", "s-", "^--"]
    for (label, rate), st in zip(rates.items(), styles, strict=False):
        ax.plot(sigmas, rate, st, label=label, ms=4)
    ax.set_xlabel("perturbation σ [m]")
    ax.set_ylabel("return rate [-]")
    ax.set_ylim(-0.03, 1.03)
    ax.set_title("(c) return rate (E / E_orig < 2)")
    ax.grid(alpha=0.3)
    legend_outside(ax, "below", ncol=1)
    return save(fig, path)


def _wind_background(ax, t: np.ndarray, wind: np.ndarray) -> None:
    """Shade time spans blue (F_wind = 0) and orange (F_wind = 1)."""
    edges = np.flatnonzero(np.diff(wind)) + 1
    bounds = np.concatenate([[0], edges, [len(wind) - 1]])
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        ax.axvspan(t[a], t[b], color=WIND_COLOURS[int(wind[a] > 0.5)], alpha=0.12, lw=0)


@styled
def plot_switching_curves(path: Path, cmp: np.ndarray, target: np.ndarray, wind: np.ndarray,
                          segments: dict[str, tuple[int, int]], title: str = "") -> Path:
    """(a) the drawn curve in each wind segment over its target. cmp, target: (T, 2); wind: (T,);
    segments: label → (first, end) rows after the transient."""
    fig, axes = plt.subplots(1, len(segments), figsize=(min(DOUBLE, 2.6 * len(segments) + 0.4), 3.2),
                             squeeze=False)
    axes = axes[0]
    for ax, (label, (a, b)) in zip(np.atleast_1d(axes), segments.items(), strict=True):
        colour = WIND_COLOURS[int(wind[a] > 0.5)]
        ax.plot(target[a:b, 0], target[a:b, 1], "--", color=TARGET, lw=1.2, label="target")
        ax.plot(cmp[a:b, 0], cmp[a:b, 1], color=colour, lw=1.0, label="CMP")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{label}:\nF_wind = {int(wind[a] > 0.5)} N")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        legend_outside(ax, "below")
    fig.suptitle(f"(a) drawn curves with and without wind (after a transient){', ' + title if title else ''}")
    return save(fig, path)


@styled
def plot_switching_dynamics(path: Path, t: np.ndarray, r: np.ndarray, wind: np.ndarray, cmp: int) -> Path:
    """(b) x(t) and y(t) of every movable mass around a switch (CMP red), background by wind. r: (T, M, 2)."""
    fig, axes = plt.subplots(2, 1, figsize=size(DOUBLE, 0.55), sharex=True)
    for c, ax in enumerate(axes):
        _wind_background(ax, t, wind)
        centred = r[:, :, c] - r[:, :, c].mean(0)
        for m in range(r.shape[1]):
            if m != cmp:
                ax.plot(t, centred[:, m], color="0.55", lw=0.6)
        ax.plot(t, centred[:, cmp], color=VERMILLION, lw=1.4, label="CMP")
        ax.set_ylabel(f"{'xy'[c]} − mean [m]")
        ax.grid(alpha=0.3)
    axes[0].plot([], [], color="0.55", lw=0.6, label="other movable masses")
    legend_outside(axes[0], "right")
    axes[1].set_xlabel("time [s] (blue: F_wind = 0, orange: F_wind = 1)")
    axes[0].set_title("(b) each movable mass before and after the wind switches on (CMP in red)")
    return save(fig, path)


@styled
def plot_bifurcation(path: Path, winds: np.ndarray, max_x: list[np.ndarray], max_y: list[np.ndarray],
                     cmp: np.ndarray, show: list[float], period: np.ndarray, title: str = "") -> Path:
    """(d) local maxima of the CMP's x and y per F_wind, trajectories at ``show`` values on top.
    cmp: (T, len(winds), 2) after the transient; period: (len(winds),) orbit period multiple (0 aperiodic)."""
    fig = plt.figure(figsize=(DOUBLE, 5.2))
    grid = fig.add_gridspec(3, len(show), height_ratios=[1.0, 1.3, 1.3])
    for j, f in enumerate(show):
        ax = fig.add_subplot(grid[0, j])
        b = int(np.argmin(np.abs(winds - f)))
        xy = cmp[:, b]
        ax.plot(xy[:, 0], xy[:, 1], lw=0.5, color=WIND_COLOURS.get(int(round(f)), "0.3") if f in (0.0, 1.0) else "0.3")
        ax.set_title(f"F = {winds[b]:.2f}\n" + (f"period {period[b]}" if period[b] > 0 else
                                                ("aperiodic" if period[b] == 0 else "diverged")), fontsize=6.5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=5)
        ax.set_xlabel("x [m]", fontsize=6)
        ax.set_ylabel("y [m]", fontsize=6)
    first = None
    for row, (maxima, name) in enumerate(((max_x, "x"), (max_y, "y")), start=1):
        ax = first = fig.add_subplot(grid[row, :], sharex=first)
        for f, c in ((0.0, 0), (1.0, 1)):
            ax.axvspan(f - 0.025, f + 0.025, color=WIND_COLOURS[c], alpha=0.25, lw=0)
        xs = np.concatenate([np.full(len(m), w) for w, m in zip(winds, maxima, strict=True)])
        ys = np.concatenate(maxima) if maxima else np.array([])
        ax.scatter(xs, ys, s=2, color="k", alpha=0.5, lw=0, rasterized=True)
        ax.set_ylabel(f"maxima of CMP {name} [m]")
        ax.grid(alpha=0.3)
        if row == 2:
            ax.set_xlabel("F_wind [N] (blue, orange: the trained values 0 and 1)")
    fig.suptitle(f"(d) bifurcation diagram of the switching agent{', ' + title if title else ''}")
    return save(fig, path)


@styled
def plot_timing(path: Path, runs: dict[str, dict], *, period: int, target: Callable[[np.ndarray, float], np.ndarray],
                shifts: dict[str, float]) -> Path:
    """Switch timing: per system, which n converge, and the CMP of a converging and a failing n."""
    fig, axes = plt.subplots(len(runs), 3, figsize=(DOUBLE, 2.6 * len(runs) + 0.4), squeeze=False,
                             gridspec_kw={"width_ratios": [1.6, 1, 1]})
    for row, (name, res) in enumerate(runs.items()):
        ax = axes[row, 0]
        conv = res["converged"]
        ax.bar(res["n"], np.where(conv, 1, 0), color=np.where(conv, ORANGE, PURPLE), width=1.0)
        ax.set_ylim(0, 1.1)
        ax.set_yticks([0, 1], ["no", "yes"])
        ax.set_ylabel(f"{name} timing:\nconverges?")
        ax.set_xlabel("switch phase n [1/100 period]")
        t = res["t"][-period - 1:]
        tgt = target(t, shifts[name])
        fails = np.flatnonzero(~conv)
        examples = [(0, "trained")]
        if fails.size:
            examples.append((int(fails[len(fails) // 2]), "fails"))
        else:
            examples.append((50, "converges"))
        for ax, (n, label) in zip(axes[row, 1:], examples, strict=True):
            xy = res["cmp"][-3 * period - 1:, n]
            ax.plot(tgt[:, 0], tgt[:, 1], "--", color=TARGET, lw=1.0, label="(1,3,0) target")
            ax.plot(xy[:, 0], xy[:, 1], color=ORANGE if conv[n] else PURPLE, lw=0.8, label="CMP")
            ax.set_title(f"{name}: n = {n} ({label})")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
        legend_outside(axes[row, 2], "right")
    fig.suptitle("Switching timing: wind switched on at t0 + (2π/ω)·n/100; last 3 periods")
    return save(fig, path)


@styled
def plot_scheme_ratios(path: Path, curves: list[str], seeds: list[int], ratio2: np.ndarray, ratio3: np.ndarray,
                       paper2: np.ndarray, paper3: np.ndarray) -> Path:
    """The supplement's table as annotated matrices: E_after / E_before per curve (rows) and seed (columns),
    ours beside the paper's; improved cells (< 1) green and bold."""
    fig, axes = plt.subplots(2, 2, figsize=(DOUBLE, 1.6 + 0.8 * len(curves)))
    panels = ((ratio2, "scheme 2, ours"), (paper2, "scheme 2, paper"), (ratio3, "scheme 3, ours"),
              (paper3, "scheme 3, paper"))
    for ax, (mat, title) in zip(axes.ravel(), panels, strict=True):
        mat = np.asarray(mat, dtype=float)
        cols = seeds if "ours" in title else list(range(mat.shape[1]))
        ax.imshow(np.where(mat < 1, 0.0, 1.0), cmap="RdYlGn_r", vmin=-1.5, vmax=2.5, aspect="auto")
        for i in range(mat.shape[0]):
            for j in range(mat.shape[1]):
                v = mat[i, j]
                ax.text(j, i, "diverged" if not np.isfinite(v) else f"{v:.2f}", ha="center", va="center",
                        fontweight="bold" if v < 1 else "normal", fontsize=7)
        ax.set_xticks(range(mat.shape[1]), [str(c) for c in cols])
        ax.set_yticks(range(mat.shape[0]), curves)
        ax.set_xlabel("random seed [index]")
        ax.set_ylabel("curve (a, b, δ)")
        ax.set_title(f"{title}: E_after / E_before")
    return save(fig, path)


@styled
def plot_perturbed_run(path: Path, t: np.ndarray, cmp: dict[str, np.ndarray], target: np.ndarray, t_kick: float,
                       eval_from: float | None, verdict: str) -> Path:
    """A live perturbed run (``bptsb replay``): the CMP's x(t) and y(t) — live, offline with the same perturbation,
    offline unperturbed — and the target, the perturbation time marked, the window the return is judged on shaded.
    cmp: label → (T, 2); target: (T, 2); t: (T,) [s]."""
    styles = {"live": dict(color=VERMILLION, lw=1.6), "offline": dict(color="k", lw=0.9, ls="--"),
              "unperturbed": dict(color=BLUE, lw=0.9, alpha=0.7)}
    fig, axes = plt.subplots(2, 1, figsize=size(DOUBLE, 0.55), sharex=True)
    for c, ax in enumerate(axes):
        ax.plot(t, target[:, c], color="0.6", lw=0.8, ls=":", label="target")
        for label, traj in cmp.items():
            ax.plot(t, traj[:, c], label=label, **styles.get(label, {}))
        ax.axvline(t_kick, color=GREEN, lw=1.2, label="perturbation")
        if eval_from is not None:
            ax.axvspan(eval_from, t[-1], color="0.9", zorder=0, label="error window (E, E_orig)")
        ax.set_ylabel(f"CMP {'xy'[c]} [m]")
        ax.grid(alpha=0.3)
    legend_outside(axes[0], "right")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(f"perturbed live run: {verdict}")
    return save(fig, path)
