"""Figures of the locomotion experiments (the paper's locomotion table and Fig. 4(b), the supplement's headwind
figure), in the package's one style: each writes a PNG and a PDF and returns the PNG's path."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection

from bptsb_ros.analysis.plots import moving_average
from bptsb_ros.analysis.style import (
    BLUE,
    DOUBLE,
    ORANGE,
    SEQUENTIAL,
    SKY,
    TARGET,
    VERMILLION,
    legend_outside,
    plt,
    save,
    size,
    styled,
)

#: the two agents of the headwind experiment, as the legend names them
HEADWIND_LABELS = {"switching": "after switching training", "forward": "forward agent (before)"}


@styled
def plot_gaits(path: Path, gaits: Mapping[int, Mapping[str, np.ndarray] | None], results: Mapping[int, dict],
               duration: float, snapshots: int = 8) -> Path:
    """One panel per agent (seed): ``snapshots`` body outlines over the stored open-loop gait, coloured by time
    (colorbar), as the paper's locomotion table. ``gaits``: seed → {"r": (T, N, 2) [m], "springs": (E, 2),
    "dt": [s] per row} or None (the agent failed); ``results``: seed → {"open_speed" [m/s], "ratio" [-],
    "success"}; ``duration``: the gait's length [s]."""
    seeds = list(gaits)
    n = len(seeds)
    cols = min(4, n)
    rows = (n + cols - 1) // cols
    spans = [np.ptp(np.asarray(g["r"]).reshape(-1, 2), axis=0) for g in gaits.values() if g is not None]
    aspect = float(np.clip(max((h / max(w, 1e-9) for w, h in spans), default=0.5), 0.15, 1.0))
    panel_w = (DOUBLE - 0.9) / cols  # [in], the colorbar and margins taken off
    fig, axes = plt.subplots(rows, cols, figsize=(DOUBLE, rows * (panel_w * aspect + 0.55) + 0.5), squeeze=False,
                             sharey=True, layout="constrained")
    cmap = plt.get_cmap(SEQUENTIAL)
    norm = plt.Normalize(0.0, duration)
    for ax, seed in zip(axes.flat, seeds, strict=False):
        gait, res = gaits[seed], results.get(seed)
        if gait is None or res is None:
            ax.set_title(f"seed {seed}: failed")
            ax.axis("off")
            continue
        r, springs = np.asarray(gait["r"]), np.asarray(gait["springs"])
        frames = np.linspace(0, len(r) - 1, min(snapshots, len(r))).astype(int)
        times = frames * float(gait["dt"])
        segs = r[frames][:, springs].reshape(-1, 2, 2)  # (frames·E, 2 ends, xy)
        ax.add_collection(LineCollection(segs, colors=cmap(norm(np.repeat(times, len(springs)))), linewidths=0.6))
        pts = r[frames].reshape(-1, 2)
        ax.scatter(*pts.T, s=1.5, c=cmap(norm(np.repeat(times, r.shape[1]))), lw=0)
        ax.axhline(0, color="0.5", lw=0.5)
        ax.set_aspect("equal")
        ax.autoscale_view()
        mark = "✓" if res["success"] else "✗"
        ax.set_title(f"seed {seed} {mark}: {res['open_speed']:.2f} m/s, {res['ratio']:.2f}", fontsize=6.5)
        ax.tick_params(labelsize=5.5)
        ax.set_xlabel("x [m]", fontsize=6.5)
    for ax in axes[:, 0]:
        ax.set_ylabel("y [m]", fontsize=6.5)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, label="time after training [s]",
                 shrink=0.8)
    fig.suptitle(f"Open-loop (SWG) gaits, {snapshots} snapshots over {duration:g} s. Panel title: seed, ✓ closed "
                 "loop succeeded, open-loop speed, closed/open speed")
    return save(fig, path)


@styled
def plot_closed_open_ratios(path: Path, seeds: Sequence[int], results: Mapping[int, dict],
                            series: Sequence[tuple[str, str]], success_ratio: float) -> Path:
    """Closed-loop / open-loop speed [-] per agent (seed) for each ``series`` (key in ``results[seed]``, label),
    clipped to [−0.5, 1.5]; the success threshold dashed."""
    fig, ax = plt.subplots(figsize=size(DOUBLE, 0.38))
    x = np.arange(len(seeds))
    width = 0.8 / max(len(series), 1)
    for i, (key, label) in enumerate(series):
        y = np.array([results.get(s, {}).get(key, np.nan) for s in seeds], dtype=float)
        ax.bar(x + (i - (len(series) - 1) / 2) * width, np.clip(np.nan_to_num(y, nan=0.0), -0.5, 1.5), width,
               label=label, color=f"C{i}")
    ax.axhline(success_ratio, color=TARGET, ls="--", lw=1, label=f"success: {success_ratio}")
    ax.set_xticks(x, [str(s) for s in seeds])
    ax.set_xlabel("agent [seed]")
    ax.set_ylabel("closed-loop / open-loop speed [-]")
    legend_outside(ax, "right")
    ax.grid(alpha=0.3, axis="y")
    return save(fig, path)


