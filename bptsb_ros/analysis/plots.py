"""Figures for training runs and replays, in the package's one style (:mod:`bptsb_ros.analysis.style`):
each function writes a PNG and a PDF beside it and returns the PNG's path."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib
import numpy as np

from bptsb_ros.analysis.style import (  # noqa: F401  (DPI re-exported for callers of the old name)
    BLUE,
    DOUBLE,
    DPI,
    GREEN,
    ORANGE,
    PURPLE,
    SEQUENTIAL,
    SINGLE,
    TARGET,
    VERMILLION,
    colours,
    legend_outside,
    plt,
    save,
    size,
    styled,
)


def running_median(y: np.ndarray, window: int) -> np.ndarray:
    """Median of the last ``window`` values at each index (fewer at the start): (T,) → (T,); vectorised in
    chunks of rows, so memory stays near 2**22 values whatever T × window."""
    y = np.asarray(y, dtype=float)
    if y.size == 0:
        return y
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([np.full(window - 1, np.nan), y]), window)
    rows = max(1, (1 << 22) // window)
    return np.concatenate([np.nanmedian(windows[i:i + rows], axis=1) for i in range(0, len(y), rows)])


@styled
def plot_loss(path: Path, losses: Sequence[float], loss_label: str, title: str = "") -> Path:
    """Loss per update (log scale where all positive) with a running median.

    ``loss_label``: the loss and its unit for the y axis, e.g. ``"trajectory MSE [m²]"``.
    """
    fig, ax = plt.subplots(figsize=size(SINGLE * 1.6, 0.55))
    y = np.asarray(losses, dtype=float)
    x = np.arange(1, len(y) + 1)
    ax.plot(x, y, lw=0.6, color="0.6", label="per update")
    if len(y) >= 10:
        w = max(5, len(y) // 50)
        ax.plot(x, running_median(y, w), lw=1.5, color=BLUE, label=f"running median ({w} updates)")
    if len(y) and np.all(y[np.isfinite(y)] > 0):
        ax.set_yscale("log")
    ax.set_xlabel("update [-]")
    ax.set_ylabel(loss_label)
    ax.set_title(f"BPTSB training loss {title}".strip())
    legend_outside(ax, "below")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_lissajous(path: Path, t: np.ndarray, curves: dict[str, np.ndarray], target: np.ndarray,
                   closes_at: float | None = None) -> Path:
    """CMP trajectories (label → (T, 2) [m]) over the target curve (T, 2) [m], and x(t), y(t) of the first
    curve; ``t``: (T,) [s]. ``closes_at`` [s from t[0]]: where the loop closes (the feedback layer takes over from
    the SWG), marked on both panels."""
    fig, axes = plt.subplots(1, 2, figsize=size(DOUBLE, 0.42), gridspec_kw={"width_ratios": [1, 1.5]})
    ax = axes[0]
    ax.plot(target[:, 0], target[:, 1], "--", color=TARGET, lw=1.2, label="target")
    palette = (BLUE, VERMILLION, GREEN, PURPLE)
    for i, (label, xy) in enumerate(curves.items()):  # later curves wide and pale underneath: coincident ones show
        style = {"lw": 1.0, "alpha": 0.9, "zorder": 3} if i == 0 else {"lw": 3.0, "alpha": 0.35, "zorder": 2}
        ax.plot(xy[:, 0], xy[:, 1], color=palette[i % len(palette)], label=label, **style)
    first_label, first = next(iter(curves.items()))
    tt = t - t[0]
    closing = f"loop closes (t = {closes_at:g} s)" if closes_at is not None else ""
    if closes_at is not None:
        k = int(np.argmin(np.abs(tt - closes_at)))
        ax.plot(first[k, 0], first[k, 1], "o", color=TARGET, ms=5, zorder=4, label=closing)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("CMP trajectory")
    legend_outside(ax, "below", ncol=1)
    ax = axes[1]
    if closes_at is not None:
        ax.axvline(closes_at, color=TARGET, lw=1.0, ls="-.", label=closing)
    ax.plot(tt, target[:, 0], "--", color=TARGET, lw=0.8, label="target x")
    ax.plot(tt, target[:, 1], ":", color=TARGET, lw=0.8, label="target y")
    ax.plot(tt, first[:, 0], color=BLUE, lw=1.0, label=f"x, {first_label}")
    ax.plot(tt, first[:, 1], color=VERMILLION, lw=1.0, label=f"y, {first_label}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position [m]")
    legend_outside(ax, "below")
    ax.grid(alpha=0.3)
    return save(fig, path)


def moving_average(t: np.ndarray, y: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Centred moving average over ``window`` samples, only where the window fits (no edge artefacts)."""
    window = max(1, min(window, len(y)))
    avg = np.convolve(y, np.ones(window) / window, mode="valid")
    start = (window - 1) // 2
    return t[start:start + len(avg)], avg


