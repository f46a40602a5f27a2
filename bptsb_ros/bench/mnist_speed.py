"""MNIST training throughput (images/s per system) and what the MNIST experiments cost at the paper's schedule.

Every distinct system the MNIST experiments train is timed with the experiments' own training and evaluation
functions (``train_drawing`` / ``evaluate_drawing``, ``train_readout`` / ``accuracy``), batch 50, on synthetic
28 × 28 images (no data set needed: the cost does not depend on the pixel values), one torch thread, as one
worker of the experiments' process pool runs. The paper-schedule estimate multiplies these rates by the work
of each experiment at ``--scale paper`` (60,000 training / 10,000 test images; epochs, images per digit and
label-map grids from the experiments' paper settings, ``experiments/settings/<name>.yaml``) and packs the
independent trainings onto ``workers`` processes (longest first). It assumes a
worker runs as fast in the pool as alone; on a loaded machine it does not (see ``load_average``).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

#: the MNIST split sizes (paper split: the training set, the test set)
PAPER_TRAIN_IMAGES, PAPER_TEST_IMAGES = 60_000, 10_000
#: the slowest system's training rate that keeps one paper-scale training of 50 epochs within 1 h of one core
#: (readout: 100 epochs in 2 h): 50 × 60,000 images / 3,600 s
TARGET_TRAIN_IMAGES_PER_S = 50 * PAPER_TRAIN_IMAGES / 3600
#: images of the warm-up evaluation: enough for the kernels' parallel build (``kernel.PARALLEL_MIN_BATCH``)
PARALLEL_WARM_UP = 256


def systems() -> list[dict[str, Any]]:
    """Every distinct system of the MNIST experiments: ``kind`` (drawing | readout), ``label``, the spec."""
    from bptsb_ros.experiments import mnist_drawing, mnist_readout, mnist_specific100

    out: dict[str, dict[str, Any]] = {}
    for b, shape, n, spec in mnist_specific100.systems() + [(b, spec.shape, n, spec)
                                                             for b, n, spec in mnist_drawing.systems()]:
        out.setdefault(spec.name, {"kind": "drawing", "label": mnist_drawing.system_label(b, n, shape),
                                   "spec": spec.to_json(), "masses": spec.nodes, "n_movable": n})
    for shape, n, nodes, label, _ in mnist_readout.systems():
        out[f"readout {label}"] = {"kind": "readout", "label": f"readout: {label}", "shape": shape, "nodes": nodes,
                                   "masses": nodes, "n_movable": n}
    return list(out.values())


def _images(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 784) float32 images in [0, 1], about a fifth of the pixels lit like MNIST, and labels cycling 0-9."""
    rng = np.random.default_rng(seed)
    x = (rng.random((n, 784)) * (rng.random((n, 784)) < 0.2)).astype(np.float32)
    return x, rng.permutation(np.arange(n) % 10).astype(np.int64)


def measure_system(entry: dict[str, Any], *, min_seconds: float, min_updates: int, eval_images: int,
                   repeats: int = 1, batch: int = 50) -> dict[str, Any]:
    """Time one system: training updates (forward + backward + update of a batch) and evaluation (forward only).

    After two warm-up updates (numba cache, allocator) it trains ``repeats`` times for max(``min_updates``,
    ≈ ``min_seconds`` / ``repeats``) updates (one epoch each) and, after a warm-up evaluation, evaluates
    ``eval_images`` images ``repeats`` times as the experiment does (chunks of 500 / 1,000 images: the kernels'
    parallel build). Returns the best repeat's images/s and ms per update (on a shared machine the least
    disturbed one) and every repeat's training images/s.
    """
    import torch

    from bptsb_ros.tasks import drawing as draw
    from bptsb_ros.tasks import readout as ro

    torch.set_num_threads(1)
    if entry["kind"] == "drawing":
        model = draw.ImageToBody(draw.SystemSpec.from_json(entry["spec"]), 0)

        def train(x, y):
            draw.train_drawing(model, x, y, epochs=1, batch=batch)

        def evaluate(x, y):
            draw.evaluate_drawing(model, x, y)
    else:
        model = ro.ReadoutSystem(ro.ReadoutSpec(shape=entry["shape"], nodes=entry["nodes"]), 0)

        def train(x, y):
            ro.train_readout(model, x, y, epochs=1, batch=batch)

        def evaluate(x, y):
            ro.accuracy(model, x, y)

    x, y = _images(2 * batch, seed=1)
    t0 = time.perf_counter()
    train(x, y)
    guess = (time.perf_counter() - t0) / 2
    updates = max(min_updates, math.ceil(min_seconds / repeats / max(guess, 1e-6)))
    x, y = _images(updates * batch, seed=2)
    train_s = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        train(x, y)
        train_s.append(time.perf_counter() - t0)
    x, y = _images(eval_images, seed=3)
    evaluate(x[:PARALLEL_WARM_UP], y[:PARALLEL_WARM_UP])  # loads the parallel kernels (batches of ≥ 256 bodies)
    eval_s = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        evaluate(x, y)
        eval_s.append(time.perf_counter() - t0)
    return {"updates": updates, "ms_per_update": round(1000 * min(train_s) / updates, 2),
            "train_images_per_s": round(updates * batch / min(train_s), 1),
            "train_images_per_s_repeats": [round(updates * batch / t, 1) for t in train_s],
            "forward_images_per_s": round(eval_images / min(eval_s), 1)}


