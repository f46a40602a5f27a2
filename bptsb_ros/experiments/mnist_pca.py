"""PCA of the brain's and the body's outputs (paper: main text "Division of functional roles", Fig. 2(c)).

The MLP + multiple-circle N_mov 17 (37 masses) drawing system (the same settings as ``mnist-drawing``; its
trained system is reused from ``<out>/../mnist-drawing/systems/`` when that run used the same scale, seed and
data, else trained here). On the test images, the brain output (the initial positions of the placed masses)
and the body output (the CMP trajectory) are each projected to 2-D by PCA and coloured by label; the separation
of the labels is measured by the silhouette coefficient (2-D and all features) and a linear probe.

Claim: "more separation was emphasized ... in the output of the body" → silhouette in the 2-D PCA plane of the
body output > that of the brain output.
"""

from __future__ import annotations

from bptsb_ros.experiments.mnist_analysis import pca_analysis
from bptsb_ros.experiments.mnist_common import body_nodes, load_data, obtain_drawing_system
from bptsb_ros.experiments.mnist_drawing import BATCH, SHAPE, scale_settings, system_label, system_meta
from bptsb_ros.experiments.registry import Context, experiment

#: the paper's Fig. 2(c) system: MLP + multiple circle with N_mov = 17 movable masses
N_MOV = 17


@experiment(
    "mnist-pca",
    paper_ref="Fig. 2(c); main text 'Division of functional roles'",
    summary="MLP + multiple-circle N_mov 17: brain vs body output in 2-D PCA, label separation (silhouette, probe)",
    durations={"smoke": "≈ 15 s", "short": "≈ 1 min reusing a short mnist-drawing run (≈ 2-4 min training its own)",
               "paper": "≈ 1 min reusing a paper-scale mnist-drawing run, else ≈ 25-45 min (60,000 images × 50 "
                        "epochs)"},
)
def run(ctx: Context) -> None:
    from bptsb_ros.tasks.mnist_drawing import SystemSpec

    s = scale_settings(ctx)
    data = load_data(ctx, s["n_train"], s["n_test"])
    spec = SystemSpec(brain="mlp", shape=SHAPE, nodes=body_nodes(SHAPE, N_MOV))
    reuse = ctx.out_dir.parent / "mnist-drawing" / "systems" / f"{spec.name}.pt"
    system, ev, source = obtain_drawing_system(ctx, spec, data, epochs=s["epochs"], batch=BATCH,
                                               meta=system_meta(ctx, data.key, s["epochs"]), reuse=reuse)
    label = system_label("mlp", N_MOV)
    ctx.row(label, "test drawing MSE (mean)", "m²", float(ev["errors"].mean()))
    scores = pca_analysis(ctx, ev, data.test_y, f"{label}: outputs on {len(data.test_y)} test images, 2-D PCA",
                          label)
    ctx.result.details = {"system": source, "spec": spec.to_json(), "epochs": s["epochs"], "scores": scores,
                          "data": data.description}
