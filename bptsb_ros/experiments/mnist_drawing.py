"""MNIST drawing (paper: main text "Division of functional roles", Fig. 2(a)/(b); Methods "MNIST
classification and drawing task").

Four systems, {LIL, MLP} × the paper's multiple-circle bodies N_mov = 17 and 65 (movable masses: 37 and 101
masses with the fixed outer ring; the brain places the 2(N_mov − 1) = 32 / 128 coordinates of the movable
masses other than the CMP), are trained by BPTSB to draw the label's digit with the CMP; batch 50, the paper's
learning rates (SGD: k 1e4, d 1e3, l 1, brain 1). Trainings are independent jobs in a process pool, each
batch of images one simulation.

Numbers: the mean test-set drawing MSE per system [m²] (the paper shows its values only in a figure: no
number to compare with), and the share of test drawings whose nearest target is their own label's.

Claims: the paper's two sentences on Fig. 2(b), each comparison made between systems that learned
(:func:`claims`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import fmt
from bptsb_ros.experiments.measured import judge
from bptsb_ros.experiments.mnist_claims import Check, Skill, all_of, not_learned, over_seeds
from bptsb_ros.experiments.mnist_common import body_label, body_nodes, load_data, run_jobs, train_drawing_job
from bptsb_ros.experiments.registry import Context, experiment
from bptsb_ros.experiments.result import Claim
from bptsb_ros.experiments.seeds import seed_figure

BRAINS = ("lil", "mlp")
#: the paper's "N_mov = 17, 65": movable masses (multiple circle: 37 and 101 masses)
N_MOV = (17, 65)
SHAPE = "multiple_circle"
BATCH = 50


def scale_settings(ctx: Context) -> dict[str, int | None]:
    """Training images, test images and epochs for the run's scale (None: every image of the split)."""
    return {key: ctx.settings[key] for key in ("n_train", "n_test", "epochs")}


def systems() -> list[tuple[str, int, object]]:
    """(brain, N_mov, SystemSpec) of the four drawing systems."""
    from bptsb_ros.tasks.drawing import SystemSpec

    return [(b, n, SystemSpec(brain=b, shape=SHAPE, nodes=body_nodes(SHAPE, n))) for n in N_MOV for b in BRAINS]


def system_label(brain: str, n_movable: int, shape: str = SHAPE) -> str:
    """``MLP + multiple-circle (N_mov 17)``."""
    return f"{brain.upper()} + {body_label(shape, n_movable)}"


def nearest_target_accuracy(drawings: np.ndarray, labels: np.ndarray) -> float:
    """Share of drawings (n, T+1, 2) whose closest target (MSE over the target's steps) is their label's."""
    import torch

    from bptsb_ros.tasks.drawing import DigitTargets

    errs = DigitTargets(dtype=torch.float64).all_errors(torch.as_tensor(drawings))
    return float((errs.argmin(1).numpy() == labels).mean())


@dataclass(frozen=True)
class DrawingNumbers:
    """What the claims of mnist-drawing rest on, per system keyed (brain, N_mov), brain "lil" / "mlp", N_mov 17 / 65.

    mse: the mean test drawing MSE [m²]; skill: the share of test drawings nearest to their own label's target
    (:class:`~bptsb_ros.experiments.mnist_claims.Skill`, chance: the most common test label's share)."""

    mse: dict[tuple[str, int], float]
    skill: dict[tuple[str, int], Skill]


@judge("mnist-drawing")
def claims(n: DrawingNumbers) -> list[Claim]:
    """The paper (main text, "Division of functional roles", on Fig. 2(b)): "As for the brain, the error was smaller
    in the MLP than in the LIL, reflecting the contribution of the nonlinearity of the brain to its performance.
    Focusing on the body, increasing the mass points led to better performance, suggesting an increase in the
    expressiveness of the physical system."

    * MLP < LIL: the MLP system's mean test MSE < the LIL system's (strictly), for N_mov 17 and for N_mov 65;
    * more mass points: N_mov 65 < N_mov 17 (strictly), for the LIL and for the MLP.

    Premise of each comparison: both systems learned the task, i.e. their test drawings are nearest to their own
    label's target more often than chance by the :func:`~bptsb_ros.experiments.mnist_claims.learned` margin. The
    paper compares optimised systems and reads the gap as the brain's nonlinearity or the body's expressiveness;
    between systems that did not learn it says neither. A comparison whose premise fails is not testable; the claim
    is then not testable unless the other comparison refutes it.
    """
    def pair(a: tuple[str, int], b: tuple[str, int], what: str) -> Check:
        names = {system_label(*k): n.skill[k] for k in (a, b)}
        return Check(f"{what}: {fmt(n.mse[a])} vs {fmt(n.mse[b])} m²", bool(n.mse[a] < n.mse[b]), not_learned(names))

    mlp = [pair(("mlp", m), ("lil", m), f"N_mov {m}: MLP vs LIL") for m in N_MOV]
    more = [pair((b, 65), (b, 17), f"{b.upper()}: N_mov 65 vs 17") for b in BRAINS]
    return [all_of("the MLP brain draws with a smaller error than the LIL (both bodies; systems that learned)", mlp),
            all_of("more mass points give a smaller error (N_mov 65 < 17, both brains; systems that learned)", more)]