def _schedule(jobs: list[float], workers: int) -> float:
    """Makespan [s] of independent jobs [s] on ``workers`` processes, longest first onto the least-loaded one."""
    load = [0.0] * max(1, workers)
    for t in sorted(jobs, reverse=True):
        load[load.index(min(load))] += t
    return max(load)


def paper_estimates(rates: dict[str, dict[str, float]], workers: int) -> dict[str, Any]:
    """Hours each MNIST experiment takes at ``--scale paper`` from measured ``rates`` (label → train and forward
    images/s, as :func:`measure_system` returns), with ``workers`` pool processes and on one core.

    Work per experiment (trainings of batch 50; evaluation is forward only):
    drawing: 4 systems × (50 epochs × 60,000 images) + 10,000 test images each; pca: the MLP + N_mov 17 system
    (0 when reused from mnist-drawing) + its test images; labelmap: the same + 16 masses × 10 labels × 41² label-map
    bodies; specific100: 8 systems × 1000 epochs × 100 images + their 100 evaluations + the label maps;
    readout: 5 systems × (100 epochs × 60,000 images + 100 per-epoch test evaluations of 10,000 images
    + the final training- and test-set accuracies).
    """
    from bptsb_ros.experiments import mnist_drawing as dr
    from bptsb_ros.experiments import mnist_readout as ro
    from bptsb_ros.experiments import mnist_specific100 as sp
    from bptsb_ros.experiments.experiment_settings import resolve_settings

    paper = {name: resolve_settings(name, "paper") for name in ("mnist-drawing", "mnist-labelmap", "mnist-specific100",
                                                                "mnist-readout")}
    drawing_epochs, readout_epochs = paper["mnist-drawing"]["epochs"], paper["mnist-readout"]["epochs"]
    sp_epochs, sp_per_digit = paper["mnist-specific100"]["epochs"], paper["mnist-specific100"]["per_digit"]

    def drawing(label: str, epochs: int, n_train: int, n_test: int) -> float:
        r = rates[label]
        return epochs * n_train / r["train_images_per_s"] + n_test / r["forward_images_per_s"]

    mlp17 = dr.system_label("mlp", 17)
    label_map_bodies = 16 * 10 * paper["mnist-labelmap"]["grid"] ** 2  # the N_mov 17 body: 16 placed masses
    label_maps = label_map_bodies / rates[mlp17]["forward_images_per_s"]
    mlp17_training = drawing(mlp17, drawing_epochs, PAPER_TRAIN_IMAGES, PAPER_TEST_IMAGES)
    jobs: dict[str, list[float]] = {
        "mnist-drawing": [drawing(dr.system_label(b, n), drawing_epochs, PAPER_TRAIN_IMAGES, PAPER_TEST_IMAGES)
                          for b, n, _ in dr.systems()],
        "mnist-pca": [mlp17_training],
        "mnist-labelmap": [mlp17_training + label_maps],
        "mnist-specific100": [drawing(dr.system_label(b, n, shape), sp_epochs, 10 * sp_per_digit,
                                      10 * sp_per_digit) for b, shape, n, _ in sp.systems()],
        "mnist-readout": [],
    }
    for _, _, _, label, _ in ro.systems():
        r = rates[f"readout: {label}"]
        evaluated = readout_epochs * PAPER_TEST_IMAGES + PAPER_TRAIN_IMAGES + PAPER_TEST_IMAGES
        jobs["mnist-readout"].append(readout_epochs * PAPER_TRAIN_IMAGES / r["train_images_per_s"]
                                     + evaluated / r["forward_images_per_s"])
    out: dict[str, Any] = {}
    for name, times in jobs.items():
        serial_after = 0.0
        if name == "mnist-specific100":  # its PCA and label maps follow the trainings, in the main process
            serial_after = label_maps
        out[name] = {"systems": len(times), "one_core_h": round((sum(times) + serial_after) / 3600, 3),
                     "pool_h": round((_schedule(times, workers) + serial_after) / 3600, 3)}
    for name in ("mnist-pca", "mnist-labelmap"):  # the default layout reuses mnist-drawing's system
        out[name]["after_mnist_drawing_h"] = round((jobs[name][0] - mlp17_training) / 3600, 3)
    # `bptsb reproduce` of the five one after another in the default layout: pca and labelmap reuse the drawing
    out["all_five_in_order_h"] = round(sum(out[n]["pool_h"] for n in
                                           ("mnist-drawing", "mnist-specific100", "mnist-readout"))
                                       + out["mnist-pca"]["after_mnist_drawing_h"]
                                       + out["mnist-labelmap"]["after_mnist_drawing_h"], 3)
    return out


