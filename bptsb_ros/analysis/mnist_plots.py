"""Figures of the MNIST experiments, laid out like the paper's Fig. 2 and its supplement figures, in the
package's one style (:mod:`bptsb_ros.analysis.style`): each writes a PNG and a PDF and returns the PNG."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import BoundaryNorm, ListedColormap
from matplotlib.ticker import MaxNLocator

from bptsb_ros.analysis.style import (
    DIGIT_COLOURS,
    DOUBLE,
    SEQUENTIAL,
    VERMILLION,
    legend_outside,
    plt,
    save,
    size,
    styled,
)

__all__ = ["DIGIT_COLOURS", "plot_best_drawings", "plot_curves", "plot_error_bars", "plot_label_map_sizes",
           "plot_label_maps", "plot_live_drawings", "plot_pca", "plot_targets"]

#: the grey of a target trajectory under a drawing
TARGET_GREY = "0.78"


def _time_line(ax, xy: np.ndarray, dt: float, t_max: float, lw: float = 1.6):
    seg = np.stack([xy[:-1], xy[1:]], axis=1)
    lc = LineCollection(seg, cmap=SEQUENTIAL, norm=plt.Normalize(0, t_max), linewidths=lw)
    lc.set_array(np.arange(len(seg)) * dt)
    ax.add_collection(lc)
    return lc


def _digit_axes(ax, title: str, lim: tuple[float, float, float, float]) -> None:
    ax.set_xlim(lim[0], lim[1])
    ax.set_ylim(lim[2], lim[3])
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=6.5)
    ax.tick_params(labelsize=5.5)
    ax.xaxis.set_major_locator(MaxNLocator(nbins=1))
    ax.yaxis.set_major_locator(MaxNLocator(nbins=1))


def _limits(arrays: Sequence[np.ndarray], pad: float = 0.08) -> tuple[float, float, float, float]:
    allp = np.concatenate([a.reshape(-1, 2) for a in arrays])
    lo, hi = allp.min(0) - pad, allp.max(0) + pad
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _decade(value: float) -> int:
    """The power of ten k with 10**k <= value < 10**(k+1) (0 for a value that is not positive)."""
    return int(np.floor(np.log10(value))) if np.isfinite(value) and value > 0 else 0


def _power_of_ten(k: int) -> str:
    """"10⁻⁴"-like text for 10**k ("1" for k = 0)."""
    sup = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
    return "1" if k == 0 else f"10{str(k).translate(sup)}"


def _grid(rows: int, cols: int, height_per_row: float, extra: float = 0.5):
    """A rows × cols grid of panels sharing both axes, the full text width wide (constrained layout)."""
    return plt.subplots(rows, cols, figsize=(DOUBLE, height_per_row * rows + extra), squeeze=False,
                        sharex=True, sharey=True, layout="constrained")


def _row_label(ax, name: str, unit: str, fontsize: float = 6.5) -> None:
    """A grid row's name beside its first panel, horizontal and broken at " + " and " (" (rotated, a name
    longer than the row ran into the neighbouring rows' names), with the axis quantity under it."""
    wrapped = name.replace(" + ", " +\n").replace(" (", "\n(")
    ax.set_ylabel(f"{wrapped}\n{unit}", rotation=0, ha="right", va="center", fontsize=fontsize, labelpad=4)


def _outer_labels(axes, xlabel: str = "x [m]", ylabel: str = "y [m]") -> None:
    """Axis labels on the bottom row and the left column of a shared grid."""
    for ax in axes[-1, :]:
        ax.set_xlabel(xlabel)
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)


@styled
def plot_targets(path: Path, targets: Sequence[np.ndarray], dt: float) -> Path:
    """All ten target trajectories ((T_d + 1, 2) [m] each; step ``dt`` [s]), the line coloured by time, the
    start (the CMP's rest position) marked."""
    t_max = max(len(t) - 1 for t in targets) * dt
    fig, axes = _grid(2, 5, 1.45, 0.6)
    lim = _limits(targets)
    lc = None
    for d, (ax, tgt) in enumerate(zip(axes.flat, targets)):
        lc = _time_line(ax, tgt, dt, t_max)
        ax.plot(*tgt[0], "o", color="k", ms=3, label="start (CMP at rest)")
        _digit_axes(ax, f"{d}: {len(tgt) - 1} steps ({(len(tgt) - 1) * dt:.2f} s)", lim)
    _outer_labels(axes)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", frameon=False)
    fig.colorbar(lc, ax=axes, label="time [s]", shrink=0.8)
    fig.suptitle("Target CMP trajectories for the digits 0-9 (one pen stroke each, minimum-jerk timing)")
    return save(fig, path)