@styled
def plot_headwind_speed(path: Path, traces: Mapping[str, dict], target: float, force: float, period: float) -> Path:
    """The supplement's headwind panel (c): forward speed [m/s] in 1 s blocks of each agent under a periodic
    headwind (orange bands). ``traces``: agent → {"t", "t0" [s], "v" [m/s]; "on" (steps,) bool, "dt" [s]}."""
    fig, ax = plt.subplots(figsize=size(DOUBLE, 0.38))
    for i, (name, tr) in enumerate(traces.items()):
        ax.plot(tr["t"] - tr["t0"], tr["v"], color=f"C{i}", lw=1.2, label=HEADWIND_LABELS.get(name, name),
                drawstyle="steps-pre")
    tr = traces["switching"]
    on = np.asarray(tr["on"])
    step_t = np.arange(len(on)) * tr["dt"]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
    for j, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
        ax.axvspan(step_t[a], step_t[min(b, len(step_t) - 1)], color=ORANGE, alpha=0.25, lw=0,
                   label=f"headwind F = {force:g} N" if j == 0 else None)
    ax.axhline(target, color=TARGET, ls="--", lw=1, label="target v_max/2")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("forward speed [m/s]")
    ax.set_title(f"periodic headwind (period {period:g} s); speed averaged over 1 s blocks")
    legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_speed_vs_wind(path: Path, winds: np.ndarray, curves: Mapping[str, np.ndarray], target: float,
                       trained: Sequence[float]) -> Path:
    """The supplement's headwind panel (e): late forward speed [m/s] per constant F_wind [N] (``winds``) of each
    agent; the trained wind values as bands."""
    fig, ax = plt.subplots(figsize=size(DOUBLE * 0.8, 0.45))
    for i, (name, v) in enumerate(curves.items()):
        ax.plot(winds, v, "o-", ms=2.5, lw=1, color=f"C{i}", label=HEADWIND_LABELS.get(name, name))
    ax.axhline(target, color=TARGET, ls="--", lw=1, label="target v_max/2")
    for j, f in enumerate(trained):
        ax.axvline(f, color=ORANGE if f else SKY, lw=4, alpha=0.35, label="trained F_wind" if j == 0 else None)
    ax.set_xlabel("F_wind [N] (negative: headwind)")
    ax.set_ylabel("forward speed [m/s]")
    legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_return_rate(path: Path, sigmas: np.ndarray, rates: Mapping[str, Sequence[np.ndarray]],
                     mean: Mapping[str, np.ndarray], example: Mapping[str, dict], agent: int, before_s: float,
                     dt: float) -> Path:
    """The paper's Fig. 4(b), locomotion: (left) forward speed [m/s] (1 s average) of one agent's open and closed
    loop through a σ = 0.5 m perturbation, (right) the return rate [-] vs σ [m], per agent (thin) and mean.

    ``rates``: "open"/"closed" → per agent (len(sigmas),); ``example``: loop → {"x_before": (T,) [m],
    "x_after": (T', B) [m], "success": (len(sigmas), noise seeds)}; ``dt`` [s]."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=size(DOUBLE, 0.4), gridspec_kw={"width_ratios": [1.3, 1]})
    colours = {"open": BLUE, "closed": VERMILLION}
    names = {"open": "SWG (open loop)", "closed": "FL (closed loop)"}
    i = int(np.argmin(np.abs(np.asarray(sigmas) - 0.5)))
    for loop in ("open", "closed"):
        x = example[loop]
        n_noise = x["success"].shape[1]
        v = np.concatenate([np.diff(x["x_before"]) / dt, np.diff(x["x_after"][:, i * n_noise]) / dt])
        t = np.arange(1, len(v) + 1) * dt
        a1.plot(*moving_average(t, v, max(1, int(round(1.0 / dt)))), color=colours[loop], lw=1,
                label=f"{names[loop]}, σ = {sigmas[i]:.1f} m")
    a1.axvspan(before_s - 0.1, before_s + 0.1, color=ORANGE, alpha=0.5, label="perturbation")
    a1.set_xlabel("time [s]")
    a1.set_ylabel("forward speed [m/s]")
    a1.set_title(f"agent {agent}, noise seed 0: speed (1 s average)")
    legend_outside(a1, "below", ncol=2)
    a1.grid(alpha=0.3)
    for loop in ("open", "closed"):
        for r in rates[loop]:
            a2.plot(sigmas, r, color=colours[loop], lw=0.5, alpha=0.35)
        a2.plot(sigmas, mean[loop], "o-", color=colours[loop], label=f"{names[loop]}, mean of {len(rates[loop])}")
    a2.set_xlabel("perturbation σ [m]")
    a2.set_ylabel("return rate [-]")
    a2.set_ylim(-0.03, 1.03)
    a2.set_title("return rate (thin: each agent)")
    legend_outside(a2, "below", ncol=1)
    a2.grid(alpha=0.3)
    return save(fig, path)
