"""Figures over seeds: what ``bptsb reproduce --seeds`` draws beside the first seed's own figures.

:func:`plot_seed_summary` is every multi-seed run's verdict strip: one line per claim, one cell per seed
(holds, fails, not testable), with k/n and the verdict over seeds at the end of the line. :func:`plot_band`
draws a curve over seeds as its mean with the band between the seeds' minimum and maximum, for the experiments
whose claims read a curve (return rate against σ, error against Δt), and :func:`plot_band_panels` such bands in
panels side by side (one per protocol variant); :func:`plot_bars_over_seeds` one number per system (an accuracy, an
error, a size) as bars of the mean with the seeds' range, each seed's value and the paper's. For what is a class or
a yes/no per seed rather than a number: :func:`plot_share_panels` (the share of seeds where something holds, against
a parameter), :func:`plot_period_map` (a class per seed and parameter value, one row per seed) and
:func:`plot_count_histogram` (a count per seed, with the paper's count marked).
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
    ORANGE,
    PALETTE,
    PURPLE,
    TARGET,
    VERMILLION,
    legend_outside,
    save,
    size,
    styled,
)

_CELL = {True: (GREEN, "✓"), False: (VERMILLION, "✗"), None: ("0.85", "∅")}


@styled
def plot_seed_summary(path: Path, claims: Sequence[Mapping[str, Any]], seeds: Sequence[int], experiment: str) -> Path:
    """The verdict of every claim (rows) in every seed (columns) of one experiment, with ``k/n`` (holding of
    testable) at the right; ``claims`` are the aggregated claims of the seeds' results
    (:func:`bptsb_ros.experiments.seeds.aggregate_claims`: ``per_seed`` verdicts in the order of ``seeds`` and
    ``holds_in``) of the experiment named ``experiment``."""
    import matplotlib.pyplot as plt

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
    ax.set_ylabel("claim")
    ax.tick_params(length=0)
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    ax.set_title(f"{experiment}: the paper's claims, seed by seed", fontsize=7)
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
    step = float(np.min(np.diff(np.sort(x)))) if len(x) > 1 else 1.0
    for i, at in enumerate(highlight):
        ax.axvspan(at - step / 2, at + step / 2, color="0.88", lw=0, zorder=0,
                   label=highlight_label if i == 0 and highlight_label else None)
    _bands(ax, x, curves)
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


_COLOURS = [BLUE, VERMILLION, GREEN, ORANGE, PURPLE]


def _bands(ax, x: np.ndarray, curves: Mapping[str, np.ndarray]) -> None:
    """Each curve (seeds, len(x)) as its mean over seeds (NaN ignored) and the band of the seeds' min–max."""
    for (name, ys), colour in zip(curves.items(), _COLOURS * 4, strict=False):
        ys = np.asarray(ys, dtype=float).reshape(-1, len(x))
        mean, lo, hi = _mean_range(ys)
        ax.plot(x, mean, "o-", ms=3, color=colour, label=f"{name} (mean of {ys.shape[0]} seeds)")
        ax.fill_between(x, lo, hi, color=colour, alpha=0.2, lw=0, label=f"{name}: seeds' min–max")


def _spans(ax, spans: Sequence[tuple[float, float, str]]) -> None:
    """Shade each (lo, hi, label) span of x grey (the paper's regions), labelled in the legend."""
    for i, (lo, hi, label) in enumerate(spans):
        ax.axvspan(lo, hi, color="0.85" if i % 2 == 0 else "0.75", alpha=0.6, lw=0, zorder=0, label=label)


def _panel_grid(n: int, height: float = 2.6):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, max(n, 1), figsize=(DOUBLE, height), squeeze=False, sharey=True)
    return fig, axes[0]


@styled
def plot_band_panels(path: Path, panels: Mapping[str, Mapping[str, Any]], *, xlabel: str, ylabel: str, title: str,
                     hline: float | None = None, ylim: tuple[float, float] | None = None) -> Path:
    """Curves over seeds in panels side by side, one per entry of ``panels`` (title → {"x": (X,), "curves": name →
    (seeds, X), optional "spans": [(lo, hi, label)] shaded (the paper's regions), optional "xlabel"}): each curve
    as its mean over seeds with the band of the seeds' minimum and maximum (:func:`plot_band`'s drawing); ``hline``:
    a threshold drawn dotted in every panel."""
    fig, axes = _panel_grid(len(panels))
    for ax, (name, panel) in zip(axes, panels.items(), strict=False):
        _spans(ax, panel.get("spans", ()))
        _bands(ax, np.asarray(panel["x"], dtype=float), panel["curves"])
        if hline is not None:
            ax.axhline(hline, color="0.4", ls=":", lw=0.8)
        if ylim is not None:
            ax.set_ylim(*ylim)
        ax.set_xlabel(panel.get("xlabel", xlabel))
        ax.set_title(name)
        ax.grid(alpha=0.3)
        legend_outside(ax, "below", ncol=1)
    axes[0].set_ylabel(ylabel)
    fig.suptitle(title)
    return save(fig, path)


