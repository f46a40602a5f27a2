"""Profile BPTSB training windows of a bench workload: where the time of one window goes.

    .venv/bin/python scripts/profile_training_window.py [lissajous|narma|locomotion] [numba|torch|fused] [WINDOWS]

Runs the workload of ``bptsb bench`` (float32, one torch thread) for WINDOWS training windows (default 300)
under cProfile after a warm-up, and prints the functions by own time, then the same loop timed by phase
(forward, backward, optimiser) without the profiler, in microseconds per window. ``fused`` (Lissajous only):
the fused training path, whose phases are the window call (forward, loss and gradients) and the update.
"""

from __future__ import annotations

import cProfile
import pstats
import sys
import time

import torch

from bptsb_ros.bench.suite import WORKLOADS, _setup, fused_runner


def fused_main(name: str, windows: int) -> None:
    window, step, state = fused_runner(WORKLOADS[name], torch.float32)
    phases = {"window (forward, loss, gradients)": 0.0, "update": 0.0}

    def loop(n: int, timed: bool = False) -> None:
        nonlocal state
        for _ in range(n):
            t0 = time.perf_counter()
            _loss, state = window(state)
            t1 = time.perf_counter()
            step()
            t2 = time.perf_counter()
            if timed:
                phases["window (forward, loss, gradients)"] += t1 - t0
                phases["update"] += t2 - t1

    loop(5)
    profiler = cProfile.Profile()
    profiler.runcall(loop, windows)
    pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    loop(windows, timed=True)
    total = sum(phases.values())
    print(f"{name} (fused), us per window without the profiler: "
          + ", ".join(f"{k} {v / windows * 1e6:.0f}" for k, v in phases.items())
          + f"; total {total / windows * 1e6:.0f} ({WORKLOADS[name].window * windows / total:.0f} steps/s)")


def main() -> None:
    name = sys.argv[1] if len(sys.argv) > 1 else "lissajous"
    backend = sys.argv[2] if len(sys.argv) > 2 else "numba"
    windows = int(sys.argv[3]) if len(sys.argv) > 3 else 300
    torch.set_num_threads(1)
    if backend == "fused":
        fused_main(name, windows)
        return
    body, opt, state, run_window = _setup(WORKLOADS[name], True, torch.float32, backend)
    phases = {"forward": 0.0, "backward": 0.0, "optimiser": 0.0}

    def loop(n: int, timed: bool = False) -> None:
        nonlocal state
        for _ in range(n):
            t0 = time.perf_counter()
            loss, final = run_window(state)
            t1 = time.perf_counter()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            t2 = time.perf_counter()
            opt.step()
            body.clamp_parameters_()
            t3 = time.perf_counter()
            state = final.detach() if WORKLOADS[name].brain == "swg" else state
            if timed:
                phases["forward"] += t1 - t0
                phases["backward"] += t2 - t1
                phases["optimiser"] += t3 - t2

    loop(5)
    profiler = cProfile.Profile()
    profiler.runcall(loop, windows)
    pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    loop(windows, timed=True)
    total = sum(phases.values())
    print(f"{name} ({backend}), us per window without the profiler: "
          + ", ".join(f"{k} {v / windows * 1e6:.0f}" for k, v in phases.items())
          + f"; total {total / windows * 1e6:.0f} ({WORKLOADS[name].window * windows / total:.0f} steps/s)")


if __name__ == "__main__":
    main()
