"""Label maps and label-map sizes (paper: Fig. 2(d)/(e); Methods; supplement "Label maps").

For the MLP + multiple-circle N_mov 17 system (37 masses: 20 fixed, 12 placed masses not joined to the CMP, 4
joined, and the CMP; the same system as ``mnist-drawing``'s and ``mnist-pca``'s, reused from
``<out>/../mnist-drawing/systems/`` when that run used the same scale, seed and data, else trained here), each
placed (non-central) mass is shifted by (Δx, Δy) on a grid around its trained initial position for the best
test sample of every digit, the body is released, and every cell is labelled with the digit whose target the
CMP's drawing is closest to (MSE). The label-map size is the share of cells that keep the original label;
Fig. 2(e) shows it per mass. All grids are one batched simulation.

Grid: Δ within ±size/deltaScale = ±0.8 m (the published ``deltaScale: 5``, our reading).

Claims: the paper's sentences on label-map sizes (main text, Fig. 2(e); supplement "Label maps"), premised on
label maps drawn around drawings of their own digits (:func:`claims`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import EPS, at_most, fmt, fmt_pair
from bptsb_ros.experiments.measured import judge, stored_calls
from bptsb_ros.experiments.mnist_analysis import labelmap_analysis
from bptsb_ros.experiments.mnist_claims import over_seeds
from bptsb_ros.experiments.mnist_common import body_nodes, load_data, obtain_drawing_system, sibling_systems
from bptsb_ros.experiments.mnist_drawing import BATCH, SHAPE, scale_settings, system_label, system_meta
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.seeds import seed_figure

#: the paper's label-map body (Fig. 2(d)/(e)): multiple circle with N_mov = 17 movable masses
N_MOV = 17
#: "mostly occupied by the original label": more than half of a mass's label maps' cells
MOSTLY = 0.5


@dataclass(frozen=True)
class LabelMapNumbers:
    """What the label-map claims rest on, for the P placed masses of one system.

    size: (P,) label-map size of each mass, the mean over the 10 labels of the share of cells keeping the original
    label; joined: (P,) bool, a spring joins the mass to the CMP; masses: (P,) the masses' indices in the body (for
    the evidence); centre_labels: (10,) the label of digit d's Δ = 0 cell (the unshifted best sample of d);
    boundary, regions: (P,) how intricate each mass's maps are, the mean over the 10 labels of the share of
    edge-adjacent cells with different labels and of the number of single-label regions
    (:func:`~bptsb_ros.experiments.mnist_analysis.map_intricacy`; None: not measured, a run made before they were).
    """

    size: np.ndarray
    joined: np.ndarray
    masses: np.ndarray
    centre_labels: np.ndarray
    boundary: np.ndarray | None = None
    regions: np.ndarray | None = None

    @classmethod
    def from_details(cls, maps: dict[str, Any]) -> LabelMapNumbers:
        """From :func:`~bptsb_ros.experiments.mnist_analysis.labelmap_analysis`' return value."""
        extra = {k: np.asarray(maps[f"{k}_per_mass"], float) for k in ("boundary", "regions")
                 if f"{k}_per_mass" in maps}
        return cls(np.asarray(maps["size_per_mass"], float), np.asarray(maps["joined_to_cmp"], bool),
                   np.asarray(maps["masses"], int), np.asarray(maps["centre_labels"], int), **extra)


def premise(n: LabelMapNumbers) -> str | None:
    """The failed premise of every label-map claim in words (None: testable): the maps start from drawings of their
    own digits (each digit's Δ = 0 cell carries its own label: "the proportion of the original label area" is
    measured around a drawing of that label), and the body has placed masses of both kinds, joined to the CMP and
    not."""
    centre = np.asarray(n.centre_labels)
    wrong = [f"digit {d} → {int(c)}" for d, c in enumerate(centre) if c != d]
    if len(centre) != 10 or wrong:
        return ("the label maps do not start from drawings of their own digits (the best sample's unshifted "
                f"drawing is nearest to another digit's target: {', '.join(wrong) or 'fewer than 10 digits'})")
    joined = np.asarray(n.joined, bool)
    if not (joined.any() and (~joined).any()):
        return "the body has no placed mass of one kind (joined to the CMP / not joined)"
    return None


