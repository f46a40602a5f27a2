"""MNIST drawing (paper: main text "Division of functional roles", Fig. 2(a)/(b); Methods "MNIST
classification and drawing task").

Four systems, {LIL, MLP} × multiple-circle bodies of 17 and 65 masses (the package's reading of the paper's
"N_mov = 17, 65"), are trained by BPTSB to draw the label's digit with the CMP after the brain has placed the
other movable masses; batch 50, the paper's learning rates (SGD: k 1e4, d 1e3, l 1, brain 1). Trainings are
independent jobs in a process pool.

Numbers: the mean test-set drawing MSE per system [m²] (the paper shows its values only in a figure: no
number to compare with), and the share of test drawings whose nearest target is their own label's.

Claims (the paper's words → our criterion):

* "the error was smaller in the MLP than in the LIL" → mean test MSE of MLP < LIL, for both bodies;
* "increasing the mass points led to better performance" → mean test MSE of 65 masses < 17, for both brains.
"""

from __future__ import annotations

import numpy as np

from bptsb_ros.experiments.mnist_common import load_data, run_jobs, train_drawing_job
from bptsb_ros.experiments.registry import Context, experiment

BRAINS = ("lil", "mlp")
NODES = (17, 65)
SHAPE = "multiple_circle"
BATCH = 50


def scale_settings(ctx: Context) -> dict[str, int | None]:
    """Training images, test images and epochs for the run's scale."""
    return {"n_train": ctx.pick(smoke=50, short=None, paper=None),
            "n_test": ctx.pick(smoke=30, short=None, paper=None),
            "epochs": ctx.pick(smoke=1, short=3, paper=50)}


def nearest_target_accuracy(drawings: np.ndarray, labels: np.ndarray) -> float:
    """Share of drawings (n, T+1, 2) whose closest target (MSE over the target's steps) is their label's."""
    import torch

    from bptsb_ros.tasks.mnist_drawing import DigitTargets

    errs = DigitTargets(dtype=torch.float64).all_errors(torch.as_tensor(drawings))
    return float((errs.argmin(1).numpy() == labels).mean())


def system_meta(ctx: Context, data_key: str, epochs: int) -> dict:
    return {"experiment": "mnist-drawing", "scale": ctx.scale, "seed": ctx.seed, "data": data_key,
            "epochs": epochs, "batch": BATCH}


@experiment(
    "mnist-drawing",
    paper_ref="Fig. 2(a)/(b); Methods 'MNIST classification and drawing task'",
    summary="{LIL, MLP} × multiple-circle 17/65: image → initial positions → released body draws the digit (MSE)",
    durations={"smoke": "≈ 15-45 s", "short": "≈ 10 min (8,000 images, 3 epochs; 2 processes; measured under load)",
               "paper": "≈ 4 h on 2 free cores (60,000 images, 50 epochs; 0.07 / 0.16 s per update for 17 / 65)"},
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.mnist_plots import plot_best_drawings, plot_curves, plot_error_bars
    from bptsb_ros.tasks.digits import load_targets
    from bptsb_ros.tasks.mnist_drawing import SystemSpec

    s = scale_settings(ctx)
    data = load_data(ctx, s["n_train"], s["n_test"])
    specs = [SystemSpec(brain=b, shape=SHAPE, nodes=n) for n in NODES for b in BRAINS]
    meta = system_meta(ctx, data.key, s["epochs"])
    jobs = [dict(spec_json=spec.to_json(), seed=ctx.seed, train_x=data.train_x, train_y=data.train_y,
                 test_x=data.test_x, test_y=data.test_y, epochs=s["epochs"], batch=BATCH,
                 checkpoint=str(ctx.out_dir / "systems" / f"{spec.name}.pt"), meta=meta) for spec in specs]
    ctx.log(f"mnist-drawing: training {len(specs)} systems for {s['epochs']} epochs on {len(data.train_y)} images")
    results = run_jobs(train_drawing_job, jobs, ctx.log)
    label = {spec.name: f"{spec.brain.upper()} + MC {spec.nodes}" for spec in specs}
    mean = {}
    per_digit = {}
    for spec, res in zip(specs, results):
        err = res["errors"]
        mean[spec.name] = float(err.mean())
        acc = nearest_target_accuracy(res["drawings"], data.test_y)
        ctx.row(label[spec.name], "test drawing MSE (mean)", "m²", mean[spec.name], None)
        ctx.row(label[spec.name], "test drawings nearest to their own target", "%", 100 * acc, None)
        per_digit[label[spec.name]] = [float(err[data.test_y == d].mean()) if (data.test_y == d).any() else None
                                       for d in range(10)]
    by = {(spec.brain, spec.nodes): mean[spec.name] for spec in specs}
    mlp_better = [by[("mlp", n)] < by[("lil", n)] for n in NODES]
    ctx.claim("the MLP brain draws with a smaller error than the LIL (both bodies)", all(mlp_better),
              "; ".join(f"MC {n}: MLP {by[('mlp', n)]:.4g} vs LIL {by[('lil', n)]:.4g} m²" for n in NODES))
    more_better = [by[(b, 65)] < by[(b, 17)] for b in BRAINS]
    ctx.claim("more mass points give a smaller error (65 < 17, both brains)", all(more_better),
              "; ".join(f"{b.upper()}: 65 → {by[(b, 65)]:.4g} vs 17 → {by[(b, 17)]:.4g} m²" for b in BRAINS))

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
        "reading": "multiple-circle nodes 17/65 count every mass (docs); 4 and 36 masses are placed by the brain",
    }
