"""Figures of the MNIST experiments, laid out like the paper's Fig. 2 and its supplement figures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import BoundaryNorm, ListedColormap  # noqa: E402

from bptsb_ros.analysis.plots import _save  # noqa: E402

#: one colour per digit, as the paper's PCA and label-map figures (matplotlib's tab10)
DIGIT_COLOURS = plt.get_cmap("tab10").colors


def _time_line(ax, xy: np.ndarray, dt: float, t_max: float, lw: float = 2.0):
    seg = np.stack([xy[:-1], xy[1:]], axis=1)
    lc = LineCollection(seg, cmap="viridis", norm=plt.Normalize(0, t_max), linewidths=lw)
    lc.set_array(np.arange(len(seg)) * dt)
    ax.add_collection(lc)
    return lc


def _digit_axes(ax, title: str, lim: tuple[float, float, float, float]) -> None:
    ax.set_xlim(lim[0], lim[1])
    ax.set_ylim(lim[2], lim[3])
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=6)


def _limits(arrays: Sequence[np.ndarray], pad: float = 0.08) -> tuple[float, float, float, float]:
    allp = np.concatenate([a.reshape(-1, 2) for a in arrays])
    lo, hi = allp.min(0) - pad, allp.max(0) + pad
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def plot_targets(path: Path, targets: Sequence[np.ndarray], dt: float) -> Path:
    """All ten target trajectories, the line coloured by time, the start (the CMP's rest position) marked."""
    t_max = max(len(t) - 1 for t in targets) * dt
    fig, axes = plt.subplots(2, 5, figsize=(11, 5))
    lim = _limits(targets)
    lc = None
    for d, (ax, tgt) in enumerate(zip(axes.flat, targets)):
        lc = _time_line(ax, tgt, dt, t_max)
        ax.plot(*tgt[0], "o", color="k", ms=4, label="start (CMP at rest)")
        _digit_axes(ax, f"{d}: {len(tgt) - 1} steps ({(len(tgt) - 1) * dt:.2f} s)", lim)
        ax.set_xlabel("x [m]", fontsize=7)
        if d % 5 == 0:
            ax.set_ylabel("y [m]", fontsize=7)
    axes.flat[0].legend(fontsize=6, loc="lower left")
    fig.colorbar(lc, ax=axes, label="time [s]", shrink=0.8)
    fig.suptitle("Target CMP trajectories for the digits 0-9 (one pen stroke each, minimum-jerk timing)")
    path = Path(path)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_best_drawings(path: Path, systems: dict[str, dict], targets: Sequence[np.ndarray], dt: float) -> Path:
    """Fig. 2(b)-like: for each system (row) and digit (column) the best test sample's drawing, coloured by
    time, over the target (grey); the panel title gives that sample's MSE.

    ``systems``: name → {"drawings": (n, T+1, 2), "errors": (n,), "labels": (n,)}.
    """
    rows = len(systems)
    fig, axes = plt.subplots(rows, 10, figsize=(15, 1.7 * rows + 0.6), squeeze=False)
    lim = _limits(list(targets) + [s["drawings"][np.argmin(s["errors"])] for s in systems.values()])
    t_max = max(len(t) - 1 for t in targets) * dt
    lc = None
    for r, (name, s) in enumerate(systems.items()):
        for d in range(10):
            ax = axes[r, d]
            tgt = targets[d]
            ax.plot(tgt[:, 0], tgt[:, 1], color="0.75", lw=3, zorder=0)
            idx = np.flatnonzero(s["labels"] == d)
            if idx.size:
                best = idx[np.argmin(s["errors"][idx])]
                lc = _time_line(ax, s["drawings"][best][: len(tgt)], dt, t_max, lw=1.5)
                title = f"{d}: {s['errors'][best]:.2g} m²"
            else:
                title = f"{d}: no sample"
            _digit_axes(ax, title, lim)
            ax.set_xticks([])
            ax.set_yticks([])
        axes[r, 0].set_ylabel(name, fontsize=8)
    if lc is not None:
        fig.colorbar(lc, ax=axes, label="time [s]", shrink=0.8)
    fig.suptitle("Best test drawings per digit (coloured by time) over the targets (grey); scale: "
                 f"x {lim[1] - lim[0]:.2f} m wide")
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_error_bars(path: Path, names: Sequence[str], errors: Sequence[float], stds: Sequence[float],
                    title: str) -> Path:
    """Fig. 2(b)-like error table as bars: mean test MSE per system with the standard error."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    x = np.arange(len(names))
    ax.bar(x, errors, yerr=stds, color=[f"C{i}" for i in range(len(names))], capsize=3)
    for xi, e in zip(x, errors):
        ax.text(xi, e, f"{e:.3g}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("test drawing MSE [m²]")
    ax.set_title(title, fontsize=9)
    return _save(fig, path)


def plot_pca(path: Path, brain_2d: np.ndarray, body_2d: np.ndarray, labels: np.ndarray,
             scores: dict[str, dict[str, float]], title: str) -> Path:
    """Fig. 2(c)-like: brain output and body output, each projected to 2-D by PCA, coloured by label."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    for ax, pts, part in ((axes[0], brain_2d, "brain"), (axes[1], body_2d, "body")):
        for d in range(10):
            sel = labels == d
            ax.scatter(pts[sel, 0], pts[sel, 1], s=6, color=DIGIT_COLOURS[d], label=str(d))
        sc = scores[part]
        ax.set_title(f"{part} output ({'initial positions' if part == 'brain' else 'CMP trajectory'})\n"
                     f"silhouette (2-D) {sc['silhouette_2d']:.3f}, linear probe (2-D) {100 * sc['probe_2d']:.1f} %",
                     fontsize=9)
        ax.set_xlabel("PC 1")
        ax.set_ylabel("PC 2")
    axes[1].legend(title="label", fontsize=7, markerscale=2, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_label_maps(path: Path, maps: np.ndarray, deltas: np.ndarray, rows: dict[str, int],
                    sizes: np.ndarray, title: str) -> Path:
    """Fig. 2(d) / supplement "Label maps": for each chosen mass (row), the 10 label maps (one per original
    label), each cell coloured by the digit the shifted body draws most like.

    maps: (10, P, G, G) labels; rows: row title → mass column p in ``maps``; sizes: (10, P).
    """
    cmap = ListedColormap(DIGIT_COLOURS)
    norm = BoundaryNorm(np.arange(-0.5, 10.5), 10)
    fig, axes = plt.subplots(len(rows), 10, figsize=(15, 1.75 * len(rows) + 0.8), squeeze=False)
    ext = [deltas[0], deltas[-1], deltas[0], deltas[-1]]
    im = None
    for r, (name, p) in enumerate(rows.items()):
        for d in range(10):
            ax = axes[r, d]
            im = ax.imshow(maps[d, p], origin="lower", extent=ext, cmap=cmap, norm=norm, interpolation="nearest")
            ax.set_title(f"label {d}: size {sizes[d, p]:.2f}", fontsize=7)
            ax.tick_params(labelsize=5)
            if r == len(rows) - 1:
                ax.set_xlabel("Δx [m]", fontsize=7)
        axes[r, 0].set_ylabel(f"{name}\nΔy [m]", fontsize=7)
    if im is not None:
        bar = fig.colorbar(im, ax=axes, ticks=range(10), shrink=0.8)
        bar.set_label("closest target digit")
    fig.suptitle(title, fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_label_map_sizes(path: Path, positions: np.ndarray, springs: np.ndarray, fixed: np.ndarray,
                         cmp_index: int, mass_index: np.ndarray, size: np.ndarray, joined: np.ndarray,
                         title: str) -> Path:
    """Fig. 2(e)-like: the body with every shifted mass coloured by its label-map size (mean over labels);
    masses joined to the CMP are ringed."""
    fig, ax = plt.subplots(figsize=(5.5, 5))
    for i, j in springs:
        ax.plot(*positions[[i, j]].T, color="0.8", lw=0.8, zorder=0)
    ax.scatter(*positions[fixed].T, marker="s", s=25, color="0.4", label="fixed")
    ax.scatter(*positions[cmp_index], s=60, color="k", marker="*", label="CMP")
    sc = ax.scatter(*positions[mass_index].T, c=size, cmap="viridis", vmin=0, vmax=1, s=110,
                    edgecolors=np.where(joined, "red", "none"), linewidths=1.5, zorder=3)
    ax.scatter([], [], s=60, facecolors="none", edgecolors="red", label="joined to the CMP")
    fig.colorbar(sc, ax=ax, label="label-map size (fraction of the original label)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title, fontsize=9)
    return _save(fig, path)


def plot_curves(path: Path, curves: dict[str, Sequence[float]], ylabel: str, title: str,
                xlabel: str = "update", log: bool = True) -> Path:
    """Training curves of several systems on one axis."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for name, ys in curves.items():
        ax.plot(np.arange(1, len(ys) + 1), ys, lw=1, label=name)
    if log:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    return _save(fig, path)


def plot_live_drawings(path: Path, live: np.ndarray, offline: np.ndarray | None, targets: Sequence[np.ndarray],
                       labels: np.ndarray, errors: np.ndarray, dt: float, reset_steps: Sequence[int],
                       max_panels: int = 20) -> Path:
    """The live MNIST loop (``bptsb replay``): one panel per episode (the first ``max_panels``) with its label's
    target (grey), the live drawing coloured by time and, when given, the offline drawing of the same image (black
    dashed); the panel title gives the label, the reset step and the live MSE.

    ``live``, ``offline``: (n, E, 2) [m] relative to the CMP's rest position; ``targets``: per digit (T_d + 1, 2).
    """
    n = min(len(live), max_panels)
    cols = min(n, 5)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols + 0.8, 2.6 * rows + 0.6), squeeze=False)
    lim = _limits([targets[int(d)] for d in labels[:n]] + [live[i, : len(targets[int(labels[i])])] for i in range(n)])
    t_max = (live.shape[1] - 1) * dt
    lc = None
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.axis("off")
            continue
        tgt = targets[int(labels[i])]
        ax.plot(tgt[:, 0], tgt[:, 1], color="0.75", lw=4, zorder=0, label="target")
        steps = len(tgt)
        lc = _time_line(ax, live[i, :steps], dt, t_max, lw=1.8)
        if offline is not None:
            ax.plot(offline[i, :steps, 0], offline[i, :steps, 1], "k--", lw=0.8, label="offline")
        _digit_axes(ax, f"{int(labels[i])} (step {reset_steps[i]}): {errors[i]:.3g} m²", lim)
        ax.set_xlabel("x [m]", fontsize=7)
        ax.set_ylabel("y [m]", fontsize=7)
    axes.flat[0].legend(fontsize=6, loc="best")
    if lc is not None:
        fig.colorbar(lc, ax=axes, label="time since release [s]", shrink=0.8)
    fig.suptitle("Live drawings (coloured by time) over their targets (grey)"
                 + ("; offline drawing of the same image dashed" if offline is not None else ""), fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path