@styled
def plot_best_drawings(path: Path, systems: dict[str, dict], targets: Sequence[np.ndarray], dt: float) -> Path:
    """Fig. 2(b)-like: for each system (row) and digit (column) the best test sample's drawing, coloured by
    time, over the target (grey); the panel title gives that sample's MSE [m²].

    ``systems``: name → {"drawings": (n, T+1, 2) [m], "errors": (n,) [m²], "labels": (n,)}.
    """
    rows = len(systems)
    fig, axes = _grid(rows, 10, 0.85, 0.7)
    best_errors = [float(np.min(s["errors"])) for s in systems.values()]
    scale = _decade(np.median(best_errors) if best_errors else 1.0)
    lim = _limits(list(targets) + [s["drawings"][np.argmin(s["errors"])] for s in systems.values()])
    t_max = max(len(t) - 1 for t in targets) * dt
    lc = None
    for r, (name, s) in enumerate(systems.items()):
        for d in range(10):
            ax = axes[r, d]
            tgt = targets[d]
            ax.plot(tgt[:, 0], tgt[:, 1], color=TARGET_GREY, lw=2.5, zorder=0)
            idx = np.flatnonzero(s["labels"] == d)
            if idx.size:
                best = idx[np.argmin(s["errors"][idx])]
                lc = _time_line(ax, s["drawings"][best][: len(tgt)], dt, t_max, lw=1.2)
                title = f"{d}: {s['errors'][best] / 10.0 ** scale:.2g}"
            else:
                title = f"{d}: no sample"
            _digit_axes(ax, title, lim)
        _row_label(axes[r, 0], name, "y [m]")
    for ax in axes[-1, :]:
        ax.set_xlabel("x [m]")
    if lc is not None:
        fig.colorbar(lc, ax=axes, label="time [s]", shrink=0.8)
    fig.suptitle("Best test drawing per digit (coloured by time) over its target (grey); panel title: digit: "
                 f"its MSE [{_power_of_ten(scale)} m²]")
    return save(fig, path)


@styled
def plot_error_bars(path: Path, names: Sequence[str], errors: Sequence[float], stds: Sequence[float],
                    title: str) -> Path:
    """Fig. 2(b)-like error table as bars: mean test MSE [m²] per system with its standard error."""
    fig, ax = plt.subplots(figsize=size(DOUBLE * 0.6, 0.6))
    x = np.arange(len(names))
    ax.bar(x, errors, yerr=stds, color=[f"C{i % 7}" for i in range(len(names))], capsize=3)
    for xi, e, sd in zip(x, errors, stds):  # the value above its error bar
        ax.annotate(f"{e:.3g}", (xi, e + sd), xytext=(0, 2), textcoords="offset points", ha="center",
                    va="bottom", fontsize=6.5)
    ax.set_xticks(x, names, rotation=20, ha="right")
    ax.set_xlabel("system")
    ax.set_ylabel("test drawing MSE [m²]")
    ax.set_ylim(0, max(float(np.max(np.add(errors, stds))) * 1.15, 1e-12))
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
    return save(fig, path)


@styled
def plot_pca(path: Path, brain_2d: np.ndarray, body_2d: np.ndarray, labels: np.ndarray,
             scores: dict[str, dict[str, float]], title: str) -> Path:
    """Fig. 2(c)-like: brain output (initial positions [m]) and body output (CMP trajectory [m]), each projected
    to 2-D by PCA ((n, 2) [m]), coloured by label."""
    fig, axes = plt.subplots(1, 2, figsize=size(DOUBLE, 0.42))
    for ax, pts, part in ((axes[0], brain_2d, "brain"), (axes[1], body_2d, "body")):
        for d in range(10):
            sel = labels == d
            ax.scatter(pts[sel, 0], pts[sel, 1], s=4, color=DIGIT_COLOURS[d], label=str(d), rasterized=True)
        sc = scores[part]
        ax.set_title(f"{part} output ({'initial positions' if part == 'brain' else 'CMP trajectory'})\n"
                     f"silhouette (2-D) {sc['silhouette_2d']:.3f}, linear probe (2-D) {100 * sc['probe_2d']:.1f} %")
        ax.set_xlabel("PC 1 [m]")
        ax.set_ylabel("PC 2 [m]")
    legend_outside(axes[1], "right", title="label", markerscale=2)
    fig.suptitle(title)
    return save(fig, path)


@styled
def plot_label_maps(path: Path, maps: np.ndarray, deltas: np.ndarray, rows: dict[str, int],
                    sizes: np.ndarray, title: str) -> Path:
    """Fig. 2(d) / supplement "Label maps": for each chosen mass (row), the 10 label maps (one per original
    label), each cell coloured by the digit the shifted body draws most like.

    maps: (10, P, G, G) labels; deltas: (G,) shifts [m]; rows: row title → mass column p in ``maps``;
    sizes: (10, P) label-map sizes [-].
    """
    cmap = ListedColormap(DIGIT_COLOURS)
    norm = BoundaryNorm(np.arange(-0.5, 10.5), 10)
    fig, axes = _grid(len(rows), 10, 0.95, 0.6)
    ext = [deltas[0], deltas[-1], deltas[0], deltas[-1]]
    im = None
    for r, (name, p) in enumerate(rows.items()):
        for d in range(10):
            ax = axes[r, d]
            im = ax.imshow(maps[d, p], origin="lower", extent=ext, cmap=cmap, norm=norm, interpolation="nearest")
            ax.set_title(f"label {d}: {sizes[d, p]:.2f}", fontsize=6)
            ax.tick_params(labelsize=5)
        _row_label(axes[r, 0], name, "Δy [m]", fontsize=6)
    for ax in axes[-1, :]:
        ax.set_xlabel("Δx [m]")
    if im is not None:
        bar = fig.colorbar(im, ax=axes, ticks=range(10), shrink=0.8)
        bar.set_label("closest target digit [0-9]")
    fig.suptitle(f"{title} (panel title: original label and label-map size)")
    return save(fig, path)


