"""Analyses of trained drawing systems shared by mnist-pca, mnist-labelmap and mnist-specific100: the PCA
separation of brain and body outputs (Fig. 2(c)) and label maps with their sizes (Fig. 2(d)/(e)).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.experiments.registry import Context

#: the published labelmap config's ``deltaScale: 5``, read as: shifts span ±size/deltaScale (±0.8 m for size 4)
DELTA_SCALE = 5.0
#: label-map cells per axis at paper scale (ours: neither the paper nor the configs give the resolution)
PAPER_GRID = 41


def pca_analysis(ctx: Context, evaluation: dict[str, np.ndarray], labels: np.ndarray, title: str,
                 system_label: str, figure: str = "pca.png") -> dict[str, Any]:
    """Separation scores of the brain output (initial positions of the placed masses) and the body output (the
    CMP trajectory), rows, the claim "the body separates the labels more than the brain", and the figure."""
    from bptsb_ros.analysis.mnist_plots import plot_pca
    from bptsb_ros.analysis.separation import separation_scores

    brain = evaluation["displacement"].reshape(len(labels), -1)
    brain = brain[:, np.abs(brain).sum(0) > 0]  # drop the CMP's all-zero columns
    body = evaluation["drawings"].reshape(len(labels), -1)
    scores = {"brain": separation_scores(brain, labels, ctx.seed), "body": separation_scores(body, labels, ctx.seed)}
    for part in ("brain", "body"):
        sc = scores[part]
        what = "brain output (initial positions)" if part == "brain" else "body output (CMP trajectory)"
        ctx.row(f"{system_label}: {what}", "silhouette of the labels, 2-D PCA", "1", sc["silhouette_2d"])
        ctx.row(f"{system_label}: {what}", "silhouette of the labels, all features", "1", sc["silhouette_full"])
        ctx.row(f"{system_label}: {what}", "linear-probe accuracy (held-out half)", "%", 100 * sc["probe_accuracy"])
    b2, y2 = scores["brain"]["silhouette_2d"], scores["body"]["silhouette_2d"]
    pb, py = 100 * scores["brain"]["probe_accuracy"], 100 * scores["body"]["probe_accuracy"]
    ctx.claim(f"{system_label}: the body's output separates the labels more than the brain's (silhouette in "
              "the 2-D PCA plane, body > brain)", bool(y2 > b2),
              f"silhouette 2-D: body {y2:.3f} vs brain {b2:.3f}; all features: body "
              f"{scores['body']['silhouette_full']:.3f} vs brain {scores['brain']['silhouette_full']:.3f}; probe: "
              f"body {py:.1f} % vs brain {pb:.1f} %")
    ctx.figure(plot_pca(ctx.out_dir / figure, scores["brain"]["points_2d"], scores["body"]["points_2d"], labels,
                        scores, title))
    return {part: {k: float(v) for k, v in sc.items() if k != "points_2d"} for part, sc in scores.items()}


def best_per_digit(errors: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(10,) index of the lowest-error sample of each digit (the paper's "best trajectory" positions)."""
    out = []
    for d in range(10):
        idx = np.flatnonzero(labels == d)
        if not idx.size:
            raise ValueError(f"no test image of digit {d}: label maps need one of every digit")
        out.append(idx[np.argmin(errors[idx])])
    return np.asarray(out)


def labelmap_analysis(ctx: Context, system, evaluation: dict[str, np.ndarray], labels: np.ndarray, grid: int,
                      system_label: str, prefix: str = "") -> dict[str, Any]:
    """Label maps of every placed mass around each digit's best sample; sizes per mass; the claims "masses
    joined to the CMP have smaller label-map sizes" and (supplement) "the largest-size mass is not joined to
    the CMP, the smallest-size one is"; figures like Fig. 2(d)/(e)."""
    from bptsb_ros.analysis.mnist_plots import plot_label_map_sizes, plot_label_maps
    from bptsb_ros.tasks.mnist_drawing import joined_to_cmp, label_maps

    best = best_per_digit(evaluation["errors"], labels)
    base = torch.as_tensor(evaluation["displacement"][best], dtype=system.body.k.dtype)
    half = system.spec.size / DELTA_SCALE
    ctx.log(f"label maps: {system.n_driven} masses × 10 labels × {grid}² cells = "
            f"{system.n_driven * 10 * grid * grid} bodies, one batched simulation")
    maps = label_maps(system, base, half_width=half, grid=grid)
    size = maps["size"]  # (10, P)
    per_mass = size.mean(0)
    joined = joined_to_cmp(system)[maps["masses"]]
    for p, mass in enumerate(maps["masses"]):
        index = int(system.body.movable_index[mass])
        ctx.row(f"{system_label}: mass {index}{' (joined to the CMP)' if joined[p] else ''}",
                "label-map size (mean over the 10 labels)", "1", float(per_mass[p]))
    mean_j = float(per_mass[joined].mean()) if joined.any() else float("nan")
    mean_o = float(per_mass[~joined].mean()) if (~joined).any() else float("nan")
    testable = bool(joined.any() and (~joined).any())
    ctx.claim(f"{system_label}: masses joined to the CMP have smaller label-map sizes (mean over joined < mean "
              "over the others)", testable and mean_j < mean_o,
              f"joined: {mean_j:.3f} ({int(joined.sum())} masses), others: {mean_o:.3f} ({int((~joined).sum())} masses)"
              + ("" if testable else "; not testable: this body has no placed mass of one kind"))
    hi, lo = int(np.argmax(per_mass)), int(np.argmin(per_mass))
    idx = [int(system.body.movable_index[m]) for m in maps["masses"]]
    ctx.claim(f"{system_label}: the mass with the largest label-map size is not joined to the CMP and the one "
              "with the smallest is", bool(not joined[hi] and joined[lo]),
              f"largest: mass {idx[hi]} ({per_mass[hi]:.3f}, {'joined' if joined[hi] else 'not joined'}); smallest: "
              f"mass {idx[lo]} ({per_mass[lo]:.3f}, {'joined' if joined[lo] else 'not joined'})")
    topo = system.body.topology
    ctx.figure(plot_label_maps(ctx.out_dir / f"{prefix}label_maps.png", maps["labels"], maps["deltas"],
                               {f"mass {idx[hi]} (largest)": hi, f"mass {idx[lo]} (smallest)": lo}, size,
                               f"{system_label}: label maps of the masses with the largest and smallest label-map "
                               f"size (grid {grid}×{grid}, Δ within ±{half:.2f} m)"))
    ctx.figure(plot_label_map_sizes(ctx.out_dir / f"{prefix}label_map_sizes.png", topo.positions, topo.springs,
                                    topo.fixed, topo.cmp_index, np.asarray(idx), per_mass, joined,
                                    f"{system_label}: label-map size per mass"))
    return {"grid": grid, "half_width_m": half, "masses": idx, "joined_to_cmp": joined.tolist(),
            "size_per_mass": per_mass.tolist(), "size_per_label_and_mass": size.tolist(),
            "best_sample_per_digit": best.tolist()}
