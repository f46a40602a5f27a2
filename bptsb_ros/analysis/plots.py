"""Figures for training runs and replays (matplotlib, Agg backend, 150 dpi PNG)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DPI = 150


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_loss(path: Path, losses: Sequence[float], title: str = "") -> Path:
    """Loss per update (log scale) with a running median."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    y = np.asarray(losses, dtype=float)
    x = np.arange(1, len(y) + 1)
    ax.plot(x, y, lw=0.6, color="0.6", label="per update")
    if len(y) >= 10:
        w = max(5, len(y) // 50)
        med = np.array([np.median(y[max(0, i - w + 1): i + 1]) for i in range(len(y))])
        ax.plot(x, med, lw=1.5, color="C0", label=f"running median ({w})")
    if len(y) and np.all(y[np.isfinite(y)] > 0):
        ax.set_yscale("log")
    ax.set_xlabel("update")
    ax.set_ylabel("loss")
    ax.set_title(f"BPTSB training loss {title}".strip())
    ax.legend(frameon=False)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_lissajous(path: Path, t: np.ndarray, curves: dict[str, np.ndarray], target: np.ndarray) -> Path:
    """CMP trajectories (label → (T, 2)) over the target curve (T, 2), and x(t), y(t) of the first curve."""
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.3), gridspec_kw={"width_ratios": [1, 1.4]})
    ax = axes[0]
    ax.plot(target[:, 0], target[:, 1], "k--", lw=1.2, label="target")
    for i, (label, xy) in enumerate(curves.items()):  # later curves wide and pale underneath: coincident ones show
        style = {"lw": 1.0, "alpha": 0.9, "zorder": 3} if i == 0 else {"lw": 3.0, "alpha": 0.35, "zorder": 2}
        ax.plot(xy[:, 0], xy[:, 1], color=("C0", "C3", "C2", "C4")[i % 4], label=label, **style)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("CMP trajectory")
    ax.legend(frameon=False, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2)
    ax = axes[1]
    first_label, first = next(iter(curves.items()))
    tt = t - t[0]
    ax.plot(tt, target[:, 0], "k--", lw=0.8, label="target x")
    ax.plot(tt, target[:, 1], "k:", lw=0.8, label="target y")
    ax.plot(tt, first[:, 0], color="C0", lw=1.0, label=f"x, {first_label}")
    ax.plot(tt, first[:, 1], color="C1", lw=1.0, label=f"y, {first_label}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position [m]")
    ax.legend(frameon=False, fontsize=8, ncol=2, loc="upper center", bbox_to_anchor=(0.5, -0.15))
    ax.grid(alpha=0.3)
    return _save(fig, path)