def _mass(n: LabelMapNumbers, p: int) -> str:
    return f"mass {int(n.masses[p])} ({fmt(float(n.size[p]))}, {'joined' if n.joined[p] else 'not joined'})"


def joined_smaller_claim(n: LabelMapNumbers, label: str) -> Claim:
    """Mean label-map size of the masses joined to the CMP < mean of the others, strictly (means within EPS are
    equal: sizes are shares of cells, and equal sizes average to different floats, 0.8 · 12 / 12 ≠ 0.8)."""
    text = (f"{label}: masses joined to the CMP have smaller label-map sizes (mean over joined < mean over the "
            "others)")
    if (why := premise(n)) is not None:
        return Claim.not_testable(text, why)
    size, joined = np.asarray(n.size, float), np.asarray(n.joined, bool)
    mj, mo = float(size[joined].mean()), float(size[~joined].mean())
    return Claim(text, not at_most(mo, mj), f"joined: {fmt(mj)} ({int(joined.sum())} masses), others: {fmt(mo)} "
                                      f"({int((~joined).sum())} masses)")


def extremes_claim(n: LabelMapNumbers, label: str) -> Claim:
    """Every mass at the largest label-map size is not joined to the CMP, every one at the smallest is (a tie across
    the two kinds refutes it: a joined mass then has the maximum size); sizes within EPS count as equal."""
    text = (f"{label}: the mass with the largest label-map size is not joined to the CMP and the one with the "
            "smallest is")
    if (why := premise(n)) is not None:
        return Claim.not_testable(text, why)
    size, joined = np.asarray(n.size, float), np.asarray(n.joined, bool)
    top = np.flatnonzero(size >= size.max() - EPS)
    bottom = np.flatnonzero(size <= size.min() + EPS)
    holds = bool(not joined[top].any() and joined[bottom].all())
    return Claim(text, holds, f"largest: {', '.join(_mass(n, p) for p in top)}; smallest: "
                              f"{', '.join(_mass(n, p) for p in bottom)}")


def others_mostly_claim(n: LabelMapNumbers, label: str) -> Claim:
    """Every mass not joined to the CMP keeps its original label on more than :data:`MOSTLY` of its maps' cells
    (strictly; within EPS of it is at it)."""
    text = (f"{label}: the label maps of the masses not joined to the CMP are mostly occupied by the original "
            f"label (label-map size > {MOSTLY} for every such mass)")
    if (why := premise(n)) is not None:
        return Claim.not_testable(text, why)
    size, joined = np.asarray(n.size, float), np.asarray(n.joined, bool)
    p = int(np.flatnonzero(~joined)[np.argmin(size[~joined])])
    return Claim(text, not at_most(float(size[p]), MOSTLY), f"smallest among the masses not joined: {_mass(n, p)}")


def joined_intricate_claim(n: LabelMapNumbers, label: str) -> Claim:
    """The maps of the masses joined to the CMP are more intricate than the others': their mean boundary share and
    their mean number of single-label regions are both larger, strictly beyond EPS (the measure of
    :func:`~bptsb_ros.experiments.mnist_analysis.map_intricacy`)."""
    text = (f"{label}: the label maps of the masses joined to the CMP are intricate (mean share of adjacent cells "
            "with different labels and mean single-label regions per map, joined > the others)")
    if n.boundary is None or n.regions is None:
        return Claim.not_testable(text, "not measured by this run (its stored numbers predate this claim)")
    if (why := premise(n)) is not None:
        return Claim.not_testable(text, why)
    joined = np.asarray(n.joined, bool)
    parts = []
    holds = True
    for what, values in (("boundary share", n.boundary), ("regions per map", n.regions)):
        v = np.asarray(values, float)
        mj, mo = float(v[joined].mean()), float(v[~joined].mean())
        holds = holds and not at_most(mj, mo)
        a, b = fmt_pair(mj, mo)
        parts.append(f"{what}: joined {a}, others {b}")
    return Claim(text, holds, "; ".join(parts))