@styled
def plot_share_panels(path: Path, panels: Mapping[str, Mapping[str, Any]], *, xlabel: str, ylabel: str,
                      title: str) -> Path:
    """The share of seeds in which something holds, against a parameter, in panels side by side: ``panels``:
    title → {"x": (X,), "shares": name → (seeds, X) bool (NaN-free), optional "spans": [(lo, hi, label)] shaded}.
    Each line is the mean over seeds (a share in [0, 1]); the legend names how many seeds."""
    fig, axes = _panel_grid(len(panels))
    for ax, (name, panel) in zip(axes, panels.items(), strict=False):
        _spans(ax, panel.get("spans", ()))
        x = np.asarray(panel["x"], dtype=float)
        for (label, ok), colour in zip(panel["shares"].items(), _COLOURS * 4, strict=False):
            ok = np.asarray(ok, dtype=float).reshape(-1, len(x))
            ax.step(x, ok.mean(0), where="mid", color=colour, lw=1.2, label=f"{label} ({ok.shape[0]} seeds)")
        ax.set_ylim(-0.03, 1.03)
        ax.set_xlabel(xlabel)
        ax.set_title(name)
        ax.grid(alpha=0.3)
        legend_outside(ax, "below", ncol=1)
    axes[0].set_ylabel(ylabel)
    fig.suptitle(title)
    return save(fig, path)


#: the classes of :func:`plot_period_map`: code → (colour, name)
PERIOD_CLASSES = {-1: ("0.2", "diverged"), 0: (VERMILLION, "aperiodic (chaotic)"), 1: (BLUE, "period 1"),
                  2: (GREEN, "period m ≥ 2")}


@styled
def plot_period_map(path: Path, x: np.ndarray, panels: Mapping[str, tuple[Sequence[int], np.ndarray]], *,
                    xlabel: str, title: str, spans: Sequence[tuple[float, float, str]] = ()) -> Path:
    """The orbit class of every seed (rows) at every parameter value (columns), one panel per entry of ``panels``
    (title → (the seeds, (seeds, X) periods: m ≥ 1 periodic, 0 aperiodic, −1 diverged)); ``spans``: the paper's
    regions (lo, hi, words), drawn as a strip above the panels and as dashed edges across them."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    x = np.asarray(x, dtype=float)
    rows = [max(len(seeds), 1) for seeds, _ in panels.values()] or [1]
    heights = [0.35 + 0.1 * r for r in rows]
    fig, axes = plt.subplots(len(rows) + 1, 1, figsize=(DOUBLE, 1.3 + sum(heights) + 0.3 * len(rows)), sharex=True,
                             gridspec_kw={"height_ratios": [0.18, *heights]})
    cmap = ListedColormap([PERIOD_CLASSES[c][0] for c in sorted(PERIOD_CLASSES)])
    step = float(np.median(np.diff(x))) if len(x) > 1 else 1.0
    strip = axes[0]
    for i, (lo, hi, words) in enumerate(spans):
        strip.axvspan(lo, hi, color="0.8" if i % 2 == 0 else "0.65", lw=0)
        strip.text((lo + hi) / 2, 0.5, words, ha="center", va="center", fontsize=6)
    strip.set_ylim(0, 1)
    strip.set_yticks([0.5], ["paper"])
    strip.set_ylabel("regions", rotation=0, ha="right", va="center")
    strip.tick_params(length=0)
    for ax, (name, (seeds, per)) in zip(axes[1:], panels.items(), strict=False):
        per = np.asarray(per).reshape(len(seeds), len(x))
        code = np.clip(per, -1, 2)  # m ≥ 2 as one class
        ax.imshow(code + 1, cmap=cmap, vmin=-0.5, vmax=3.5, aspect="auto", interpolation="nearest",
                  extent=(x[0] - step / 2, x[-1] + step / 2, len(seeds) - 0.5, -0.5))
        for lo, hi, _ in spans:
            for edge in (lo, hi):
                ax.axvline(edge, color="white", ls="--", lw=0.8)
        ax.set_yticks(range(len(seeds)), [str(s) for s in seeds], fontsize=5.5)
        ax.set_ylabel("seed [index]")
        ax.set_title(name)
    axes[-1].set_xlabel(xlabel)
    handles = [Patch(color=c, label=w) for c, w in (PERIOD_CLASSES[k] for k in sorted(PERIOD_CLASSES))]
    legend_outside(axes[-1], "below", handles=handles, ncol=4)
    fig.suptitle(title)
    return save(fig, path)


@styled
def plot_count_histogram(path: Path, counts: Sequence[int], *, total: int, paper: int | None, xlabel: str,
                         title: str) -> Path:
    """How many seeds gave each count (0 … ``total``), as bars; the paper's count marked by a dashed line."""
    import matplotlib.pyplot as plt

    counts = np.asarray(counts, dtype=int)
    fig, ax = plt.subplots(figsize=size(aspect=0.5))
    bins = np.arange(total + 1)
    ax.bar(bins, [int(np.sum(counts == k)) for k in bins], width=0.8, color=BLUE,
           label=f"our seeds (n = {len(counts)}; mean {counts.mean():.1f})" if len(counts) else "our seeds")
    if paper is not None:
        ax.axvline(paper, color=TARGET, ls="--", lw=1.2, zorder=3, label=f"paper: {paper}")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("seeds [count]")
    ax.set_xlim(-0.6, total + 0.6)
    ax.set_title(title)
    legend_outside(ax, "right")
    return save(fig, path)