def run_mnist_benchmarks(quick: bool, progress: Callable[[str], None] = print,
                         measure: Callable[..., dict[str, Any]] | None = None) -> dict[str, Any]:
    """Measure every MNIST system (``--quick``: ≈ 0.3 s of training each; else 3 repeats of ≈ 2 s, the best kept) and
    estimate the paper schedule."""
    measure = measure or measure_system
    settings = {"min_seconds": 0.3 if quick else 6.0, "min_updates": 2 if quick else 5,
                "eval_images": 500 if quick else 1000, "repeats": 1 if quick else 3}
    out: dict[str, Any] = {"batch": 50, "images": "synthetic 28×28, a fifth of the pixels lit", "threads": 1,
                           **settings, "load_average_at_start": list(os.getloadavg()), "systems": {}}
    t0 = time.perf_counter()
    for entry in systems():
        progress(f"bench mnist {entry['label']} ...")
        res = measure(entry, **settings)
        out["systems"][entry["label"]] = {"kind": entry["kind"], "masses": entry["masses"],
                                          "n_movable": entry["n_movable"], **res}
    out["seconds"] = round(time.perf_counter() - t0, 1)
    out["load_average_at_end"] = list(os.getloadavg())
    workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    out["paper_schedule"] = {"workers": workers, "hours": paper_estimates(out["systems"], workers)}
    return out


def _child(conn, quick: bool) -> None:
    import sys

    try:
        conn.send(run_mnist_benchmarks(quick, progress=lambda m: print(m, file=sys.stderr, flush=True)))
    except Exception as err:  # noqa: BLE001 - report any failure to the parent
        conn.send({"error": f"{type(err).__name__}: {err}"})
    finally:
        conn.close()


def run_isolated(quick: bool, timeout_s: float = 1800) -> dict[str, Any]:
    """:func:`run_mnist_benchmarks` in a fresh process (spawn: its own threads and allocator)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, quick))
    proc.start()
    child.close()
    result = parent.recv() if parent.poll(timeout_s) else {"error": "timed out"}
    proc.join(30)
    return result


def mnist_table(entry: dict[str, Any]) -> str:
    """A Markdown table of the measured MNIST systems."""
    rows = ["| MNIST system | masses / movable | train images/s | ms per update (batch 50) | forward images/s |",
            "|---|---|---|---|---|"]
    for label, m in entry["systems"].items():
        rows.append(f"| {label} | {m['masses']} / {m['n_movable']} | {m['train_images_per_s']} | "
                    f"{m['ms_per_update']} | {m['forward_images_per_s']} |")
    return "\n".join(rows)
