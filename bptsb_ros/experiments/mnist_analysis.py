"""Analyses of trained drawing systems shared by mnist-pca, mnist-labelmap and mnist-specific100: the PCA
separation of brain and body outputs (Fig. 2(c)) and label maps with their sizes (Fig. 2(d)/(e)). The claims on
them are the experiments' own (``claims`` in each module).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from bptsb_ros.experiments.registry import Context

#: the published labelmap config's ``deltaScale: 5``, read as: shifts span ±size/deltaScale (±0.8 m for size 4)
DELTA_SCALE = 5.0


def pca_analysis(ctx: Context, evaluation: dict[str, np.ndarray], labels: np.ndarray, title: str,
                 system_label: str, figure: str = "pca.png") -> dict[str, dict[str, Any]]:
    """Separation scores (:func:`~bptsb_ros.analysis.separation.separation_scores`) of the brain output (the initial
    positions of the placed masses) and of the body output (the CMP trajectory), their rows and the figure.
    Returns {"brain": scores, "body": scores} without the projected points (arrays as lists, for JSON)."""
    from bptsb_ros.analysis.mnist_plots import plot_pca
    from bptsb_ros.analysis.separation import separation_scores

    brain = evaluation["displacement"].reshape(len(labels), -1)
    brain = brain[:, np.abs(brain).sum(0) > 0]  # drop the CMP's all-zero columns
    body = evaluation["drawings"].reshape(len(labels), -1)
    ctx.phase(f"{system_label}: PCA, silhouettes and linear probes of the brain and body outputs")
    scores = {"brain": separation_scores(brain, labels, ctx.seed), "body": separation_scores(body, labels, ctx.seed)}
    for part in ("brain", "body"):
        sc = scores[part]
        what = "brain output (initial positions)" if part == "brain" else "body output (CMP trajectory)"
        ctx.row(f"{system_label}: {what}", "silhouette of the labels, 2-D PCA", "1", sc["silhouette_2d"])
        ctx.row(f"{system_label}: {what}", "linear-probe accuracy in the 2-D PCA plane (held-out half)", "%",
                100 * sc["probe_2d"])
        ctx.row(f"{system_label}: {what}", "silhouette of the labels, all features", "1", sc["silhouette_full"])
        ctx.row(f"{system_label}: {what}", "linear-probe accuracy (held-out half)", "%", 100 * sc["probe_accuracy"])
    ctx.figure(plot_pca(ctx.out_dir / figure, scores["brain"]["points_2d"], scores["body"]["points_2d"], labels,
                        scores, title))
    return {part: {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in sc.items() if k != "points_2d"}
            for part, sc in scores.items()}


def label_map_half_width(size: float) -> float:
    """Half-width [m] of the label-map grid: Δx, Δy run over ±size/:data:`DELTA_SCALE` (±0.8 m for size 4)."""
    return size / DELTA_SCALE


def best_per_digit(errors: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(10,) index of the lowest-error sample of each digit (the paper's "best trajectory" positions)."""
    out = []
    for d in range(10):
        idx = np.flatnonzero(labels == d)
        if not idx.size:
            raise ValueError(f"no test image of digit {d}: label maps need one of every digit")
        out.append(idx[np.argmin(errors[idx])])
    return np.asarray(out)