@styled
def plot_label_map_sizes(path: Path, positions: np.ndarray, springs: np.ndarray, fixed: np.ndarray,
                         cmp_index: int, mass_index: np.ndarray, size_: np.ndarray, joined: np.ndarray,
                         title: str) -> Path:
    """Fig. 2(e)-like: the body (``positions`` (N, 2) [m]) with every shifted mass coloured by its label-map
    size [-] (mean over labels); masses joined to the CMP are ringed."""
    fig, ax = plt.subplots(figsize=(DOUBLE * 0.62, DOUBLE * 0.45))
    ax.add_collection(LineCollection(positions[np.asarray(springs)], colors="0.8", linewidths=0.8, zorder=0))
    ax.scatter(*positions[fixed].T, marker="s", s=16, color="0.4", label="fixed")
    ax.scatter(*positions[cmp_index], s=50, color="k", marker="*", label="CMP")
    sc = ax.scatter(*positions[mass_index].T, c=size_, cmap=SEQUENTIAL, vmin=0, vmax=1, s=60,
                    edgecolors=np.where(joined, VERMILLION, "none"), linewidths=1.5, zorder=3)
    ax.scatter([], [], s=50, facecolors="none", edgecolors=VERMILLION, label="joined to the CMP")
    fig.colorbar(sc, ax=ax, label="label-map size [-]", pad=0.02)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    legend_outside(ax, "below", ncol=3)
    ax.set_title(title)
    return save(fig, path)


@styled
def plot_curves(path: Path, curves: dict[str, Sequence[float]], ylabel: str, title: str,
                xlabel: str = "update [-]", log: bool = True) -> Path:
    """Training curves of several systems on one axis; ``xlabel``, ``ylabel`` name their units."""
    fig, ax = plt.subplots(figsize=size(DOUBLE * 0.8, 0.4))
    for i, (name, ys) in enumerate(curves.items()):
        ax.plot(np.arange(1, len(ys) + 1), ys, lw=1, color=f"C{i % 7}", label=name)
    if log:
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_live_drawings(path: Path, live: np.ndarray, offline: np.ndarray | None, targets: Sequence[np.ndarray],
                       labels: np.ndarray, errors: np.ndarray, dt: float, reset_steps: Sequence[int],
                       max_panels: int = 20) -> Path:
    """The live MNIST loop (``bptsb replay``): one panel per episode (the first ``max_panels``; the title says
    how many of how many) with its label's target (grey), the live drawing coloured by time and, when given,
    the offline drawing of the same image (black dashed); the panel title gives the label, the reset step and
    the live MSE [m²].

    ``live``, ``offline``: (n, E, 2) [m] relative to the CMP's rest position; ``targets``: per digit (T_d + 1, 2).
    """
    n = min(len(live), max_panels)
    cols = min(n, 5)
    rows = (n + cols - 1) // cols
    fig, axes = _grid(rows, cols, DOUBLE / cols, 0.7)
    lim = _limits([targets[int(d)] for d in labels[:n]] + [live[i, : len(targets[int(labels[i])])] for i in range(n)])
    t_max = (live.shape[1] - 1) * dt
    scale = _decade(float(np.median(errors[:n])) if n else 1.0)
    lc = None
    for i, ax in enumerate(axes.flat):
        if i >= n:
            ax.axis("off")
            continue
        tgt = targets[int(labels[i])]
        ax.plot(tgt[:, 0], tgt[:, 1], color=TARGET_GREY, lw=3, zorder=0, label="target")
        steps = len(tgt)
        lc = _time_line(ax, live[i, :steps], dt, t_max, lw=1.4)
        if offline is not None:
            ax.plot(offline[i, :steps, 0], offline[i, :steps, 1], "k--", lw=0.8, label="offline")
        _digit_axes(ax, f"{int(labels[i])} (step {reset_steps[i]}): {errors[i] / 10.0 ** scale:.3g}", lim)
    _outer_labels(axes)
    for ax in axes.flat[n:]:  # an empty slot in the last row: label the panel above it instead
        above = axes.flat[list(axes.flat).index(ax) - cols]
        above.set_xlabel("x [m]")
        above.xaxis.set_tick_params(labelbottom=True)
    fig.legend(*axes.flat[0].get_legend_handles_labels(), loc="outside lower center", ncol=2, frameon=False)
    if lc is not None:
        fig.colorbar(lc, ax=axes, label="time since release [s]", shrink=0.8)
    fig.suptitle(f"Live drawings of {n} of {len(live)} episodes (coloured by time) over their targets (grey)"
                 + ("; offline drawing of the same image dashed" if offline is not None else "")
                 + f".\nPanel title: label (reset step): live MSE [{_power_of_ten(scale)} m²]")
    return save(fig, path)
