"""MNIST drawing with 100 specific inputs (paper: supplement "MNIST classification with specific inputs").

100 training images, 10 of every digit chosen at random (seeded) from the training part of the split, are
used for training *and* testing. Systems: {LIL, MLP} × {double-circle N_mov 17 and 65 (33 and 129 masses),
multiple-circle 17 and 65 masses (the package's reading)}, plus the MLP + multiple-circle 37 (17 movable) body
for the label maps (see ``mnist-labelmap`` for why). Trainings are independent jobs in a process pool.

Claims (the supplement's words → our criterion):

* "The MLP yielded less error than the LIL" → MLP < LIL for every body (4 comparisons);
* "bodies with more mass points performed better" → 65 < 17 for every brain and shape (4 comparisons);
* "the result for the body demonstrates explicit separation for each label" while the brain's is moderate →
  silhouette (2-D PCA) of the body output > brain output, MLP + multiple-circle 17;
* label-map sizes of the masses joined to the CMP are comparatively small → mean joined < mean others.
"""

from __future__ import annotations

from bptsb_ros.experiments.mnist_analysis import labelmap_analysis, pca_analysis
from bptsb_ros.experiments.mnist_common import load_data, run_jobs, specific_images, train_drawing_job
from bptsb_ros.experiments.registry import Context, experiment

BODIES = (("double_circle", 33, 17), ("double_circle", 129, 65), ("multiple_circle", 17, 17),
          ("multiple_circle", 65, 65))  # (shape, nodes, the paper's N_mov)
BRAINS = ("lil", "mlp")
LABELMAP_NODES = 37
BATCH = 50


def _short(shape: str) -> str:
    return "DC" if shape == "double_circle" else "MC"


@experiment(
    "mnist-specific100",
    paper_ref="supplement 'MNIST classification with specific inputs' (Fig. S: errors, label-map sizes, PCA)",
    summary="100 fixed images (10 per digit) train = test: {LIL, MLP} × four bodies; errors, PCA, label maps",
    durations={"smoke": "≈ 25 s", "short": "≈ 22 min under load (150 epochs of 2 batches, 9 systems; 2 processes)",
               "paper": "≈ 1 h on 2 free cores (1,000 epochs; the paper gives no epoch count)"},
)
def run(ctx: Context) -> None:
    from bptsb_ros.analysis.mnist_plots import plot_best_drawings, plot_error_bars
    from bptsb_ros.tasks.digits import load_targets
    from bptsb_ros.tasks.mnist_drawing import SystemSpec, load_system

    per_digit = ctx.pick(smoke=2, short=10, paper=10)
    epochs = ctx.pick(smoke=1, short=150, paper=1000)
    grid = ctx.pick(smoke=3, short=15, paper=41)
    data = load_data(ctx, None, 0)
    x, y = specific_images(data.train_x, data.train_y, per_digit, ctx.seed)
    ctx.result.provenance["data"] = (f"{10 * per_digit} images ({per_digit} per digit, seed {ctx.seed}) from the "
                                     f"training part of: {data.description}; used for training and testing")
    specs = [SystemSpec(brain=b, shape=shape, nodes=n) for shape, n, _ in BODIES for b in BRAINS]
    specs.append(SystemSpec(brain="mlp", shape="multiple_circle", nodes=LABELMAP_NODES))
    meta = {"experiment": "mnist-specific100", "scale": ctx.scale, "seed": ctx.seed}
    jobs = [dict(spec_json=sp.to_json(), seed=ctx.seed, train_x=x, train_y=y, test_x=x, test_y=y, epochs=epochs,
                 batch=BATCH, checkpoint=str(ctx.out_dir / "systems" / f"{sp.name}.pt"), meta=meta) for sp in specs]
    ctx.log(f"mnist-specific100: {len(specs)} systems, {epochs} epochs on {len(y)} images")
    results = dict(zip([sp.name for sp in specs], run_jobs(train_drawing_job, jobs, ctx.log)))
    paper_nmov = {(shape, n): m for shape, n, m in BODIES}
    label = {}
    mean = {}
    metric = f"drawing MSE on the {len(y)} training = test images (mean)"
    for sp in specs[:-1]:
        label[sp.name] = f"{sp.brain.upper()} + {_short(sp.shape)} N_mov {paper_nmov[(sp.shape, sp.nodes)]}"
        mean[(sp.brain, sp.shape, sp.nodes)] = float(results[sp.name]["errors"].mean())
        ctx.row(label[sp.name], metric, "m²", mean[(sp.brain, sp.shape, sp.nodes)])
    mlp = [(shape, n, mean[("mlp", shape, n)], mean[("lil", shape, n)]) for shape, n, _ in BODIES]
    ctx.claim("the MLP yields less error than the LIL (every body)", all(m < lil for _, _, m, lil in mlp),
              "; ".join(f"{_short(s)} {n}: MLP {m:.3g} vs LIL {lil:.3g}" for s, n, m, lil in mlp))
    more = [(b, shape, mean[(b, shape, big)], mean[(b, shape, small)])
            for b in BRAINS for shape, small, big in (("double_circle", 33, 129), ("multiple_circle", 17, 65))]
    ctx.claim("bodies with more mass points perform better (65 < 17, every brain and shape)",
              all(big < small for *_, big, small in more),
              "; ".join(f"{b.upper()} {_short(s)}: 65 → {big:.3g} vs 17 → {small:.3g}" for b, s, big, small in more))

    pca_spec = SystemSpec(brain="mlp", shape="multiple_circle", nodes=17)
    pca = pca_analysis(ctx, results[pca_spec.name], y, "MLP + MC 17 trained on 100 specific images: 2-D PCA",
                       "MLP + MC 17 (specific 100)")
    lm_spec = specs[-1]
    lm_res = results[lm_spec.name]
    system, _ = load_system(lm_res["checkpoint"])
    lm_label = f"MLP + MC {LABELMAP_NODES} (17 movable, specific 100)"
    ctx.row(lm_label, metric, "m²", float(lm_res["errors"].mean()))
    maps = labelmap_analysis(ctx, system, lm_res, y, grid, lm_label)

    targets = load_targets()
    ctx.figure(plot_best_drawings(ctx.out_dir / "drawings.png",
                                  {label[sp.name]: {"drawings": results[sp.name]["drawings"],
                                                    "errors": results[sp.name]["errors"], "labels": y}
                                   for sp in specs[:-1] if sp.brain == "mlp"}, targets, 0.01))
    names = [label[sp.name] for sp in specs[:-1]]
    errs = [results[sp.name]["errors"] for sp in specs[:-1]]
    ctx.figure(plot_error_bars(ctx.out_dir / "errors.png", names, [float(e.mean()) for e in errs],
                               [float(e.std() / len(e) ** 0.5) for e in errs],
                               f"Specific {len(y)} images: mean drawing MSE (train = test)"))
    ctx.result.details = {"epochs": epochs, "images": len(y), "pca": pca, "label_maps": maps,
                          "systems": {sp.name: {"updates": results[sp.name]["updates"],
                                                "train_s": round(results[sp.name]["train_s"], 1),
                                                "guard": results[sp.name]["guard"]} for sp in specs}}
