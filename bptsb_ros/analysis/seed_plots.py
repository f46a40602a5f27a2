"""Figures over seeds: what ``bptsb reproduce --seeds`` draws beside the first seed's own figures.

:func:`plot_seed_summary` is every multi-seed run's verdict strip: one line per claim, one cell per seed
(holds, fails, not testable), with k/n and the verdict over seeds at the end of the line. :func:`plot_band`
draws a curve over seeds as its mean with the band between the seeds' minimum and maximum, for the experiments
whose claims read a curve (return rate against σ, error against Δt); :func:`plot_bars_over_seeds` one number per
system (an accuracy, an error, a size) as bars of the mean with the seeds' range, each seed's value and the paper's.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.analysis.style import (
    BLUE,
    DOUBLE,
    GREEN,
    PALETTE,
    TARGET,
    VERMILLION,
    legend_outside,
    save,
    size,
    styled,
)

_CELL = {True: (GREEN, "✓"), False: (VERMILLION, "✗"), None: ("0.85", "∅")}


@styled
def plot_seed_summary(path: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> Path:
    """The verdict of every claim (rows) in every seed (columns) of one experiment, with ``k/n`` (holding of
    testable) at the right; ``per_seed`` are the seeds' result.json contents in the order of ``seeds``."""
    import matplotlib.pyplot as plt

    from bptsb_ros.experiments.seeds import aggregate_claims

    claims = aggregate_claims(per_seed)
    n_claims, n_seeds = max(1, len(claims)), len(seeds)
    width = min(7.0, 3.6 + 0.22 * n_seeds)
    fig, ax = plt.subplots(figsize=(width, 0.3 + 0.34 * n_claims))
    for i, c in enumerate(claims):
        for j, v in enumerate(c["per_seed"]):
            colour, mark = _CELL[v]
            ax.add_patch(plt.Rectangle((j, i), 0.92, 0.86, color=colour, lw=0))
            ax.text(j + 0.46, i + 0.45, mark, ha="center", va="center", fontsize=6,
                    color="white" if v is not None else "0.3")
        k, n = c["holds_in"]
        ax.text(n_seeds + 0.2, i + 0.45, f"{k}/{n} {_verdict_word(c['verdict'])}", va="center", fontsize=6)
    ax.set_xlim(0, n_seeds + 2.6)
    ax.set_ylim(n_claims, 0)
    ax.set_xticks(np.arange(n_seeds) + 0.46, [str(s) for s in seeds], fontsize=6)
    ax.set_yticks(np.arange(len(claims)) + 0.45,
                  [textwrap.shorten(c["claim"], 70, placeholder=" …") for c in claims], fontsize=6)
    ax.set_xlabel("seed [-]   (✓ holds, ✗ fails, ∅ not testable; k/n: seeds where it holds / could test it)")
    ax.tick_params(length=0)
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    name = per_seed[0]["experiment"] if per_seed else ""
    ax.set_title(f"{name}: the paper's claims, seed by seed", fontsize=7)
    return save(fig, path)


def _verdict_word(verdict: str) -> str:
    return {"holds": "✓", "fails": "✗", "split": "split", "not_testable": "∅"}[verdict]