@judge("mnist-labelmap")
def claims(n: LabelMapNumbers, label: str = system_label("mlp", N_MOV)) -> list[Claim]:
    """The paper (main text, "Division of functional roles", Fig. 2(d)/(e)): "The map structures of the mass points
    directly connected to the CMP were intricate, ... Conversely, other maps were mostly occupied by the original
    label number" and "To shed light on this distribution, the label map size of the mass point that connects
    directly to the CMP is smaller."; the supplement ("Label maps"): "The mass point with the maximum label map
    size does not connect to the CMP directly; on the contrary, the point with the minimum size has a direct
    connection."

    * joined smaller: mean size over the masses joined to the CMP < mean over the others, strictly (beyond EPS);
    * largest not joined, smallest joined: every mass at the maximum size is not joined, every one at the minimum
      is (ties within EPS; a tie across the two kinds refutes the sentence);
    * others mostly original: every mass not joined to the CMP has size > 1/2 ("mostly occupied"), strictly;
    * joined intricate ("The map structures of the mass points directly connected to the CMP were intricate"):
      against the other maps, which the sentence sets apart ("Conversely"), the joined masses' maps have the larger
      mean share of edge-adjacent cells with different labels and the larger mean number of single-label regions
      (both, strictly beyond EPS; :func:`joined_intricate_claim`).

    Premise of all four (:func:`premise`): the maps start from drawings of their own digits, each digit's Δ = 0
    cell carries its own label (the paper shifts masses from "the proper positions to realize the best
    trajectory"; the size is "the proportion of the original label area", meaningless around a drawing of another
    digit), and the body has placed masses of both kinds.
    """
    return [joined_smaller_claim(n, label), extremes_claim(n, label), others_mostly_claim(n, label),
            joined_intricate_claim(n, label)]


@experiment(
    "mnist-labelmap",
    paper_ref="Fig. 2(d)/(e); Methods; supplement 'Label maps'",
    summary="MLP + multiple-circle N_mov 17: label maps per placed mass, label-map sizes, joined-to-CMP claim",
)
def run(ctx: Context) -> None:
    from bptsb_ros.tasks.drawing import SystemSpec

    s = scale_settings(ctx)
    grid = ctx.settings["grid"]
    data = load_data(ctx, s["n_train"], s["n_test"])
    spec = SystemSpec(brain="mlp", shape=SHAPE, nodes=body_nodes(SHAPE, N_MOV))
    reuse = sibling_systems(ctx, spec.name)
    system, ev, source = obtain_drawing_system(ctx, spec, data, epochs=s["epochs"], batch=BATCH,
                                               meta=system_meta(ctx, data.key, s["epochs"]), reuse=reuse)
    label = system_label("mlp", N_MOV)
    ctx.row(label, "test drawing MSE (mean)", "m²", float(ev["errors"].mean()))
    maps = labelmap_analysis(ctx, system, ev, data.test_y, grid, label)
    ctx.judge(claims, LabelMapNumbers.from_details(maps), label)
    ctx.result.details = {"system": source, "spec": spec.to_json(), "epochs": s["epochs"], "label_maps": maps,
                          "data": data.description}


@seed_figure("mnist-labelmap")
def seed_figures(out: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds: each placed mass's label-map size (what the claims read), masses joined to the CMP in their
    own colour, the "mostly" bound ½ dotted."""
    from bptsb_ros.analysis.seed_plots import Bars, plot_bars_over_seeds

    first = next((calls[0][1][0] for r in per_seed if (calls := stored_calls(r, claims)) and calls[0][1]), None)
    if first is None:
        return []
    size = over_seeds(per_seed, claims, lambda num: num.size if len(num.size) == len(first.size) else
                      np.full(len(first.size), np.nan))
    groups = ["joined to the CMP" if j else "not joined to the CMP" for j in np.asarray(first.joined, bool)]
    return [plot_bars_over_seeds(out / "label_map_sizes_over_seeds.png",
                                 [Bars([str(int(m)) for m in first.masses], size, "label-map size [-]",
                                       hline=(MOSTLY, "½: 'mostly occupied by the original label'"), groups=groups,
                                       xlabel="placed mass (its index in the body) [-]")],
                                 f"{system_label('mlp', N_MOV)}: label-map size per mass over {len(seeds)} seeds")]
