"""Figures over seeds: what ``bptsb reproduce --seeds`` draws beside the first seed's own figures.

:func:`plot_seed_summary` is every multi-seed run's verdict strip: one line per claim, one cell per seed
(holds, fails, not testable), with k/n and the verdict over seeds at the end of the line. :func:`plot_band`
draws a curve over seeds as its mean with the band between the seeds' minimum and maximum, for the experiments
whose claims read a curve (return rate against σ, error against Δt); :func:`plot_band_panels` draws such bands in
panels side by side (one per protocol variant). For what is a class or a yes/no per seed rather than a number:
:func:`plot_share_panels` (the share of seeds where something holds, against a parameter), :func:`plot_period_map`
(a class per seed and parameter value, one row per seed) and :func:`plot_count_histogram` (a count per seed, with
the paper's count marked).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

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
    ax.set_ylabel("claim")
    ax.tick_params(length=0)
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    name = per_seed[0]["experiment"] if per_seed else ""
    ax.set_title(f"{name}: the paper's claims, seed by seed", fontsize=7)
    return save(fig, path)


def _verdict_word(verdict: str) -> str:
    return {"holds": "✓", "fails": "✗", "split": "split", "not_testable": "∅"}[verdict]


@styled
def plot_band(path: Path, x: np.ndarray, curves: Mapping[str, np.ndarray], *, xlabel: str, ylabel: str,
              title: str, reference: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
              hline: float | None = None) -> Path:
    """Curves over seeds: for each name, ``curves[name]`` is (seeds, len(x)); drawn as the mean over seeds (NaN
    ignored) with a band from the seeds' minimum to their maximum and the number of seeds in the legend.
    ``reference``: name → (x, y) drawn as a black dashed line (the paper's values where it gives them);
    ``hline``: a threshold drawn dotted."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size(aspect=0.55))
    _bands(ax, x, curves)
    for name, (rx, ry) in (reference or {}).items():
        ax.plot(rx, ry, "--", color=TARGET, lw=1, label=name)
    if hline is not None:
        ax.axhline(hline, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="best")
    return save(fig, path)


_COLOURS = [BLUE, VERMILLION, GREEN, ORANGE, PURPLE]


def _bands(ax, x: np.ndarray, curves: Mapping[str, np.ndarray]) -> None:
    """Each curve (seeds, len(x)) as its mean over seeds (NaN ignored) and the band of the seeds' min–max."""
    for (name, ys), colour in zip(curves.items(), _COLOURS * 4, strict=False):
        ys = np.asarray(ys, dtype=float).reshape(-1, len(x))
        ok = ~np.all(np.isnan(ys), axis=0)
        mean = np.full(ys.shape[1], np.nan)
        lo, hi = mean.copy(), mean.copy()
        mean[ok], lo[ok], hi[ok] = np.nanmean(ys[:, ok], 0), np.nanmin(ys[:, ok], 0), np.nanmax(ys[:, ok], 0)
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