@styled
def plot_speed(path: Path, t: np.ndarray, speeds: dict[str, np.ndarray], target: float | None = None,
               window: int = 1, shade: list[tuple[float, float]] | None = None, shade_label: str = "") -> Path:
    """Forward speed [m/s] (mean x-velocity of all masses) over time ``t`` [s], averaged over ``window`` steps;
    ``shade``: time intervals [s] drawn as orange bands (e.g. while the wind blows)."""
    fig, ax = plt.subplots(figsize=size(DOUBLE * 0.8, 0.4))
    for i, (a, b) in enumerate(shade or []):
        ax.axvspan(a, b, color=ORANGE, alpha=0.25, lw=0, label=shade_label if i == 0 and shade_label else None)
    for i, (label, v) in enumerate(speeds.items()):
        ax.plot(*moving_average(t, v, window), lw=1.0, color=f"C{i}", label=label)
    if target is not None:
        ax.axhline(target, color=TARGET, ls="--", lw=1, label="target")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("forward speed [m/s]")
    if window > 1:
        ax.set_title(f"forward speed, {window}-step moving average")
    legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_series(path: Path, series: dict[str, np.ndarray], xlabel: str, ylabel: str, title: str = "",
                shade: tuple[int, int] | None = None) -> Path:
    """Several aligned time series (e.g. NARMA input, target and output); ``xlabel``, ``ylabel`` with units."""
    fig, ax = plt.subplots(figsize=size(DOUBLE, 0.35))
    for i, (label, y) in enumerate(series.items()):
        ax.plot(np.arange(len(y)), y, lw=1.0, color=f"C{i}", label=label, drawstyle="steps-mid")
    if shade is not None:
        ax.axvspan(*shade, color="0.9", zorder=0, label="test samples")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


@styled
def plot_spring_lengths(path: Path, t: np.ndarray, lengths: np.ndarray, springs: Sequence[int] | None = None) -> Path:
    """Spring lengths (T, E) [m] over time ``t`` (T,) [s]: every spring (or those in ``springs``); up to 7 springs
    in the palette with a legend, more coloured by spring index (``viridis``, colorbar); the title says which
    springs of how many are shown."""
    lengths = np.asarray(lengths, dtype=float)
    total = lengths.shape[1]
    shown = np.arange(total) if springs is None else np.asarray(springs, dtype=int)
    if shown.size == 0 or shown.min() < 0 or shown.max() >= total:
        raise ValueError(f"spring indices must lie in 0..{total - 1}, got {shown.tolist()}")
    fig, ax = plt.subplots(figsize=size(DOUBLE * 0.8, 0.45))
    many = shown.size > 7
    norm = plt.Normalize(0, max(total - 1, 1))
    cols = plt.get_cmap(SEQUENTIAL)(0.9 * norm(shown)) if many else colours(shown.size)
    for e, c in zip(shown, cols, strict=True):
        ax.plot(t, lengths[:, e], lw=0.7, color=c, label=f"spring {e}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("spring length [m]")
    which = "all" if shown.size == total else "springs " + ", ".join(map(str, shown[:8])) + (
        " …" if shown.size > 8 else "")
    ax.set_title(f"spring lengths: {shown.size} of {total} springs ({which})")
    if many:
        cmap = matplotlib.colors.LinearSegmentedColormap.from_list(
            "springs", plt.get_cmap(SEQUENTIAL)(np.linspace(0, 0.9, 256)))
        fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="spring index [-]", pad=0.02)
    else:
        legend_outside(ax, "right")
    ax.grid(alpha=0.3)
    return save(fig, path)


