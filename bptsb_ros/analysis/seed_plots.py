"""Figures over seeds: what ``bptsb reproduce --seeds`` draws beside the first seed's own figures.

:func:`plot_seed_summary` is every multi-seed run's verdict strip: one line per claim, one cell per seed
(holds, fails, not testable), with k/n and the verdict over seeds at the end of the line. :func:`plot_band`
draws a curve over seeds as its mean with the band between the seeds' minimum and maximum, for the experiments
whose claims read a curve (return rate against σ, error against Δt).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.analysis.style import BLUE, GREEN, TARGET, VERMILLION, save, size, styled

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
    colours = [BLUE, VERMILLION, GREEN, "#E69F00", "#CC79A7"]
    for (name, ys), colour in zip(curves.items(), colours * 4, strict=False):
        ys = np.asarray(ys, dtype=float)
        ok = ~np.all(np.isnan(ys), axis=0)
        mean = np.full(ys.shape[1], np.nan)
        lo, hi = mean.copy(), mean.copy()
        mean[ok], lo[ok], hi[ok] = np.nanmean(ys[:, ok], 0), np.nanmin(ys[:, ok], 0), np.nanmax(ys[:, ok], 0)
        ax.plot(x, mean, "o-", ms=3, color=colour, label=f"{name} (mean of {ys.shape[0]} seeds)")
        ax.fill_between(x, lo, hi, color=colour, alpha=0.2, lw=0, label=f"{name}: seeds' min–max")
    for name, (rx, ry) in (reference or {}).items():
        ax.plot(rx, ry, "--", color=TARGET, lw=1, label=name)
    if hline is not None:
        ax.axhline(hline, color="0.5", ls=":", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(loc="best")
    return save(fig, path)