def _mean_range(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, minimum and maximum over axis 0 (seeds) ignoring NaN; NaN where no seed has a value."""
    values = np.asarray(values, dtype=float)
    ok = ~np.all(np.isnan(values), axis=0)
    mean = np.full(values.shape[1:], np.nan)
    lo, hi = mean.copy(), mean.copy()
    mean[ok], lo[ok], hi[ok] = np.nanmean(values[:, ok], 0), np.nanmin(values[:, ok], 0), np.nanmax(values[:, ok], 0)
    return mean, lo, hi


@styled
def plot_band(path: Path, x: np.ndarray, curves: Mapping[str, np.ndarray], *, xlabel: str, ylabel: str,
              title: str, reference: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
              hline: float | None = None, hline_label: str = "", highlight: Sequence[float] = (),
              highlight_label: str = "") -> Path:
    """Curves over seeds: for each name, ``curves[name]`` is (seeds, len(x)); drawn as the mean over seeds (NaN
    ignored) with a band from the seeds' minimum to their maximum and the number of seeds in the legend.
    ``reference``: name → (x, y) drawn as a black dashed line (the paper's values where it gives them);
    ``hline``: a threshold drawn dotted (``hline_label`` in the legend); ``highlight``: x positions shaded grey
    (``highlight_label`` in the legend), e.g. the digits a sentence names."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size(aspect=0.55))
    colours = [BLUE, VERMILLION, GREEN, "#E69F00", "#CC79A7"]
    step = float(np.min(np.diff(np.sort(x)))) if len(x) > 1 else 1.0
    for i, at in enumerate(highlight):
        ax.axvspan(at - step / 2, at + step / 2, color="0.88", lw=0, zorder=0,
                   label=highlight_label if i == 0 and highlight_label else None)
    for (name, ys), colour in zip(curves.items(), colours * 4, strict=False):
        ys = np.asarray(ys, dtype=float)
        mean, lo, hi = _mean_range(ys)
        ax.plot(x, mean, "o-", ms=3, color=colour, label=f"{name} (mean of {ys.shape[0]} seeds)")
        ax.fill_between(x, lo, hi, color=colour, alpha=0.2, lw=0, label=f"{name}: seeds' min–max")
    for name, (rx, ry) in (reference or {}).items():
        ax.plot(rx, ry, "--", color=TARGET, lw=1, label=name)
    if hline is not None:
        ax.axhline(hline, color="0.5", ls=":", lw=0.8, label=hline_label or None)
    if len(x) <= 12:  # a tick at every point (digits, σ in steps of 0.1)
        ax.set_xticks(x)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    legend_outside(ax, "right")
    return save(fig, path)


@dataclass(frozen=True)
class Bars:
    """One panel of :func:`plot_bars_over_seeds`.

    names: (k,) the bars; values: (seeds, k), NaN where a seed has no value; ylabel: the quantity with its unit;
    paper: (k,) the paper's values (NaN where it gives none) or None; hline: (value, legend text) of a threshold
    or None; groups: (k,) a group per bar, each group its colour and legend entry (None: one colour); title: the
    panel's title; xlabel: what the bars are; bars: False draws each mean as a short line instead of a bar from
    zero, with the axis fitted to the values (for numbers whose differences are small beside their size, e.g.
    accuracies near 95 %)."""

    names: Sequence[str]
    values: np.ndarray
    ylabel: str
    paper: Sequence[float] | None = None
    hline: tuple[float, str] | None = None
    groups: Sequence[str] | None = None
    title: str = ""
    xlabel: str = "system"
    bars: bool = True


@styled
def plot_bars_over_seeds(path: Path, panels: Sequence[Bars], title: str) -> Path:
    """One number per system over seeds, panels side by side: for each bar the mean over the seeds with a value,
    a whisker from the seeds' minimum to their maximum, each seed's value as a dot and, where given, the paper's
    value as an open diamond; the mean is written above its whisker (in a panel of at most 8 bars)."""
    import matplotlib.pyplot as plt

    widths = [max(2, len(p.names)) for p in panels]
    fig, axes = plt.subplots(1, len(panels), figsize=(DOUBLE, 0.4 * DOUBLE), squeeze=False, layout="constrained",
                             gridspec_kw={"width_ratios": widths})
    handles: dict[str, object] = {}
    for ax, p in zip(axes[0], panels, strict=True):
        values = np.asarray(p.values, dtype=float).reshape(-1, len(p.names))
        n_seeds = values.shape[0]
        mean, lo, hi = _mean_range(values)
        x = np.arange(len(p.names))
        groups = list(p.groups) if p.groups is not None else [None] * len(p.names)
        order = list(dict.fromkeys(groups))
        colour = {g: PALETTE[i % len(PALETTE)] for i, g in enumerate(order)}
        for g in order:
            sel = np.array([gg == g for gg in groups])
            if p.bars:
                drawn = ax.bar(x[sel], np.nan_to_num(mean[sel]), color=colour[g], alpha=0.6, width=0.7)
            else:
                drawn = ax.scatter(x[sel], mean[sel], marker="_", s=220, color=colour[g], lw=2, zorder=2)
            handles.setdefault(g if g is not None else f"mean of the seeds (of {n_seeds})", drawn)
        ok = ~np.isnan(mean)
        whisker = ax.errorbar(x[ok], mean[ok], yerr=[mean[ok] - lo[ok], hi[ok] - mean[ok]], fmt="none", ecolor="k",
                              elinewidth=0.8, capsize=3)
        handles.setdefault("seeds' min–max", whisker)
        jitter = np.linspace(-0.18, 0.18, n_seeds) if n_seeds > 1 else np.zeros(1)
        for k in range(n_seeds):
            dots = ax.scatter(x + jitter[k], values[k], s=5, color="k", zorder=3, lw=0)
            handles.setdefault("one seed", dots)
        if p.paper is not None:
            paper = np.asarray(p.paper, dtype=float)
            marks = ax.scatter(x, paper, marker="D", s=18, facecolors="white", edgecolors=TARGET, zorder=4, lw=0.8)
            handles.setdefault("paper", marks)
        if p.hline is not None:
            handles.setdefault(p.hline[1], ax.axhline(p.hline[0], color="0.4", ls=":", lw=0.8))
        for xi, m, h in zip(x[ok], mean[ok], hi[ok]) if len(p.names) <= 8 else ():  # room for the numbers
            ax.annotate(f"{m:.3g}", (xi, h), xytext=(0, 2), textcoords="offset points", ha="center", va="bottom",
                        fontsize=6)
        shown = np.concatenate([lo[ok], hi[ok], values[~np.isnan(values)],
                                np.asarray(p.paper, float) if p.paper is not None else [],
                                [p.hline[0]] if p.hline is not None else []])
        shown = shown[np.isfinite(shown)]
        top, low = (float(shown.max()), float(shown.min())) if shown.size else (1.0, 0.0)
        if p.bars:
            ax.set_ylim(min(0.0, low * 1.1), top * 1.15 if top > 0 else 1.0)
        else:
            pad = 0.12 * (top - low) if top > low else max(abs(top) * 0.05, 1e-9)
            ax.set_ylim(low - pad, top + 1.5 * pad)
        ax.set_xticks(x, p.names, rotation=25, ha="right")
        ax.set_xlabel(p.xlabel)
        ax.set_ylabel(p.ylabel)
        if p.title:
            ax.set_title(p.title)
        ax.grid(axis="y", alpha=0.3)
    fig.legend(list(handles.values()), list(handles.keys()), loc="outside lower center", ncol=min(4, len(handles)),
               frameon=False)
    fig.suptitle(title)
    return save(fig, path)
