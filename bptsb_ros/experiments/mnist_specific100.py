"""MNIST drawing with 100 specific inputs (paper: supplement "MNIST classification with specific inputs").

100 training images, 10 of every digit chosen at random (seeded) from the training part of the split, are
used for training *and* testing. Systems: {LIL, MLP} × {double-circle N_mov 17 and 65 (33 and 129 masses),
multiple-circle N_mov 17 and 65 (37 and 101 masses)}; the PCA and the label maps are of the MLP + multiple-circle
N_mov 17 system (the supplement's Fig. S(b)/(c)). Trainings are independent jobs in a process pool.

The supplement compares this system with the same system trained on all the data (its Fig. 2(c) and the bottom
rows of its label-map figure). That system is the MLP + multiple-circle N_mov 17 system of ``mnist-drawing`` at the
same scale and seed: reused from an ``mnist-drawing`` run beside this one (``<out>/../mnist-drawing``, or the same
seed's folder of a multi-seed run) when it was trained with ``mnist-drawing``'s settings of this scale, else trained
here with them (one more job beside the eight, into ``systems/all-data/``). Its PCA (on its test images) and label
maps (same grid) are measured here, so every comparison lies within one run and one seed.

Claims: the supplement's sentences on its Fig. S (errors, label-map sizes, PCA) and on the comparison with the
system trained on all data, each comparison between systems that learned (:func:`claims`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import EPS, at_most, fmt, fmt_pair
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.mnist_analysis import labelmap_analysis, pca_analysis
from bptsb_ros.experiments.mnist_claims import (
    Check,
    Separation,
    Skill,
    all_of,
    classifies,
    more_separated,
    not_learned,
    over_seeds,
)
from bptsb_ros.experiments.mnist_common import (
    body_nodes,
    first_reusable,
    load_data,
    run_jobs,
    sibling_systems,
    specific_images,
    train_drawing_job,
)
from bptsb_ros.experiments.mnist_drawing import nearest_target_accuracy, system_label, system_meta
from bptsb_ros.experiments.mnist_labelmap import LabelMapNumbers, extremes_claim, joined_smaller_claim
from bptsb_ros.experiments.mnist_labelmap import premise as maps_premise
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.seeds import seed_figure

#: (shape, the paper's N_mov: movable masses)
BODIES = (("double_circle", 17), ("double_circle", 65), ("multiple_circle", 17), ("multiple_circle", 65))
BRAINS = ("lil", "mlp")
#: the body of the PCA and label maps (supplement Fig. S(b)/(c)): MLP + multiple circle N_mov 17
ANALYSED = ("mlp", "multiple_circle", 17)
BATCH = 50
#: "high accuracy in drawing the label numbers": at least this share of the drawings nearest to their own target
HIGH_ACCURACY = 0.9
#: "the brain did not deliver a unique output to the body in accordance with the input label": a label's brain
#: outputs are one point when their RMS radius is at most this share of the distance from their mean to the nearest
#: other label's mean (drawn in the PCA plane: a dot a tenth the size of the gap to the next label)
ONE_POINT = 0.1
#: the evidence of a claim whose numbers a run did not measure (stored before they were)
NOT_MEASURED = "not measured by this run (its stored numbers predate this claim)"


@dataclass(frozen=True)
class LabelSpread:
    """How the analysed system's brain output (the initial positions [m] of its placed masses) spreads within each
    label (:func:`~bptsb_ros.analysis.separation.label_spread`): radius (10,) the RMS distance [m] of a label's
    outputs from their mean; gap (10,) the distance [m] from that mean to the nearest other label's mean (NaN: fewer
    than two images of the label)."""

    radius: np.ndarray
    gap: np.ndarray


@dataclass(frozen=True)
class Specific100Numbers:
    """What the claims of mnist-specific100 rest on.

    mse, skill: per system keyed (brain, shape, N_mov): the mean drawing MSE [m²] on the images (training = test)
    and its drawings nearest to their own target (:class:`Skill`); brain, body: the separation of the analysed
    system's (MLP + multiple circle N_mov 17) outputs in the 2-D PCA plane; maps: its label maps; brain_spread: its
    brain output's spread within each label (:class:`LabelSpread`).

    The same system trained on all the data (``mnist-drawing``'s, at the same scale and seed): full_skill its test
    drawings nearest to their own target, full_brain / full_body the separation of its outputs on its test images in
    the 2-D PCA plane, full_maps its label maps (the same grid). None: not measured (a run made before they were);
    the claims that read them are then not testable."""

    mse: dict[tuple[str, str, int], float]
    skill: dict[tuple[str, str, int], Skill]
    brain: Separation
    body: Separation
    maps: LabelMapNumbers
    full_skill: Skill | None = None
    full_brain: Separation | None = None
    full_body: Separation | None = None
    full_maps: LabelMapNumbers | None = None
    brain_spread: LabelSpread | None = None


def _name(key: tuple[str, str, int]) -> str:
    b, shape, m = key
    return f"{b.upper()} {_short(shape)} N_mov {m}"


@judge("mnist-specific100")
def claims(n: Specific100Numbers) -> list[Claim]:
    """The supplement ("MNIST classification with specific inputs", Fig. S): "With the specific 100 images used for
    training and testing, all systems achieved high accuracy in drawing the label numbers (Fig. S(a)). The MLP
    yielded less error than the LIL, and bodies with more mass points performed better. The label map sizes of
    the multiple-circle structure (N_mov=17; Fig. S(b)) indicate that the values of the mass points directly
    connected to the central mass point (CMP) are comparatively small ... As for the result for the brain, there is
    moderate separation by labels. ... On the other hand, the result for the body demonstrates explicit separation
    for each label." and ("Label maps", of this system too): "The mass point with the maximum label map size does
    not connect to the CMP directly; on the contrary, the point with the minimum size has a direct connection."

    * high accuracy: every system's drawings are nearest to their own target for ≥ :data:`HIGH_ACCURACY` of the
      images (inclusive);
    * MLP < LIL for each of the four bodies; N_mov 65 < 17 for each brain and shape (mean MSE, strictly). Premise
      of each comparison: both systems learned (:func:`~bptsb_ros.experiments.mnist_claims.learned`);
    * PCA, in the 2-D plane the figure shows (as mnist-pca): the brain's output shows separation by labels (its
      2-D probe beats chance: "moderate" is some, less than the body's); the body's output separates every label
      (each digit's mean silhouette > 0: its points nearer their own digit than the next); and more than the
      brain's (silhouette body > brain). Premise: the analysed system learned;
    * label maps (premises as mnist-labelmap): mean size of the masses joined to the CMP < the others'; the
      largest-size mass is not joined, the smallest-size one is;
    * "the brain did not deliver a unique output to the body in accordance with the input label" (the hypothesis
      it rejects: "the initial positions of the mass points should match for each label"): a label's outputs are
      one point when their RMS radius is at most :data:`ONE_POINT` of the distance from their mean to the nearest
      other label's mean (a gap of 0: not one label's point, not unique); the claim holds when the median of that
      ratio over the ten labels is > :data:`ONE_POINT` (strictly), i.e. for the typical label, not one stray
      label, the brain's outputs are spread. Premise: the analysed system learned; every label has two images;
    * and on the comparison with the system trained on all the data (main text: "When the input was limited to a
      specific set of images, the improvement in separation performance via the body was more pronounced";
      supplement "Label maps": "The system trained with specific inputs has more complex and intricate map
      structures"), both from the same run and seed: the improvement via the body is the silhouette gain in the
      2-D PCA plane, body − brain, each system on the images the paper's figure of it shows (the 100 images here,
      the test images for the system trained on all data); more pronounced: gain (specific) > gain (all data),
      strictly, premise both systems learned. The label maps are more complex and intricate when, over all
      their maps (10 labels × every placed mass, the same grid and shift range), both the mean share of
      edge-adjacent cells with different labels (boundary length per cell pair: intricate) and the mean number
      of single-label regions (complex) are larger, strictly beyond EPS; premise: each system's maps start from
      drawings of their own digits (as mnist-labelmap).
    """
    high = [Check(n.skill[k].text(_name(k)), bool(n.skill[k].accuracy >= HIGH_ACCURACY)) for k in n.skill]
    out = [all_of(f"all systems draw the label numbers with high accuracy (≥ {fmt(100 * HIGH_ACCURACY)} % of the "
                  "drawings nearest to their own target)", high)]

    def pair(a: tuple[str, str, int], b: tuple[str, str, int], what: str) -> Check:
        return Check(f"{what}: {fmt(n.mse[a])} vs {fmt(n.mse[b])} m²", bool(n.mse[a] < n.mse[b]),
                     not_learned({_name(k): n.skill[k] for k in (a, b)}))

    shapes = ("double_circle", "multiple_circle")
    out.append(all_of("the MLP yields less error than the LIL (every body; systems that learned)",
                      [pair(("mlp", s, m), ("lil", s, m), f"{_short(s)} N_mov {m}: MLP vs LIL") for s, m in BODIES]))
    out.append(all_of("bodies with more mass points perform better (N_mov 65 < 17, every brain and shape; systems "
                      "that learned)", [pair((b, s, 65), (b, s, 17), f"{b.upper()} {_short(s)}: N_mov 65 vs 17")
                                        for b in BRAINS for s in shapes]))
    b, shape, m = ANALYSED
    label = f"{system_label(b, m, shape)}, specific 100"
    premise = not_learned({_name(ANALYSED): n.skill[ANALYSED]}, "the system did not learn to draw")
    c = classifies("brain output", n.brain)
    out.append(all_of(f"{label}: the brain's output shows separation by labels (2-D PCA plane, linear probe above "
                      "chance)", [Check(c.text, c.holds, premise)]))
    each = []
    for d in range(10):
        v = n.body.per_label[d]
        each.append(Check(f"digit {d}: {fmt(v)}", bool(v > 0), premise or (
            None if math.isfinite(v) else f"no image of digit {d}")))
    out.append(all_of(f"{label}: the body's output separates every label (mean silhouette of each digit in the 2-D "
                      "PCA plane > 0)", each))
    sep = more_separated(n.brain, n.body)
    out.append(all_of(f"{label}: the body's output separates the labels more than the brain's (silhouette in the "
                      "2-D PCA plane, body > brain)", [Check(sep.text, sep.holds, premise or sep.premise)]))
    out.append(joined_smaller_claim(n.maps, label))
    out.append(extremes_claim(n.maps, label))
    out.append(unique_output_claim(n.brain_spread, label, premise))
    out.append(pronounced_claim(n, label))
    out.append(intricate_claim(n.maps, n.full_maps, label))
    return out


def unique_output_claim(spread: LabelSpread | None, label: str, premise: str | None) -> Claim:
    """The brain did not deliver a unique output per label: median over the ten labels of radius / gap >
    :data:`ONE_POINT` (see :func:`claims`)."""
    text = (f"{label}: the brain does not deliver a unique output per label (its outputs for the images of one "
            f"label are spread, not one point: median over the labels of the RMS radius / the distance to the "
            f"nearest other label's mean > {fmt(ONE_POINT)})")
    if spread is None:
        return Claim.not_testable(text, NOT_MEASURED)
    if premise is not None:
        return Claim.not_testable(text, premise)
    radius, gap = np.asarray(spread.radius, float), np.asarray(spread.gap, float)
    missing = [d for d in range(10) if not (math.isfinite(radius[d]) and math.isfinite(gap[d]))]
    if missing:
        return Claim.not_testable(text, f"fewer than two images of digit {', '.join(map(str, missing))}")
    ratio = np.divide(radius, gap, out=np.full(10, np.inf), where=gap > 0)
    median = float(np.median(ratio))
    one = int(np.count_nonzero(ratio <= ONE_POINT + EPS))
    per = "; ".join(f"{d}: {fmt(radius[d])} / {fmt(gap[d])} m = {fmt(ratio[d])}" for d in range(10))
    return Claim(text, not at_most(median, ONE_POINT),
                 f"median ratio {fmt(median)}; {one} of 10 labels one point; radius / gap per digit: {per}")


def pronounced_claim(n: Specific100Numbers, label: str) -> Claim:
    """The body's separation gain (silhouette in the 2-D PCA plane, body − brain) is larger here than in the
    system trained on all data, strictly; premise: both systems learned (see :func:`claims`)."""
    text = (f"{label}: the improvement in separation via the body is more pronounced than in the system trained "
            "with all data (silhouette in the 2-D PCA plane, body − brain: specific 100 > all data)")
    if n.full_skill is None or n.full_brain is None or n.full_body is None:
        return Claim.not_testable(text, NOT_MEASURED)
    why = not_learned({f"{_name(ANALYSED)}, specific 100": n.skill[ANALYSED],
                       f"{_name(ANALYSED)}, all data": n.full_skill})
    here, full = n.body.silhouette - n.brain.silhouette, n.full_body.silhouette - n.full_brain.silhouette
    if why is None and not (math.isfinite(here) and math.isfinite(full)):
        why = "a silhouette is undefined (fewer than two labels)"
    a, b = fmt_pair(here, full)
    words = (f"specific 100: body {fmt(n.body.silhouette)} − brain {fmt(n.brain.silhouette)} = {a}; all data: body "
             f"{fmt(n.full_body.silhouette)} − brain {fmt(n.full_brain.silhouette)} = {b}")
    return all_of(text, [Check(words, bool(here > full), why)])


def intricate_claim(maps: LabelMapNumbers, full: LabelMapNumbers | None, label: str) -> Claim:
    """The specific-input system's label maps have a larger mean boundary share and more regions per map than
    those of the system trained on all data, each strictly beyond EPS (see :func:`claims`)."""
    text = (f"{label}: its label maps are more complex and intricate than those of the system trained with all data "
            "(mean over the maps: share of adjacent cells with different labels, and single-label regions; "
            "specific 100 > all data)")
    if full is None or any(m.boundary is None or m.regions is None for m in (maps, full)):
        return Claim.not_testable(text, NOT_MEASURED)
    why = next((f"{which}: {w}" for which, m in (("specific 100", maps), ("all data", full))
                if (w := maps_premise(m)) is not None), None)
    b_here, b_full = float(np.mean(maps.boundary)), float(np.mean(full.boundary))
    r_here, r_full = float(np.mean(maps.regions)), float(np.mean(full.regions))
    (b1, b2), (r1, r2) = fmt_pair(b_here, b_full), fmt_pair(r_here, r_full)
    return all_of(text, [Check(f"boundary share: specific 100 {b1} vs all data {b2}", not at_most(b_here, b_full), why),
                         Check(f"regions per map: specific 100 {r1} vs all data {r2}", not at_most(r_here, r_full),
                               why)])


def _analysed_label() -> str:
    b, shape, m = ANALYSED
    return system_label(b, m, shape)


def _short(shape: str) -> str:
    return "DC" if shape == "double_circle" else "MC"


def systems() -> list[tuple[str, str, int, object]]:
    """(brain, shape, N_mov, SystemSpec) of the eight systems."""
    from bptsb_ros.tasks.drawing import SystemSpec

    return [(b, shape, n, SystemSpec(brain=b, shape=shape, nodes=body_nodes(shape, n)))
            for shape, n in BODIES for b in BRAINS]


@experiment(
    "mnist-specific100",
    parallel=True,
    paper_ref="supplement 'MNIST classification with specific inputs' (Fig. S: errors, label-map sizes, PCA)",
    summary="100 fixed images (10 per digit) train = test: {LIL, MLP} × four bodies; errors, PCA, label maps",
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.mnist_plots import plot_best_drawings, plot_error_bars
    from bptsb_ros.analysis.separation import label_spread
    from bptsb_ros.experiments.experiment_settings import resolve_settings
    from bptsb_ros.tasks.digits import load_targets
    from bptsb_ros.tasks.drawing import SystemSpec, evaluate_drawing, load_system

    per_digit, epochs, grid = ctx.settings["per_digit"], ctx.settings["epochs"], ctx.settings["grid"]
    data = load_data(ctx, None, 0)
    x, y = specific_images(data.train_x, data.train_y, per_digit, ctx.seed)
    specific_data = (f"{10 * per_digit} images ({per_digit} per digit, seed {ctx.seed}) from the training part of: "
                     f"{data.description}; used for training and testing")
    chosen = systems()
    specs = [spec for *_, spec in chosen]
    meta = {"experiment": "mnist-specific100", "scale": ctx.scale, "seed": ctx.seed}
    jobs = [dict(spec_json=sp.to_json(), seed=ctx.seed, train_x=x, train_y=y, test_x=x, test_y=y, epochs=epochs,
                 batch=BATCH, checkpoint=str(ctx.out_dir / "systems" / f"{sp.name}.pt"), meta=meta) for sp in specs]
    costs = [len(y) * epochs] * len(jobs)

    # the same system trained on all the data: mnist-drawing's, reused from a run beside this one or trained here
    full_settings = resolve_settings("mnist-drawing", ctx.scale)
    full_data = load_data(ctx, full_settings["n_train"], full_settings["n_test"])
    b, shape, m = ANALYSED
    full_spec = SystemSpec(brain=b, shape=shape, nodes=body_nodes(shape, m))
    full_meta = system_meta(ctx, full_data.key, full_settings["epochs"])
    reuse = first_reusable(sibling_systems(ctx, full_spec.name), full_meta)
    reused = reuse is not None
    full_path = reuse if reuse is not None else ctx.out_dir / "systems" / "all-data" / f"{full_spec.name}.pt"
    if not reused:
        jobs.append(dict(spec_json=full_spec.to_json(), seed=ctx.seed, train_x=full_data.train_x,
                         train_y=full_data.train_y, test_x=full_data.test_x, test_y=full_data.test_y,
                         epochs=full_settings["epochs"], batch=BATCH, checkpoint=str(full_path), meta=full_meta))
        costs.append(len(full_data.train_y) * full_settings["epochs"])
    ctx.result.provenance["data"] = (f"{specific_data}. The system trained on all data (for the comparisons): "
                                     f"{full_data.description}")
    ctx.log(f"mnist-specific100: {len(specs)} systems, {epochs} epochs on {len(y)} images"
            + ("" if reused else f"; and {full_spec.name} on all data ({len(full_data.train_y)} images, "
                                 f"{full_settings['epochs']} epochs)"))
    done = run_jobs(ctx, train_drawing_job, jobs, costs=costs)
    results = dict(zip([sp.name for sp in specs], done))
    label = {}
    mean = {}
    skill = {}
    metric = f"drawing MSE on the {len(y)} training = test images (mean)"
    for b, shape, n, sp in chosen:
        label[sp.name] = system_label(b, n, shape)
        mean[(b, shape, n)] = float(results[sp.name]["errors"].mean())
        acc = nearest_target_accuracy(results[sp.name]["drawings"], y)
        skill[(b, shape, n)] = Skill.of(acc, y)
        ctx.row(label[sp.name], metric, "m²", mean[(b, shape, n)])
        ctx.row(label[sp.name], f"drawings nearest to their own target ({len(y)} training = test images)", "%",
                100 * acc)
    analysed = next(sp for b, shape, n, sp in chosen if (b, shape, n) == ANALYSED)
    res = results[analysed.name]
    analysed_label = f"{label[analysed.name]}, specific 100"
    pca = pca_analysis(ctx, res, y, f"{label[analysed.name]} trained on 100 specific images: 2-D PCA", analysed_label)
    system, _ = load_system(res["checkpoint"])
    maps = labelmap_analysis(ctx, system, res, y, grid, analysed_label)
    radius, gap = label_spread(res["displacement"].reshape(len(y), -1), y)
    ratio = np.divide(radius, gap, out=np.full(10, np.inf), where=gap > 0)
    ctx.row(f"{analysed_label}: brain output (initial positions)", "RMS radius of a label's outputs / distance to "
            "the nearest other label's mean (median over the labels)", "1", float(np.median(ratio)))

    full_label = f"{label[analysed.name]}, all data"
    full_system, _ = load_system(full_path)
    if reused:
        ctx.log(f"reusing the system trained on all data: {reuse}")
        full_ev = evaluate_drawing(full_system, full_data.test_x, full_data.test_y)
        source = f"reused {reuse}"
    else:
        full_ev = {k: done[-1][k] for k in ("errors", "drawings", "brain", "displacement")}
        g = done[-1]["guard"]
        source = (f"trained here ({done[-1]['updates']} updates, {done[-1]['train_s']:.0f} s, {g['rejections']} "
                  f"update(s) undone by the guard, final rates {g['rates']})")
    full_acc = nearest_target_accuracy(full_ev["drawings"], full_data.test_y)
    ctx.row(full_label, f"test drawing MSE ({len(full_data.test_y)} test images, mean)", "m²",
            float(full_ev["errors"].mean()))
    ctx.row(full_label, "test drawings nearest to their own target", "%", 100 * full_acc)
    full_pca = pca_analysis(ctx, full_ev, full_data.test_y, f"{full_label}: outputs on {len(full_data.test_y)} test "
                            "images, 2-D PCA", full_label, figure="pca_all_data.png")
    full_maps = labelmap_analysis(ctx, full_system, full_ev, full_data.test_y, grid, full_label, prefix="all_data_")
    for name, mp in ((analysed_label, maps), (full_label, full_maps)):
        ctx.row(name, "label maps: share of adjacent cells with different labels (mean over the maps)", "1",
                float(np.mean(mp["boundary_per_mass"])))
        ctx.row(name, "label maps: single-label regions per map (mean)", "1", float(np.mean(mp["regions_per_mass"])))
    ctx.judge(claims, Specific100Numbers(mean, skill, Separation.from_scores(pca["brain"]),
                                         Separation.from_scores(pca["body"]), LabelMapNumbers.from_details(maps),
                                         full_skill=Skill.of(full_acc, full_data.test_y),
                                         full_brain=Separation.from_scores(full_pca["brain"]),
                                         full_body=Separation.from_scores(full_pca["body"]),
                                         full_maps=LabelMapNumbers.from_details(full_maps),
                                         brain_spread=LabelSpread(radius, gap)))

    ctx.phase("plotting the drawings and errors")
    targets = load_targets()
    ctx.figure(plot_best_drawings(ctx.out_dir / "drawings.png",
                                  {label[sp.name]: {"drawings": results[sp.name]["drawings"],
                                                    "errors": results[sp.name]["errors"], "labels": y}
                                   for sp in specs if sp.brain == "mlp"}, targets, 0.01))
    names = [label[sp.name] for sp in specs]
    errs = [results[sp.name]["errors"] for sp in specs]
    ctx.figure(plot_error_bars(ctx.out_dir / "errors.png", names, [float(e.mean()) for e in errs],
                               [float(e.std() / len(e) ** 0.5) for e in errs],
                               f"Specific {len(y)} images: mean drawing MSE (train = test)"))
    ctx.result.details = {"epochs": epochs, "images": len(y), "pca": pca, "label_maps": maps,
                          "brain_spread": {"radius_m": radius.tolist(), "gap_m": gap.tolist()},
                          "all_data": {"system": source, "epochs": full_settings["epochs"],
                                       "data": full_data.description, "pca": full_pca, "label_maps": full_maps},
                          "systems": {sp.name: {"updates": results[sp.name]["updates"],
                                                "train_s": round(results[sp.name]["train_s"], 1),
                                                "guard": results[sp.name]["guard"]} for sp in specs}}


@seed_figure("mnist-specific100")
def seed_figures(out: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds, what the claims read: each system's drawing error and share of drawings of the right digit;
    the comparison with the system trained on all data (the body's silhouette gain, the label maps' boundary share
    and regions); the brain output's spread within each label against :data:`ONE_POINT`."""
    from bptsb_ros.analysis.seed_plots import Bars, plot_band, plot_bars_over_seeds

    keys = [(b, s, m) for b, s, m, _ in systems()]
    names = [_name(k) for k in keys]
    n_seeds = len(seeds)
    mse = over_seeds(per_seed, claims, lambda num: [num.mse.get(k, math.nan) for k in keys])
    acc = over_seeds(per_seed, claims, lambda num: [100 * num.skill[k].accuracy if k in num.skill else math.nan
                                                    for k in keys])
    figs = [plot_bars_over_seeds(out / "errors_over_seeds.png",
                                 [Bars(names, mse, "drawing MSE (train = test) [m²]", title="mean drawing error"),
                                  Bars(names, acc, "drawings of the right digit [%]",
                                       hline=(100 * HIGH_ACCURACY, "90 %: 'high accuracy'"),
                                       title="drawings nearest to their own target")],
                                 f"Specific 100 images: the eight systems over {n_seeds} seeds")]

    def compare(num: Specific100Numbers) -> list[float]:
        nan2 = [math.nan, math.nan]
        gain = nan2 if num.full_brain is None or num.full_body is None else [
            num.body.silhouette - num.brain.silhouette, num.full_body.silhouette - num.full_brain.silhouette]
        maps = [num.maps, num.full_maps]
        measured = num.full_maps is not None and all(m.boundary is not None and m.regions is not None for m in maps)
        boundary = [float(np.mean(m.boundary)) for m in maps] if measured else nan2
        regions = [float(np.mean(m.regions)) for m in maps] if measured else nan2
        return gain + boundary + regions

    both = over_seeds(per_seed, claims, compare)
    if both.shape[1] == 6 and not np.isnan(both).all():
        pair = ["specific 100", "all data"]
        figs.append(plot_bars_over_seeds(
            out / "comparison_over_seeds.png",
            [Bars(pair, both[:, 0:2], "silhouette gain, body − brain [-]", title="separation via the body",
                  xlabel="trained on"),
             Bars(pair, both[:, 2:4], "adjacent cells with other labels [-]", title="label-map boundaries",
                  xlabel="trained on"),
             Bars(pair, both[:, 4:6], "single-label regions per map [-]", title="label-map regions",
                  xlabel="trained on")],
            f"{_analysed_label()}: specific 100 images vs all data over {n_seeds} seeds"))

    def ratio(num: Specific100Numbers) -> np.ndarray:
        if num.brain_spread is None:
            return np.full(10, np.nan)
        r, g = np.asarray(num.brain_spread.radius, float), np.asarray(num.brain_spread.gap, float)
        return np.divide(r, g, out=np.full(10, np.nan), where=g > 0)

    spread = over_seeds(per_seed, claims, ratio)
    if spread.shape[1] == 10 and not np.isnan(spread).all():
        figs.append(plot_band(out / "brain_spread_over_seeds.png", np.arange(10), {"brain output": spread},
                              xlabel="digit [-]", ylabel="RMS radius / gap to the nearest label [-]", hline=ONE_POINT,
                              hline_label=f"{fmt(ONE_POINT)}: one point per label below it",
                              title=f"Specific 100: spread of the brain's outputs within each label over {n_seeds} "
                                    "seeds"))
    return figs
