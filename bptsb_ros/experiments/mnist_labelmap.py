"""Label maps and label-map sizes (paper: Fig. 2(d)/(e); Methods; supplement "Label maps").

For the MLP + multiple-circle N_mov 17 system (37 masses: 20 fixed, 12 placed masses not joined to the CMP, 4
joined, and the CMP; the same system as ``mnist-drawing``'s and ``mnist-pca``'s, reused from
``<out>/../mnist-drawing/systems/`` when that run used the same scale, seed and data, else trained here), each
placed (non-central) mass is shifted by (Δx, Δy) on a grid around its trained initial position for the best
test sample of every digit, the body is released, and every cell is labelled with the digit whose target the
CMP's drawing is closest to (MSE). The label-map size is the share of cells that keep the original label;
Fig. 2(e) shows it per mass. All grids are one batched simulation.

Grid: Δ within ±size/deltaScale = ±0.8 m (the published ``deltaScale: 5``, our reading).

Claims: "the label map size of the mass point that connects directly to the CMP is smaller" → mean size of the
joined masses < mean of the others; supplement: the largest-size mass is not joined, the smallest-size one is.
"""

from __future__ import annotations

from bptsb_ros.experiments.mnist_analysis import PAPER_GRID, labelmap_analysis
from bptsb_ros.experiments.mnist_common import body_nodes, load_data, obtain_drawing_system
from bptsb_ros.experiments.mnist_drawing import BATCH, SHAPE, scale_settings, system_label, system_meta
from bptsb_ros.experiments.registry import Context, experiment

#: the paper's label-map body (Fig. 2(d)/(e)): multiple circle with N_mov = 17 movable masses
N_MOV = 17


@experiment(
    "mnist-labelmap",
    paper_ref="Fig. 2(d)/(e); Methods; supplement 'Label maps'",
    summary="MLP + multiple-circle N_mov 17: label maps per placed mass, label-map sizes, joined-to-CMP claim",
    durations={"smoke": "≈ 20 s", "short": "≈ 1 min reusing a short mnist-drawing run (≈ 2-4 min training its own)",
               "paper": "≈ 2-3 min reusing a paper-scale mnist-drawing run (41×41 grids: 268,960 bodies), else "
                        "≈ 25-45 min (60,000 images × 50 epochs)"},
)
def run(ctx: Context) -> None:
    from bptsb_ros.tasks.mnist_drawing import SystemSpec

    s = scale_settings(ctx)
    grid = ctx.pick(smoke=3, short=15, paper=PAPER_GRID)
    data = load_data(ctx, s["n_train"], s["n_test"])
    spec = SystemSpec(brain="mlp", shape=SHAPE, nodes=body_nodes(SHAPE, N_MOV))
    reuse = ctx.out_dir.parent / "mnist-drawing" / "systems" / f"{spec.name}.pt"
    system, ev, source = obtain_drawing_system(ctx, spec, data, epochs=s["epochs"], batch=BATCH,
                                               meta=system_meta(ctx, data.key, s["epochs"]), reuse=reuse)
    label = system_label("mlp", N_MOV)
    ctx.row(label, "test drawing MSE (mean)", "m²", float(ev["errors"].mean()))
    maps = labelmap_analysis(ctx, system, ev, data.test_y, grid, label)
    ctx.result.details = {"system": source, "spec": spec.to_json(), "epochs": s["epochs"], "label_maps": maps,
                          "data": data.description}