def system_meta(ctx: Context, data_key: str, epochs: int) -> dict:
    return {"experiment": "mnist-drawing", "scale": ctx.scale, "seed": ctx.seed, "data": data_key,
            "epochs": epochs, "batch": BATCH}


@experiment(
    "mnist-drawing",
    parallel=True,
    paper_ref="Fig. 2(a)/(b); Methods 'MNIST classification and drawing task'",
    summary="{LIL, MLP} × multiple-circle N_mov 17/65: image → initial positions → released body draws the digit",
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.mnist_plots import plot_best_drawings, plot_curves, plot_error_bars
    from bptsb_ros.tasks.digits import load_targets

    s = scale_settings(ctx)
    data = load_data(ctx, s["n_train"], s["n_test"])
    chosen = systems()
    specs = [spec for _, _, spec in chosen]
    meta = system_meta(ctx, data.key, s["epochs"])
    jobs = [dict(spec_json=spec.to_json(), seed=ctx.seed, train_x=data.train_x, train_y=data.train_y,
                 test_x=data.test_x, test_y=data.test_y, epochs=s["epochs"], batch=BATCH,
                 checkpoint=str(ctx.out_dir / "systems" / f"{spec.name}.pt"), meta=meta) for spec in specs]
    ctx.log(f"mnist-drawing: training {len(specs)} systems for {s['epochs']} epochs on {len(data.train_y)} images")
    results = run_jobs(ctx, train_drawing_job, jobs)
    label = {spec.name: system_label(b, n) for b, n, spec in chosen}
    mean = {}
    per_digit = {}
    skill = {}
    for spec, res in zip(specs, results):
        err = res["errors"]
        mean[spec.name] = float(err.mean())
        acc = nearest_target_accuracy(res["drawings"], data.test_y)
        skill[spec.name] = Skill.of(acc, data.test_y)
        ctx.row(label[spec.name], "test drawing MSE (mean)", "m²", mean[spec.name], None)
        ctx.row(label[spec.name], "test drawings nearest to their own target", "%", 100 * acc, None)
        per_digit[label[spec.name]] = [float(err[data.test_y == d].mean()) if (data.test_y == d).any() else None
                                       for d in range(10)]
    by = {(b, n): mean[spec.name] for b, n, spec in chosen}
    ctx.judge(claims, DrawingNumbers(by, {(b, n): skill[spec.name] for b, n, spec in chosen}))

    ctx.phase("plotting the drawings, errors and training curves")
    targets = load_targets()
    fig = plot_best_drawings(ctx.out_dir / "drawings.png",
                             {label[sp.name]: {"drawings": r["drawings"], "errors": r["errors"],
                                               "labels": data.test_y} for sp, r in zip(specs, results)},
                             targets, 0.01)
    ctx.figure(fig)
    names = [label[sp.name] for sp in specs]
    sem = [float(r["errors"].std() / np.sqrt(len(r["errors"]))) for r in results]
    ctx.figure(plot_error_bars(ctx.out_dir / "errors.png", names, [mean[sp.name] for sp in specs], sem,
                               f"MNIST drawing: mean test MSE ({len(data.test_y)} test images)"))
    ctx.figure(plot_curves(ctx.out_dir / "training.png", {label[sp.name]: r["losses"] for sp, r in zip(specs, results)},
                           "batch drawing MSE [m²]", "BPTSB training (batch 50, SGD, paper's learning rates)"))
    ctx.result.details = {
        "systems": {label[sp.name]: {"spec": sp.to_json(), "updates": r["updates"], "train_s": round(r["train_s"], 1),
                                     "first_epoch_train_mse": r["epoch_losses"][0] if r["epoch_losses"] else None,
                                     "last_epoch_train_mse": r["epoch_losses"][-1] if r["epoch_losses"] else None,
                                     "checkpoint": str(sp.name) + ".pt", "guard": r["guard"]}
                    for sp, r in zip(specs, results)},
        "per_digit_test_mse": per_digit,
        "epochs": s["epochs"], "batch": BATCH, "data": data.description,
        "bodies": {body_label(SHAPE, n): {"masses": body_nodes(SHAPE, n), "placed_by_the_brain": n - 1}
                   for n in N_MOV},
    }


@seed_figure("mnist-drawing")
def seed_figures(out: Path, per_seed: Sequence[Mapping[str, Any]], seeds: Sequence[int]) -> list[Path]:
    """Across seeds: each system's mean test drawing MSE and its share of drawings nearest to their own target (the
    claims' comparisons and their premise)."""
    from bptsb_ros.analysis.seed_plots import Bars, plot_bars_over_seeds

    keys = [(b, n) for n in N_MOV for b in BRAINS]
    names = [f"{b.upper()} {n}" for b, n in keys]
    mse = over_seeds(per_seed, claims, lambda num: [num.mse.get(k, math.nan) for k in keys])
    acc = over_seeds(per_seed, claims, lambda num: [100 * num.skill[k].accuracy if k in num.skill else math.nan
                                                    for k in keys])
    return [plot_bars_over_seeds(out / "errors_over_seeds.png",
                                 [Bars(names, mse, "test drawing MSE [m²]", title="mean test drawing error",
                                       xlabel="brain and N_mov"),
                                  Bars(names, acc, "drawings of the right digit [%]", xlabel="brain and N_mov",
                                       title="drawings nearest to their own target")],
                                 f"MNIST drawing, multiple-circle bodies: the four systems over {len(seeds)} seeds")]