def moving_average(t: np.ndarray, y: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Centred moving average over ``window`` samples, only where the window fits (no edge artefacts)."""
    window = max(1, min(window, len(y)))
    avg = np.convolve(y, np.ones(window) / window, mode="valid")
    start = (window - 1) // 2
    return t[start:start + len(avg)], avg


def plot_speed(path: Path, t: np.ndarray, speeds: dict[str, np.ndarray], target: float | None = None,
               window: int = 1, shade: list[tuple[float, float]] | None = None, shade_label: str = "") -> Path:
    """Forward speed (mean x-velocity of all masses) over time, averaged over ``window`` steps; ``shade``:
    time intervals [s] drawn as orange bands (e.g. while the wind blows)."""
    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    for i, (a, b) in enumerate(shade or []):
        ax.axvspan(a, b, color="orange", alpha=0.25, lw=0, label=shade_label if i == 0 and shade_label else None)
    for i, (label, v) in enumerate(speeds.items()):
        ax.plot(*moving_average(t, v, window), lw=1.0, color=f"C{i}", label=label)
    if target is not None:
        ax.axhline(target, color="k", ls="--", lw=1, label="target")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"forward speed [m/s]{f', {window}-step average' if window > 1 else ''}")
    ax.legend(frameon=False)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_series(path: Path, series: dict[str, np.ndarray], xlabel: str, ylabel: str, title: str = "",
                shade: tuple[int, int] | None = None) -> Path:
    """Several aligned time series (e.g. NARMA input, target and output)."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for i, (label, y) in enumerate(series.items()):
        ax.plot(np.arange(len(y)), y, lw=1.0, color=f"C{i}", label=label, drawstyle="steps-mid")
    if shade is not None:
        ax.axvspan(*shade, color="0.9", zorder=0, label="test samples")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.legend(frameon=False, fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_spring_lengths(path: Path, t: np.ndarray, lengths: np.ndarray, max_springs: int = 12) -> Path:
    """Spring lengths (T, E) over time (first ``max_springs`` springs)."""
    fig, ax = plt.subplots(figsize=(7, 3.5))
    for e in range(min(max_springs, lengths.shape[1])):
        ax.plot(t, lengths[:, e], lw=0.8, label=f"spring {e}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("length [m]")
    ax.legend(frameon=False, fontsize=6, ncol=4)
    ax.grid(alpha=0.3)
    return _save(fig, path)


IPC_CMAPS = ("Blues", "Oranges", "Greens", "Purples", "Greys")


def draw_ipc_bars(ax, names: Sequence[str], capacity: np.ndarray, degrees: np.ndarray, max_delays: np.ndarray,
                  ranks: Sequence[float] | None = None, highlight: int | None = None, legend: bool = True) -> None:
    """Stacked IPC bars in the style of the paper's Fig. 3(c): one bar per state set (``capacity`` (B, F)),
    segments by degree n (colour: blue = linear) and by the longest delay Δt (shade: darker = shorter delay);
    ``highlight`` (a basis-function column) is drawn in red at the bottom; a black tick marks each rank."""
    capacity = np.atleast_2d(capacity)
    top_delay = max(int(max_delays.max()), 1)
    x = np.arange(len(names))
    bottom = np.zeros(len(names))
    if highlight is not None:
        h = capacity[:, highlight]
        ax.bar(x, h, bottom=bottom, color="red", width=0.8, edgecolor="none")
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
    ax.set_xticklabels(names, rotation=90, fontsize=7)
    ax.set_ylabel("capacity C")
    ax.set_ylim(0, max(1.05, float(bottom.max()) * 1.08, float(np.max(ranks)) * 1.08 if ranks is not None else 0))
    if legend:
        from matplotlib.patches import Patch

        handles = [Patch(color=plt.get_cmap(IPC_CMAPS[min(n, len(IPC_CMAPS)) - 1])(0.75), label=f"n = {n}")
                   for n in range(1, int(degrees.max()) + 1)]
        if highlight is not None:
            handles.insert(0, Patch(color="red", label="highlighted term"))
        handles.append(Patch(color="white", label=f"shade: Δt 0 (dark) … {top_delay} (light)"))
        if ranks is not None:
            from matplotlib.lines import Line2D

            handles.append(Line2D([], [], color="k", marker="_", ls="none", markersize=12, label="rank"))
        ax.legend(handles=handles, fontsize=7, frameon=False, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.grid(axis="y", alpha=0.3)


def plot_ipc_bars(path: Path, res, labels: Sequence[str] | None = None, title: str = "",
                  highlight: int | None = None) -> Path:
    """One figure of :func:`draw_ipc_bars` for the state sets ``labels`` (default all) of an IPCResult."""
    labels = list(labels) if labels is not None else list(res.labels)
    rows = [res.group(lab) for lab in labels]
    fig, ax = plt.subplots(figsize=(max(4.0, 0.28 * len(labels) + 3), 4))
    draw_ipc_bars(ax, labels, res.capacity[rows], res.degrees, res.max_delays(), res.rank[rows], highlight)
    ax.set_title(title, fontsize=9)
    return _save(fig, path)