def map_intricacy(maps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How intricate label maps are (the supplement: "more complex and intricate map structures"), for ``maps``
    (..., G, G) of labels: ``boundary`` (...), the share of the 2G(G − 1) pairs of edge-adjacent cells whose labels
    differ (0: one label everywhere; 1: a checkerboard), and ``regions`` (...), the number of connected single-label
    regions (4-connected: cells touching only at a corner are apart). A map split by one straight line has
    boundary G / (2G(G − 1)) = 1 / (2(G − 1)) and 2 regions."""
    from scipy import ndimage

    maps = np.asarray(maps)
    lead, (rows, cols) = maps.shape[:-2], maps.shape[-2:]
    flat = maps.reshape(-1, rows, cols)
    pairs = rows * (cols - 1) + cols * (rows - 1)
    differ = (flat[:, 1:, :] != flat[:, :-1, :]).sum((1, 2)) + (flat[:, :, 1:] != flat[:, :, :-1]).sum((1, 2))
    boundary = differ / pairs if pairs else np.zeros(len(flat))
    cross = np.zeros((3, 3, 3), bool)  # 4-connectivity inside each map, none across maps
    cross[1] = [[0, 1, 0], [1, 1, 1], [0, 1, 0]]
    regions = np.zeros(len(flat), np.int64)
    for value in np.unique(flat):  # one labelling of the whole stack per label value
        parts, count = ndimage.label(flat == value, structure=cross)
        if count:
            owner = np.zeros(count + 1, np.int64)
            owner[parts[parts > 0]] = np.nonzero(parts)[0]  # the map each region lies in
            regions += np.bincount(owner[1:], minlength=len(flat))
    return boundary.reshape(lead), regions.reshape(lead)


def labelmap_analysis(ctx: Context, system, evaluation: dict[str, np.ndarray], labels: np.ndarray, grid: int,
                      system_label: str, prefix: str = "") -> dict[str, Any]:
    """Label maps of every placed mass around each digit's best sample (its lowest-error one), Δ over
    ±:func:`label_map_half_width` on a ``grid`` × ``grid`` lattice (odd, so Δ = 0 is a cell); sizes per mass, rows
    and figures like Fig. 2(d)/(e). Returns what the label-map claims rest on (``size_per_mass``,
    ``joined_to_cmp``, ``masses``, ``centre_labels``: the label of each digit's Δ = 0 cell; ``boundary_per_mass``,
    ``regions_per_mass``: the maps' :func:`map_intricacy`, mean over the 10 labels) and the maps' sizes."""
    from bptsb_ros.analysis.mnist_plots import plot_label_map_sizes, plot_label_maps
    from bptsb_ros.tasks.drawing import joined_to_cmp, label_maps

    if grid < 1 or grid % 2 == 0:
        raise ValueError(f"label-map grid must be odd (a cell at Δ = 0), got {grid}")
    best = best_per_digit(evaluation["errors"], labels)
    base = torch.as_tensor(evaluation["displacement"][best], dtype=system.body.k.dtype)
    half = label_map_half_width(system.spec.size)
    ctx.log(f"label maps: {system.n_driven} masses × 10 labels × {grid}² cells = "
            f"{system.n_driven * 10 * grid * grid} bodies, one batched simulation")
    maps = label_maps(system, base, half_width=half, grid=grid)
    size = maps["size"]  # (10, P)
    per_mass = size.mean(0)
    boundary, regions = map_intricacy(maps["labels"])  # (10, P) each
    joined = joined_to_cmp(system)[maps["masses"]]
    centre = maps["labels"][:, 0, grid // 2, grid // 2]  # Δ = 0: the same unshifted body for every mass
    idx = [int(system.body.movable_index[m]) for m in maps["masses"]]
    for p, index in enumerate(idx):
        ctx.row(f"{system_label}: mass {index}{' (joined to the CMP)' if joined[p] else ''}",
                "label-map size (mean over the 10 labels)", "1", float(per_mass[p]))
    hi, lo = int(np.argmax(per_mass)), int(np.argmin(per_mass))
    topo = system.body.topology
    ctx.phase("plotting the label maps")
    ctx.figure(plot_label_maps(ctx.out_dir / f"{prefix}label_maps.png", maps["labels"], maps["deltas"],
                               {f"mass {idx[hi]} (largest)": hi, f"mass {idx[lo]} (smallest)": lo}, size,
                               f"{system_label}: label maps of the masses with the largest and smallest label-map "
                               f"size (grid {grid}×{grid}, Δ within ±{half:.2f} m)"))
    ctx.figure(plot_label_map_sizes(ctx.out_dir / f"{prefix}label_map_sizes.png", topo.positions, topo.springs,
                                    topo.fixed, topo.cmp_index, np.asarray(idx), per_mass, joined,
                                    f"{system_label}: label-map size per mass"))
    return {"grid": grid, "half_width_m": half, "masses": idx, "joined_to_cmp": joined.tolist(),
            "size_per_mass": per_mass.tolist(), "size_per_label_and_mass": size.tolist(),
            "best_sample_per_digit": best.tolist(), "centre_labels": [int(c) for c in centre],
            "boundary_per_mass": boundary.mean(0).tolist(), "regions_per_mass": regions.mean(0).tolist()}
