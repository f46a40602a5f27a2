"""Label maps and label-map sizes (paper: Fig. 2(d)/(e); Methods; supplement "Label maps").

For an MLP + multiple-circle system, each placed (non-central) mass is shifted by (Δx, Δy) on a grid around its
trained initial position for the best test sample of every digit, the body is released, and every cell is
labelled with the digit whose target the CMP's drawing is closest to (MSE). The label-map size is the share of
cells that keep the original label; Fig. 2(e) shows it per mass. All grids are one batched simulation.

Body: multiple-circle with 37 masses, i.e. 17 movable masses. Under the package's reading (``nodes`` counts every
mass) the paper's "N_mov = 17" multiple-circle body has only 4 placed masses, all joined to the CMP, and the
paper's statements about masses that are *not* joined to the CMP could not apply to it; 37 masses give exactly
17 movable ones (12 not joined to the CMP, 4 joined), the body these statements need.

Grid: Δ within ±size/deltaScale = ±0.8 m (the published ``deltaScale: 5``, our reading).

Claims: "the label map size of the mass point that connects directly to the CMP is smaller" → mean size of the
joined masses < mean of the others; supplement: the largest-size mass is not joined, the smallest-size one is.
"""

from __future__ import annotations

from bptsb_ros.experiments.mnist_analysis import labelmap_analysis
from bptsb_ros.experiments.mnist_common import load_data, obtain_drawing_system
from bptsb_ros.experiments.mnist_drawing import BATCH, SHAPE, scale_settings
from bptsb_ros.experiments.registry import Context, experiment

NODES = 37


@experiment(
    "mnist-labelmap",
    paper_ref="Fig. 2(d)/(e); Methods; supplement 'Label maps'",
    summary="MLP + multiple-circle 37 (17 movable): label maps per placed mass, label-map sizes, joined-to-CMP claim",
    durations={"smoke": "≈ 10 s", "short": "≈ 3 min (8,000 images, 3 epochs; 15×15 grids)",
               "paper": "≈ 2 h (60,000 images, 50 epochs; 41×41 grids)"},
)
def run(ctx: Context) -> None:
    from bptsb_ros.tasks.mnist_drawing import SystemSpec

    s = scale_settings(ctx)
    grid = ctx.pick(smoke=3, short=15, paper=41)
    data = load_data(ctx, s["n_train"], s["n_test"])
    spec = SystemSpec(brain="mlp", shape=SHAPE, nodes=NODES)
    meta = {"experiment": "mnist-labelmap", "scale": ctx.scale, "seed": ctx.seed, "data": data.key}
    system, ev, source = obtain_drawing_system(ctx, spec, data, epochs=s["epochs"], batch=BATCH, meta=meta)
    label = f"MLP + MC {NODES} ({system.body.n_movable} movable)"
    ctx.row(label, "test drawing MSE (mean)", "m²", float(ev["errors"].mean()))
    maps = labelmap_analysis(ctx, system, ev, data.test_y, grid, label)
    ctx.result.details = {"system": source, "spec": spec.to_json(), "epochs": s["epochs"], "label_maps": maps,
                          "data": data.description}
