"""Benchmarks of the standard workloads: physics steps per second (forward alone; forward + backward
+ update) and peak memory, for both body backends side by side (torch: the reference; numba: the
compiled window kernel) and, for Lissajous training, the fused path (``training.backend: fused``: window,
loss, gradients and update as compiled calls), each measurement in its own process so its peak RSS is its
own; and the MNIST systems' training throughput in images/s with the paper-schedule estimate
(:mod:`bptsb_ros.bench.mnist_speed`).

Speed is measured here, never asserted in a timed test. The numba kernels' first-call time (compile, or
loading the on-disk cache) is measured separately and kept out of the steady-state figures.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import platform
import resource
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import torch

#: published code on a 2-core machine, training steps/s (facts file): as shipped / anomaly mode off
PUBLISHED = {
    "lissajous": {"as_published": 131, "anomaly_mode_off": 1010},
    "locomotion": {"as_published": 80, "anomaly_mode_off": 706},
    "narma": {"as_published": 97, "anomaly_mode_off": 707},
}
BACKENDS = ("torch", "numba")
#: workloads also timed on the fused training path (``training.backend: fused``: SWG, batch 1)
FUSED_WORKLOADS = ("lissajous",)
#: workloads whose task also has its own update timed on the numba path and its fused episodes (task_numba, task_fused)
TASK_WORKLOADS = ("narma",)
#: the fused path's target: training steps/s ≥ this × the numba path's, in the same run
FUSED_TARGET_RATIO = 5.0
#: the NARMA task's fused episodes' target: training steps/s ≥ this × its numba path's, in the same run
NARMA_FUSED_TARGET_RATIO = 2.0
#: the NARMA task rows' system: ``config/narma.yaml`` with the MLP brain
NARMA_TASK_OVERRIDES: dict[str, Any] = {"brain.type": "mlp"}
#: the memory task at the paper's schedule as populations on 2 processes: at most this many hours
MEMORY_TASK_TARGET_H = 3.0
#: the paper's expanded-NARMA schedule: epochs × steps per epoch
NARMA_PAPER_EPOCHS, NARMA_EPISODE_STEPS = 40_000, 3_000


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
    forward_only: bool = False
    #: time the task's own update (``NarmaTask``, ``config/narma.yaml``) instead of the bare body window
    task: bool = False
    #: ``task`` only: overrides of ``config/narma.yaml`` (``{"a.b": value}``)
    overrides: Mapping[str, Any] = field(default_factory=lambda: dict(NARMA_TASK_OVERRIDES))


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
    "sweep": Workload("sweep", "double_circle", 25, 1000, 100, "swg", forward_only=True,
                      description="forward-only batched rollouts (perturbation sweeps): double-circle 25, SWG, "
                                  "batch 1000, 100-step windows"),
}


def _setup(w: Workload, adjoint: bool, dtype: torch.dtype, backend: str = "numba"):
    from bptsb_ros.agent import Agent, brain_forces, force_inputs
    from bptsb_ros.body.adjoint import rollout_window
    from bptsb_ros.body.msdn import MSDN, Environment
    from bptsb_ros.body.shapes import build_shape
    from bptsb_ros.brains import MLPBrain, SineWaveGenerator

    gen = torch.Generator().manual_seed(0)
    env = replace(Environment.locomotion(), ground_clamp=True) if w.environment == "locomotion" else Environment()
    body = MSDN(build_shape(w.shape, w.nodes), environment=env, generator=gen, dtype=dtype, backend=backend)
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
    with torch.no_grad():
        state0 = body.initial_state(w.batch)
        if w.forward_only:  # a sweep: every body of the batch starts from its own perturbation
            state0 = body.initial_state(w.batch, displacement=0.05 * torch.randn(
                w.batch, n_mov, 2, generator=gen, dtype=torch.float64).to(dtype))

    def run_window(state):
        k0 = state.step
        ext = None
        if w.brain == "swg":
            rest = swg.rest_length_at_steps(body.l, torch.arange(k0 + 1, k0 + 1 + w.window), body.dt)
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

    run_window.swg = swg if w.brain == "swg" else None  # type: ignore[attr-defined] - for ``fused_runner``
    return body, opt, state0, run_window


def fused_runner(w: Workload, dtype: torch.dtype):
    """The workload of :func:`_setup` (numba body, same parameters, rates and start) on the fused path: the same
    loss, mean of CMP², is the fused Lissajous loss with a zero target. Returns (window(state) → (loss, final),
    step(), start state)."""
    from bptsb_ros.training.fused import FusedSwgWindow, LissajousLoss

    if w.brain != "swg" or w.batch != 1:
        raise ValueError(f"the fused path trains one SWG body; workload {w.name} has brain {w.brain}, batch {w.batch}")
    body, opt, state0, run_window = _setup(w, True, dtype, "numba")
    swg = run_window.swg
    fused = FusedSwgWindow(body, swg, opt, w.window, LissajousLoss(0.0, 0.0, 1.0, 1.0, 0.0, swg.omega, body.cmp_local))

    def window(state):
        loss, _ok, final = fused.window(state)
        return loss, final

    return window, fused.step, state0


def _timed(update, steps_per_update: int, min_seconds: float) -> tuple[float, float, float]:
    """Call ``update()`` once (compile or cache load: its time is returned apart), then until ``min_seconds``
    have passed. Returns (first call [s], steps/s, ms per update) of the timed calls."""
    t0 = time.perf_counter()
    update()
    first_call = time.perf_counter() - t0
    calls, t0 = 0, time.perf_counter()
    while True:
        update()
        calls += 1
        elapsed = time.perf_counter() - t0
        if elapsed >= min_seconds:
            return first_call, calls * steps_per_update / elapsed, 1e3 * elapsed / calls


def _measure_fused(w: Workload, dtype: torch.dtype, min_seconds: float) -> dict[str, Any]:
    """Training steps/s of the fused path (forward, loss, gradients and SGD update per window)."""
    from bptsb_ros.body.threads import configure_threads

    threads = configure_threads(w.batch, "numba")
    window, step, state = fused_runner(w, dtype)

    def update() -> None:
        nonlocal state
        _loss, state = window(state)
        step()

    first_call, train, _ms = _timed(update, w.window, min_seconds)
    return {"backend": "fused", "threads": threads, "first_call_s": round(first_call, 3),
            "train_steps_per_s": round(train, 1), "train_body_steps_per_s": round(train * w.batch, 1)}


def _measure_narma_task(backend: str, min_seconds: float, overrides: Mapping[str, Any] = NARMA_TASK_OVERRIDES
                        ) -> dict[str, Any]:
    """Training steps/s of the NARMA task itself (``config/narma.yaml``: double circle of 33 masses, MLP brain,
    3,000-step episodes, SGD; ``overrides``: ``--set`` items of that config) on the numba path or with its fused
    episodes (``body/held_window.py``)."""
    from bptsb_ros.body.threads import configure_threads

    threads = configure_threads(1, "numba")
    from bptsb_ros.bench.workloads import narma_task_update

    task, update = narma_task_update({**overrides, "training.backend": backend})

    first_call, train, ms = _timed(update, task.steps_per_update, min_seconds)
    return {"backend": backend, "fused_episodes": task.fused_episodes, "threads": threads,
            "first_call_s": round(first_call, 3), "train_steps_per_s": round(train, 1),
            "ms_per_update": round(ms, 2)}


def _measure(w: Workload, adjoint: bool, dtype: torch.dtype, min_seconds: float, backend: str) -> dict[str, Any]:
    from bptsb_ros.body.threads import configure_threads

    if w.task:
        return _measure_narma_task(backend, min_seconds, w.overrides)
    if backend == "fused":
        return _measure_fused(w, dtype, min_seconds)
    threads = configure_threads(w.batch, backend)
    body, opt, state, run_window = _setup(w, adjoint, dtype, backend)
    t0 = time.perf_counter()
    if w.forward_only:
        with torch.no_grad():
            run_window(state)
    else:
        loss, _ = run_window(state)
        loss.backward()
    first_call = time.perf_counter() - t0  # numba: compile or load the cache; kept out of the figures below

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

    out: dict[str, Any] = {"backend": backend, "threads": threads, "first_call_s": round(first_call, 3)}
    forward = timed(False)
    out["forward_steps_per_s"] = round(forward, 1)
    out["forward_body_steps_per_s"] = round(forward * w.batch, 1)
    if not w.forward_only:
        train = timed(True)
        out["train_steps_per_s"] = round(train, 1)
        out["train_body_steps_per_s"] = round(train * w.batch, 1)
    return out


def _child(conn, w: Workload, adjoint: bool, dtype_name: str, min_seconds: float, backend: str,
           numba_cache: str | None) -> None:
    try:
        if numba_cache is not None:  # before numba is imported
            os.environ["NUMBA_CACHE_DIR"] = numba_cache
            from bptsb_ros.body import compile_notice

            compile_notice.enabled = False  # this process times the compile; the bench's line says so
        out = _measure(w, adjoint, getattr(torch, dtype_name), min_seconds, backend)
        out["peak_rss_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        conn.send(out)
    except Exception as err:  # noqa: BLE001 - report any failure to the parent
        conn.send({"error": f"{type(err).__name__}: {err}"})
    finally:
        conn.close()


def measure_isolated(w: Workload, adjoint: bool, dtype: str = "float32", min_seconds: float = 3.0,
                     backend: str = "torch", numba_cache: str | None = None) -> dict[str, Any]:
    """Run one measurement in a fresh process (spawn) and return its numbers and peak RSS."""
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(child, w, adjoint, dtype, min_seconds, backend, numba_cache))
    proc.start()
    child.close()
    result = parent.recv() if parent.poll(900) else {"error": "timed out"}
    proc.join(30)
    return result


def measure_compile(min_seconds: float) -> dict[str, Any]:
    """The numba kernels' first call in a fresh process: with an empty cache (compile) and again (cache load).

    Lissajous training (serial kernels, float32) and the batched sweep (parallel forward); the normal cache
    lives beside the module (``bptsb_ros/body/__pycache__``), reused by every later run.
    """
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="bptsb-numba-cache-") as cache:
        for label in ("cold_compile", "cached"):
            first = {}
            for name in ("lissajous", "sweep"):
                r = measure_isolated(WORKLOADS[name], True, min_seconds=min_seconds, backend="numba",
                                     numba_cache=cache)
                first[name] = r.get("first_call_s", r.get("error"))
            out[label] = {"lissajous_train_first_call_s": first["lissajous"],
                          "sweep_forward_first_call_s": first["sweep"]}
    return out


def _ratio(a: Any, b: Any) -> float | None:
    return round(a / b, 2) if isinstance(a, (int, float)) and isinstance(b, (int, float)) and b else None


def run_benchmarks(quick: bool = False, progress=print, update=None) -> dict[str, Any]:
    """All workloads on both backends (torch also with plain autograd), batch scaling, compile time, targets.

    ``progress(line)`` is told each measurement before it starts; ``update(report)``, when given, gets the
    report as measured so far after each one (``bptsb bench`` rewrites its ``--out`` file with it, so a
    killed bench keeps what it measured). The report returned is the last one ``update`` saw.
    """
    min_s = 1.0 if quick else 3.0
    done = update if update is not None else (lambda _report: None)
    report: dict[str, Any] = {
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "cpu_count": mp.cpu_count(), "torch": torch.__version__,
                    "load_average_at_start": list(os.getloadavg())},
        "min_seconds_per_measurement": min_s,
        "published_code_train_steps_per_s": PUBLISHED,
        "workloads": {},
        "batch_scaling": {},
    }
    for name, w in WORKLOADS.items():
        entry: dict[str, Any] = {"description": w.description, "batch": w.batch, "window": w.window}
        report["workloads"][name] = entry
        for backend in BACKENDS:
            progress(f"bench {name} ({backend}) ...")
            entry[backend] = measure_isolated(w, True, min_seconds=min_s, backend=backend)
            done(report)
        if not w.forward_only:
            progress(f"bench {name} (torch, plain autograd) ...")
            entry["torch_autograd"] = measure_isolated(w, False, min_seconds=min_s, backend="torch")
            done(report)
        key = "forward_steps_per_s" if w.forward_only else "train_steps_per_s"
        entry["numba_over_torch"] = _ratio(entry["numba"].get(key), entry["torch"].get(key))
        if name in TASK_WORKLOADS:  # the task's own update, numba path vs its fused episodes
            task_w = replace(w, name=f"{name}_task", task=True)
            for backend in ("numba", "fused"):
                progress(f"bench narma task ({backend}) ...")
                entry[f"task_{backend}"] = measure_isolated(task_w, True, min_seconds=min_s, backend=backend)
                done(report)
            entry["task_fused_over_numba"] = _ratio(entry["task_fused"].get(key), entry["task_numba"].get(key))
        if name in FUSED_WORKLOADS:
            progress(f"bench {name} (fused training path) ...")
            entry["fused"] = measure_isolated(w, True, min_seconds=min_s, backend="fused")
            entry["fused_over_numba"] = _ratio(entry["fused"].get(key), entry["numba"].get(key))
            entry["fused_over_torch"] = _ratio(entry["fused"].get(key), entry["torch"].get(key))
        done(report)
    batches = (1, 64) if quick else (1, 16, 64, 256)
    base = WORKLOADS["lissajous"]
    for b in batches:
        row: dict[str, Any] = {}
        report["batch_scaling"][str(b)] = row
        for backend in BACKENDS:
            progress(f"bench lissajous batch {b} ({backend}) ...")
            w = replace(base, name=f"lissajous_b{b}", batch=b)
            row[backend] = measure_isolated(w, True, min_seconds=min_s, backend=backend).get("train_body_steps_per_s")
            done(report)
        row["numba_over_torch"] = _ratio(row["numba"], row["torch"])
    progress("bench numba first-call time (empty cache, then cached) ...")
    report["numba_first_call"] = measure_compile(min_s)
    done(report)
    wl = report["workloads"]

    def measured(name: str, backend: str, key: str) -> float:
        return wl[name][backend].get(key, math.nan)

    narma = {b: measured("narma", b, "train_steps_per_s") for b in BACKENDS}
    narma.update({f"task_{b}": measured("narma", f"task_{b}", "train_steps_per_s") for b in ("numba", "fused")})
    report["narma_paper_schedule"] = {
        "epochs": NARMA_PAPER_EPOCHS, "steps_per_epoch": NARMA_EPISODE_STEPS,
        "projected_hours": {b: round(NARMA_PAPER_EPOCHS * NARMA_EPISODE_STEPS / v / 3600, 2) if v else None
                            for b, v in narma.items()}}
    targets = {
        "lissajous_train_steps_per_s": (40_000, measured("lissajous", "numba", "train_steps_per_s")),
        "narma_train_steps_per_s": (30_000, narma["numba"]),
        "sweep_forward_body_steps_per_s": (1_000_000, measured("sweep", "numba", "forward_body_steps_per_s")),
    }
    from bptsb_ros.bench import mnist_speed as bench_mnist

    progress("bench mnist (every MNIST system, batch 50; paper-schedule estimate) ...")
    report["mnist"] = bench_mnist.run_isolated(quick)
    done(report)
    mnist_rates = [m["train_images_per_s"] for m in report["mnist"].get("systems", {}).values()]
    targets["mnist_slowest_system_train_images_per_s"] = (round(bench_mnist.TARGET_TRAIN_IMAGES_PER_S, 1),
                                                          min(mnist_rates) if mnist_rates else math.nan)
    from bptsb_ros.bench import gang_speed as bench_gang

    progress("bench memory-task trainings alone, as a gang and as a population (paper-schedule estimate) ...")
    report["memory_task_gang"] = bench_gang.run_isolated(quick)
    done(report)
    paper_h = report["memory_task_gang"].get("paper_memory_task", {}).get("populations_h", math.nan)
    narma_ratio = wl["narma"].get("task_fused_over_numba")
    targets["narma_task_fused_over_numba_train"] = (NARMA_FUSED_TARGET_RATIO,
                                                    math.nan if narma_ratio is None else narma_ratio)
    fused_ratio = wl["lissajous"].get("fused_over_numba")
    targets["lissajous_fused_over_numba_train"] = (FUSED_TARGET_RATIO,
                                                   math.nan if fused_ratio is None else fused_ratio)
    report["targets"] = {k: {"target": t, "measured": m, "met": bool(m >= t)} for k, (t, m) in targets.items()}
    report["targets"]["memory_task_paper_hours_as_populations"] = {
        "target_at_most": MEMORY_TASK_TARGET_H, "measured": paper_h, "met": bool(paper_h <= MEMORY_TASK_TARGET_H)}
    rss = {n: (e["numba"].get("peak_rss_mib", math.nan), e["torch"].get("peak_rss_mib", math.nan))
           for n, e in wl.items()}
    report["targets"]["peak_rss_not_above_torch"] = {
        "per_workload_mib_numba_torch": rss, "met": all(a <= b for a, b in rss.values())}
    report["ipc"] = _ipc_entry(quick, progress)
    done(report)
    return report


def _ipc_entry(quick: bool, progress) -> dict[str, Any]:
    """IPC of 17 masses × 2 axes and of a 34-unit tanh reservoir, degree ≤ 3, delay ≤ 20, 3,000 samples, 1,000
    surrogates per degree tuple (200 with --quick); the reference definition and the orthogonalised variant."""
    from bptsb_ros.analysis.ipc import benchmark_ipc

    progress("bench ipc ...")
    return benchmark_ipc(surrogates=200 if quick else 1000)


def workload_table(report: dict[str, Any]) -> str:
    """A Markdown table of the report (for the docs): one row per workload and backend (fused: Lissajous only; its
ratio column is fused / torch, with fused / numba beside it; NARMA also the task's own update, ``task_numba``
and ``task_fused``, training only)."""
    rows = ["| workload | batch | backend | forward steps/s | train steps/s | train steps/s (plain autograd) "
            "| numba / torch | peak RSS MiB |",
            "|---|---|---|---|---|---|---|---|"]
    for name, e in report["workloads"].items():
        for backend in (*BACKENDS, "fused", "task_numba", "task_fused"):
            if backend not in e:
                continue
            m = e[backend]
            autograd = e.get("torch_autograd", {}).get("train_steps_per_s", "–") if backend == "torch" else "–"
            fused_ratio = f"{e.get('fused_over_torch')} (fused / numba {e.get('fused_over_numba')})"
            ratio = {"numba": e["numba_over_torch"], "fused": fused_ratio,
                     "task_fused": f"task fused / task numba {e.get('task_fused_over_numba')}"}.get(backend, "")
            fwd = m.get("forward_steps_per_s", m.get("error", "–"))
            if e["batch"] > 1 and "forward_body_steps_per_s" in m:
                fwd = f"{fwd} ({m['forward_body_steps_per_s']:.3g} body-steps/s)"
            rows.append(f"| {name} | {e['batch']} | {backend} | {fwd} | {m.get('train_steps_per_s', '–')} | "
                        f"{autograd} | {ratio} | {m.get('peak_rss_mib')} |")
    return "\n".join(rows)


__all__ = ["WORKLOADS", "Workload", "fused_runner", "measure_compile", "measure_isolated", "run_benchmarks",
           "workload_table"]
