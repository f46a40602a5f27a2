"""Benchmarks of the standard workloads: physics steps per second (forward alone; forward + backward
+ update) and peak memory, each workload in its own process so its peak RSS is its own.

Speed is measured here, never asserted in a timed test.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import platform
import resource
import time
from dataclasses import dataclass, replace
from typing import Any

import torch

#: published code on a 2-core machine, training steps/s (facts file): as shipped / anomaly mode off
PUBLISHED = {
    "lissajous": {"as_published": 131, "anomaly_mode_off": 1010},
    "locomotion": {"as_published": 80, "anomaly_mode_off": 706},
    "narma": {"as_published": 97, "anomaly_mode_off": 707},
}


@dataclass(frozen=True)
class Workload:
    name: str
    shape: str
    nodes: int
    batch: int
    window: int
    brain: str  # swg | mlp | mnist
    environment: str = "none"
    description: str = ""


WORKLOADS = {
    "lissajous": Workload("lissajous", "double_circle", 25, 1, 100, "swg",
                          description="Lissajous: double-circle 25 masses / 48 springs, SWG, 100-step windows, "
                                      "batch 1"),
    "narma": Workload("narma", "double_circle", 33, 1, 3000, "mlp",
                      description="expanded NARMA: double-circle 33 masses, MLP forces, 3000-step episode, batch 1"),
    "locomotion": Workload("locomotion", "caterpillar", 10, 20, 200, "swg", "locomotion",
                           description="locomotion: caterpillar 10 masses / 24 springs, environment, 200-step windows, "
                                       "batch 20"),
    "mnist_like": Workload("mnist_like", "double_circle", 33, 100, 200, "mnist",
                           description="MNIST-like: double-circle 33 masses, MLP 784→128→128 initial displacements, "
                                       "batch 100, 200 steps"),
}


def _setup(w: Workload, adjoint: bool, dtype: torch.dtype):
    from bptsb_ros.agent import Agent, brain_forces, force_inputs
    from bptsb_ros.body.adjoint import rollout_window
    from bptsb_ros.body.msdn import MSDN, Environment
    from bptsb_ros.body.shapes import build_shape
    from bptsb_ros.brains import MLPBrain, SineWaveGenerator

    gen = torch.Generator().manual_seed(0)
    env = replace(Environment.locomotion(), ground_clamp=True) if w.environment == "locomotion" else Environment()
    body = MSDN(build_shape(w.shape, w.nodes), environment=env, generator=gen, dtype=dtype)
    n_springs, n_mov = body.topology.n_springs, body.n_movable
    params = list(body.parameters())
    if w.brain == "swg":
        swg = SineWaveGenerator(n_springs, amplitude=0.4, generator=gen, dtype=dtype)
        params += list(swg.parameters())
    else:
        n_in = 784 if w.brain == "mnist" else 1
        n_out = 2 * (int(force_inputs(body).sum()) if w.brain == "mlp" else n_mov)
        mlp = MLPBrain(n_in, n_out, generator=gen, dtype=dtype)
        params += list(mlp.parameters())
        inputs = torch.rand(w.batch if w.brain == "mnist" else w.window // 20, n_in, generator=gen, dtype=dtype)
    opt = torch.optim.SGD(params, lr=1e-9)
    cmp = max(body.cmp_local, 0)
    state0 = body.initial_state(w.batch).detach()

    def run_window(state):
        k0 = state.step
        t = torch.arange(k0 + 1, k0 + 1 + w.window, dtype=dtype) * body.dt
        ext = None
        if w.brain == "swg":
            rest = swg.rest_length(body.l, t)
        else:
            rest = body.l.expand(w.window, -1)
            if w.brain == "mlp":
                forces = brain_forces(Agent({}, body, mlp, None), inputs)
                ext = forces.repeat_interleave(20, 0).unsqueeze(1)
            else:
                disp = 0.1 * torch.tanh(mlp(inputs)).view(w.batch, n_mov, 2)
                state = body.initial_state(w.batch, displacement=disp)
        win = rollout_window(body, state, rest, ext, adjoint=adjoint)
        loss = (win.r[:, :, cmp] ** 2).mean()
        return loss, win.final

    return body, opt, state0, run_window


def _measure(w: Workload, adjoint: bool, dtype: torch.dtype, min_seconds: float) -> dict[str, float]:
    torch.set_num_threads(1)
    body, opt, state, run_window = _setup(w, adjoint, dtype)
    loss, _ = run_window(state)  # warm-up
    loss.backward()

    def timed(train: bool) -> float:
        nonlocal state
        steps, t0 = 0, time.perf_counter()
        while True:
            if train:
                loss, final = run_window(state)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                body.clamp_parameters_()
            else:
                with torch.no_grad():
                    loss, final = run_window(state)
            state = final.detach() if w.brain == "swg" else state
            steps += w.window
            elapsed = time.perf_counter() - t0
            if elapsed >= min_seconds:
                return steps / elapsed

    forward = timed(False)
    train = timed(True)
    return {
        "forward_steps_per_s": round(forward, 1),
        "train_steps_per_s": round(train, 1),
        "train_body_steps_per_s": round(train * w.batch, 1),
    }


def _child(conn, w: Workload, adjoint: bool, dtype_name: str, min_seconds: float) -> None:
    try:
        out = _measure(w, adjoint, getattr(torch, dtype_name), min_seconds)
        out["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        conn.send(out)
    except Exception as err:  # noqa: BLE001 - report any failure to the parent
        conn.send({"error": f"{type(err).__name__}: {err}"})
    finally:
        conn.close()


def measure_isolated(w: Workload, adjoint: bool, dtype: str = "float32", min_seconds: float = 3.0) -> dict[str, Any]:
    """Run one measurement in a fresh process (spawn) and return its numbers and peak RSS."""
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, w, adjoint, dtype, min_seconds))
    proc.start()
    child.close()
    result = parent.recv() if parent.poll(600) else {"error": "timed out"}
    proc.join(30)
    return result


def run_benchmarks(quick: bool = False, progress=print) -> dict[str, Any]:
    """All workloads with the adjoint and with plain autograd, plus batch scaling of the Lissajous body."""
    min_s = 1.0 if quick else 3.0
    report: dict[str, Any] = {
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "cpu_count": mp.cpu_count(), "torch": torch.__version__, "threads_per_process": 1},
        "min_seconds_per_measurement": min_s,
        "published_code_train_steps_per_s": PUBLISHED,
        "workloads": {},
        "batch_scaling": {},
    }
    for name, w in WORKLOADS.items():
        entry: dict[str, Any] = {"description": w.description, "batch": w.batch, "window": w.window}
        for mode, adj in (("adjoint", True), ("autograd", False)):
            progress(f"bench {name} ({mode}) ...")
            entry[mode] = measure_isolated(w, adj, min_seconds=min_s)
        report["workloads"][name] = entry
    batches = (1, 8, 64) if quick else (1, 4, 16, 64, 256)
    base = WORKLOADS["lissajous"]
    for b in batches:
        progress(f"bench lissajous batch {b} ...")
        w = Workload(f"lissajous_b{b}", base.shape, base.nodes, b, base.window, base.brain)
        report["batch_scaling"][str(b)] = measure_isolated(w, True, min_seconds=min_s)
    liss = report["workloads"]["lissajous"]["adjoint"].get("train_steps_per_s", math.nan)
    report["target"] = {"lissajous_train_steps_per_s": 3000, "measured": liss, "met": bool(liss >= 3000)}
    report["ipc"] = _ipc_entry(quick, progress)
    return report


def _ipc_entry(quick: bool, progress) -> dict[str, Any]:
    """IPC of 17 masses × 2 axes, degree ≤ 3, delay ≤ 20, 3,000 samples, 200 surrogates (20 with --quick)."""
    from bptsb_ros.analysis.ipc import benchmark_ipc

    progress("bench ipc ...")
    return benchmark_ipc(surrogates=20 if quick else 200)


def workload_table(report: dict[str, Any]) -> str:
    """A Markdown table of the report (for the README)."""
    rows = ["| workload | batch | forward steps/s | train steps/s (adjoint) | train steps/s (autograd) "
            "| peak RSS MiB |",
            "|---|---|---|---|---|---|"]
    for name, e in report["workloads"].items():
        a, g = e["adjoint"], e["autograd"]
        rows.append(f"| {name} | {e['batch']} | {a.get('forward_steps_per_s')} | {a.get('train_steps_per_s')} | "
                    f"{g.get('train_steps_per_s')} | {a.get('peak_rss_mib')} |")
    return "\n".join(rows)


__all__ = ["WORKLOADS", "Workload", "measure_isolated", "run_benchmarks", "workload_table"]