IPC_CMAPS = ("Blues", "Oranges", "Greens", "Purples", "Greys")
#: the colour of a highlighted basis function in IPC bars
HIGHLIGHT = "black"


def draw_ipc_bars(ax, names: Sequence[str], capacity: np.ndarray, degrees: np.ndarray, max_delays: np.ndarray,
                  ranks: Sequence[float] | None = None, highlight: int | None = None, legend: bool = True) -> None:
    """Stacked IPC bars in the style of the paper's Fig. 3(c): one bar per state set (``capacity`` (B, F)),
    segments by degree n (colour: blue = linear) and by the longest delay Δt (shade: darker = shorter delay);
    ``highlight`` (a basis-function column) is drawn in black at the bottom (red in the paper: black stays apart
    from the degree colours for every colour vision); a black tick marks each rank.
    Call it inside a :func:`~bptsb_ros.analysis.style.styled` function."""
    capacity = np.atleast_2d(capacity)
    top_delay = max(int(max_delays.max()), 1)
    x = np.arange(len(names))
    bottom = np.zeros(len(names))
    if highlight is not None:
        h = capacity[:, highlight]
        ax.bar(x, h, bottom=bottom, color=HIGHLIGHT, width=0.8, edgecolor="none")
        bottom += h
        capacity = capacity.copy()
        capacity[:, highlight] = 0
    for n in range(1, int(degrees.max()) + 1):
        cmap = plt.get_cmap(IPC_CMAPS[min(n, len(IPC_CMAPS)) - 1])
        for d in range(top_delay + 1):
            cols = (degrees == n) & (max_delays == d)
            if not cols.any():
                continue
            seg = capacity[:, cols].sum(axis=1)
            if not seg.any():
                continue
            ax.bar(x, seg, bottom=bottom, color=cmap(0.9 - 0.65 * d / top_delay), width=0.8, edgecolor="none")
            bottom += seg
    if ranks is not None:
        ax.scatter(x, ranks, marker="_", s=200, color="k", zorder=5, label="rank")
    ax.set_xticks(x)
    ax.set_xticklabels(names, rotation=90, fontsize=6)
    ax.set_xlabel("state set")
    ax.set_ylabel("capacity C [-]")
    ax.set_ylim(0, max(1.05, float(bottom.max()) * 1.08, float(np.max(ranks)) * 1.08 if ranks is not None else 0))
    if legend:
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch

        handles = [Patch(color=plt.get_cmap(IPC_CMAPS[min(n, len(IPC_CMAPS)) - 1])(0.75), label=f"n = {n}")
                   for n in range(1, int(degrees.max()) + 1)]
        if highlight is not None:
            handles.insert(0, Patch(color=HIGHLIGHT, label="highlighted term"))
        handles.append(Patch(color="white", label=f"shade: Δt 0 (dark) … {top_delay} (light)"))
        if ranks is not None:
            handles.append(Line2D([], [], color="k", marker="_", ls="none", markersize=12, label="rank"))
        legend_outside(ax, "right", handles=handles)
    ax.grid(axis="y", alpha=0.3)


@styled
def plot_ipc_bars(path: Path, res, labels: Sequence[str] | None = None, title: str = "",
                  highlight: int | None = None) -> Path:
    """One figure of :func:`draw_ipc_bars` for the state sets ``labels`` (default all) of an IPCResult."""
    labels = list(labels) if labels is not None else list(res.labels)
    rows = [res.group(lab) for lab in labels]
    fig, ax = plt.subplots(figsize=(min(DOUBLE, max(SINGLE, 0.2 * len(labels) + 2.5)), 3.0))
    draw_ipc_bars(ax, labels, res.capacity[rows], res.degrees, res.max_delays(), res.rank[rows], highlight)
    ax.set_title(title)
    return save(fig, path)
