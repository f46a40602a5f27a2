"""Figures of the time-series experiments (the paper's Fig. 3 and the supplement's memory task, target IPC and
MSDN nonlinearity), in the package's one style: each writes a PNG and a PDF and returns the PNG's path."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bptsb_ros.analysis.plots import draw_ipc_bars
from bptsb_ros.analysis.style import DOUBLE, TARGET, legend_outside, plt, save, styled


@dataclass(frozen=True)
class IpcPanel:
    """One axes of stacked IPC bars (:func:`~bptsb_ros.analysis.plots.draw_ipc_bars`): ``capacity`` (B, F)
    per state set ``names`` (B,), basis-function ``degrees`` and ``max_delays`` (F,), ``ranks`` (B,)."""

    title: str
    names: Sequence[str]
    capacity: np.ndarray
    degrees: np.ndarray
    max_delays: np.ndarray
    ranks: np.ndarray | None = None
    highlight: int | None = None
    legend: bool = True

    @classmethod
    def of(cls, res, labels: Sequence[str], title: str, names: Sequence[str] | None = None,
           highlight: int | None = None, legend: bool = True) -> IpcPanel:
        """The state sets ``labels`` of an IPCResult ``res``, shown as ``names`` (default the labels)."""
        rows = [res.group(lab) for lab in labels]
        return cls(title, list(names if names is not None else labels), res.capacity[rows], res.degrees,
                   res.max_delays(), res.rank[rows], highlight, legend)


@styled
def plot_ipc_panels(path: Path, panels: Sequence[Sequence[IpcPanel]], width_ratios: Sequence[float] | None = None,
                    row_height: float = 2.6, width: float = DOUBLE) -> Path:
    """A grid of IPC bar panels (rows of :class:`IpcPanel`), e.g. the paper's Fig. 3(c) and supplement IPC
    figures; ``width`` [in], ``row_height`` [in] per row."""
    rows, cols = len(panels), max(len(r) for r in panels)
    fig, axes = plt.subplots(rows, cols, figsize=(width, row_height * rows + 0.3), squeeze=False,
                             gridspec_kw={"width_ratios": width_ratios} if width_ratios else None)
    for r, row in enumerate(panels):
        for c in range(cols):
            ax = axes[r, c]
            if c >= len(row):
                ax.axis("off")
                continue
            p = row[c]
            draw_ipc_bars(ax, p.names, p.capacity, p.degrees, p.max_delays, p.ranks, p.highlight, p.legend)
            ax.set_title(p.title)
    return save(fig, path)


@styled
def plot_memory_error(path: Path, delays: Sequence[int], errors: Mapping[str, np.ndarray], t: np.ndarray,
                      u: np.ndarray, target: np.ndarray, outputs: Mapping[str, np.ndarray], focus: int) -> Path:
    """The supplement's memory-task figure (a), (b): (a) NMSE [-] vs delay Δt (``errors``: body → (D, S) over
    ``delays`` and seeds; mean ± std), (b) the input u(t) above, the target u(t − ``focus``) and each body's
    output (CMP y [m]) below, over task steps ``t``."""
    fig = plt.figure(figsize=(DOUBLE, 3.0), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=[1, 1.5], height_ratios=[1, 1.6])
    ax = fig.add_subplot(grid[:, 0])
    seeds = 0
    for i, (b, err) in enumerate(errors.items()):
        err = np.asarray(err, dtype=float)
        seeds = err.shape[1]
        ax.errorbar(delays, err.mean(axis=1), yerr=err.std(axis=1), marker="o", capsize=3, color=f"C{i}",
                    label=f"LIL + {b}")
    ax.set_xlabel("delay Δt [task steps]")
    ax.set_ylabel("NMSE (held-out) [-]")
    ax.set_title(f"(a) memory task error,\nmean ± std over {seeds} seed(s)")
    ax.grid(alpha=0.3)
    legend_outside(ax, "below", ncol=1)
    top = fig.add_subplot(grid[0, 1])
    top.plot(t, u[t], color="0.3", lw=0.8, drawstyle="steps-mid")
    top.set_ylabel("input u [-]")
    top.set_title(f"(b) input (top), target and outputs (bottom), Δt = {focus}")
    bottom = fig.add_subplot(grid[1, 1], sharex=top)
    top.tick_params(labelbottom=False)
    bottom.plot(t, target[t], "--", color=TARGET, lw=1.5, label=f"target u(t − {focus})")
    for i, (b, y) in enumerate(outputs.items()):
        bottom.plot(t, y, color=f"C{i}", lw=1, label=f"output, {b}")
    bottom.set_xlabel("task step t [-]")
    bottom.set_ylabel("output y (CMP y) [m]")
    legend_outside(bottom, "below", ncol=3)
    return save(fig, path)


@styled
def plot_narma_emulation(path: Path, t: np.ndarray, u: np.ndarray, target: np.ndarray,
                         outputs: Mapping[str, np.ndarray], errors: Mapping[str, float], title: str) -> Path:
    """The paper's Fig. 3(b): the input u(t), the target and every system's output (CMP y [m]) on the held-out
    sequence at task steps ``t``, and the NMSE [-] per system as bars coloured like its line (the paper's table)."""
    fig, axes = plt.subplots(3, 1, figsize=(DOUBLE, 4.6), gridspec_kw={"height_ratios": [1, 2, 1.2]})
    axes[0].plot(t, u[t], color="0.3", lw=0.8, drawstyle="steps-mid")
    axes[0].set_ylabel("input u [-]")
    axes[0].set_xlabel("task step t [-]")
    axes[0].set_title(title)
    axes[1].plot(t, target[t], "--", color=TARGET, lw=1.5, label="target")
    for i, (name, out) in enumerate(outputs.items()):
        axes[1].plot(t, out[t], color=f"C{i}", lw=1.0, label=name)
    axes[1].set_ylabel("output y (CMP y) [m]")
    axes[1].set_xlabel("task step t [-] (τ = 20 simulation steps)")
    legend_outside(axes[1], "right")
    names = list(outputs)
    axes[2].barh(names, [errors[k] for k in names], color=[f"C{i}" for i in range(len(names))])
    axes[2].invert_yaxis()
    axes[2].set_xlabel("NMSE (held-out) [-]")
    axes[2].set_ylabel("system")
    axes[2].grid(axis="x", alpha=0.3)
    return save(fig, path)
