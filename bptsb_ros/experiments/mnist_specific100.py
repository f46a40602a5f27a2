"""MNIST drawing with 100 specific inputs (paper: supplement "MNIST classification with specific inputs").

100 training images, 10 of every digit chosen at random (seeded) from the training part of the split, are
used for training *and* testing. Systems: {LIL, MLP} × {double-circle N_mov 17 and 65 (33 and 129 masses),
multiple-circle N_mov 17 and 65 (37 and 101 masses)}; the PCA and the label maps are of the MLP + multiple-circle
N_mov 17 system (the supplement's Fig. S(b)/(c)). Trainings are independent jobs in a process pool.

Claims: the supplement's sentences on its Fig. S (errors, label-map sizes, PCA), each comparison between systems
that learned (:func:`claims`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bptsb_ros.experiments.claim_rules import fmt
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
)
from bptsb_ros.experiments.mnist_common import (
    body_nodes,
    load_data,
    run_jobs,
    specific_images,
    train_drawing_job,
)
from bptsb_ros.experiments.mnist_drawing import nearest_target_accuracy, system_label
from bptsb_ros.experiments.mnist_labelmap import LabelMapNumbers, extremes_claim, joined_smaller_claim
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim

#: (shape, the paper's N_mov: movable masses)
BODIES = (("double_circle", 17), ("double_circle", 65), ("multiple_circle", 17), ("multiple_circle", 65))
BRAINS = ("lil", "mlp")
#: the body of the PCA and label maps (supplement Fig. S(b)/(c)): MLP + multiple circle N_mov 17
ANALYSED = ("mlp", "multiple_circle", 17)
BATCH = 50
#: "high accuracy in drawing the label numbers": at least this share of the drawings nearest to their own target
HIGH_ACCURACY = 0.9


@dataclass(frozen=True)
class Specific100Numbers:
    """What the claims of mnist-specific100 rest on.

    mse, skill: per system keyed (brain, shape, N_mov): the mean drawing MSE [m²] on the images (training = test)
    and its drawings nearest to their own target (:class:`Skill`); brain, body: the separation of the analysed
    system's (MLP + multiple circle N_mov 17) outputs in the 2-D PCA plane; maps: its label maps."""

    mse: dict[tuple[str, str, int], float]
    skill: dict[tuple[str, str, int], Skill]
    brain: Separation
    body: Separation
    maps: LabelMapNumbers


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
      largest-size mass is not joined, the smallest-size one is.
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
    return out


def _short(shape: str) -> str:
    return "DC" if shape == "double_circle" else "MC"


def systems() -> list[tuple[str, str, int, object]]:
    """(brain, shape, N_mov, SystemSpec) of the eight systems."""
    from bptsb_ros.tasks.mnist_drawing import SystemSpec

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
    from bptsb_ros.tasks.digits import load_targets
    from bptsb_ros.tasks.mnist_drawing import load_system

    per_digit, epochs, grid = ctx.settings["per_digit"], ctx.settings["epochs"], ctx.settings["grid"]
    data = load_data(ctx, None, 0)
    x, y = specific_images(data.train_x, data.train_y, per_digit, ctx.seed)
    ctx.result.provenance["data"] = (f"{10 * per_digit} images ({per_digit} per digit, seed {ctx.seed}) from the "
                                     f"training part of: {data.description}; used for training and testing")
    chosen = systems()
    specs = [spec for *_, spec in chosen]
    meta = {"experiment": "mnist-specific100", "scale": ctx.scale, "seed": ctx.seed}
    jobs = [dict(spec_json=sp.to_json(), seed=ctx.seed, train_x=x, train_y=y, test_x=x, test_y=y, epochs=epochs,
                 batch=BATCH, checkpoint=str(ctx.out_dir / "systems" / f"{sp.name}.pt"), meta=meta) for sp in specs]
    ctx.log(f"mnist-specific100: {len(specs)} systems, {epochs} epochs on {len(y)} images")
    results = dict(zip([sp.name for sp in specs], run_jobs(ctx, train_drawing_job, jobs)))
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
    ctx.judge(claims, Specific100Numbers(mean, skill, Separation.from_scores(pca["brain"]),
                                                       Separation.from_scores(pca["body"]),
                                                       LabelMapNumbers.from_details(maps)))

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
                          "systems": {sp.name: {"updates": results[sp.name]["updates"],
                                                "train_s": round(results[sp.name]["train_s"], 1),
                                                "guard": results[sp.name]["guard"]} for sp in specs}}
