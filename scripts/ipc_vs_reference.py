"""This package's IPC beside the reference implementation (K. Inoue's ``ipc-module``, PyPI, Python ≥ 3.12) on the
same input and states: per-degree totals and seconds of each.

The package runs on Python 3.11 and ``ipc-module`` needs 3.12, so the check is three steps in two environments:

    python scripts/ipc_vs_reference.py states STATES.npz                           # package env: input, states
    OMP_NUM_THREADS=1 python scripts/ipc_vs_reference.py ours STATES.npz           # package env
    OMP_NUM_THREADS=1 python3.12 scripts/ipc_vs_reference.py reference STATES.npz  # env with ipc-module

``states`` writes two 34-state systems driven by one i.i.d. input, 3,000 samples: an untrained double-circle body
(N_mov 17, every movable mass's x and y) under LIL forces with each input held τ = 20 steps (the
``msdn-nonlinearity`` body, input scale 20), and a 34-unit tanh reservoir. Any other ``.npz`` with arrays
``u_NAME`` (T,) in [−1, 1] and ``x_NAME`` (T, N) works as well, and so does a trained body's held-out run as
the ``narma-emulation``, ``narma-ipc`` and ``memory-task`` trainings write it (``states_EPOCHS.npz`` in each
training's directory under ``sweep/jobs`` of the run directory). ``ours`` and ``reference`` print one JSON object
per system: the capacity summed per degree (after each definition's surrogate thresholds and rank cap), the rank,
and of ``--repeats`` calls the shortest wall time and the first, in seconds (the first system's first call is the
process's, with its warm-up). Both use degree ≤ 3, delays 0 … 20, 100 discarded samples, 1,000 shuffled-input
surrogates from seed 0 and Legendre polynomials.
"""

from __future__ import annotations

import argparse
import json
import time
import zipfile
from pathlib import Path

import numpy as np

MAX_DEGREE, MAX_DELAY, WASHOUT, SURROGATES, SEED = 3, 20, 100, 1000, 0


def write_states(path: Path, samples: int = 3000) -> None:
    """The body and the reservoir of the module docstring, into ``path``."""
    import torch

    from bptsb_ros.analysis.ipc import mass_groups, tanh_reservoir, to_unit_interval
    from bptsb_ros.experiments.msdn_nonlinearity import TAU, _bodies
    from bptsb_ros.sim.blocks import block_positions

    torch.set_num_threads(1)
    u = np.random.default_rng(SEED).uniform(0.0, 1.0, samples)
    body, forces = _bodies(SEED)["double-circle (N_mov 17)"]
    positions = block_positions(body, forces, (20.0 * u)[None], TAU)[0]  # (T, M, 2)
    groups, labels = mass_groups(positions, body.topology.movable, body.topology.cmp_index)
    ur, xr = tanh_reservoir(samples, 34, SEED)
    np.savez(path, u_body=to_unit_interval(u), x_body=groups[labels.index("all movable x, y")], u_reservoir=ur,
             x_reservoir=xr)


def systems(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{name: (u (T,), x (T, N))} of a states file, or of a time-series job's ``states_<epochs>.npz`` (the
    trained body's held-out run: u in [0, 1] mapped by 2u − 1, x every movable mass's x and y)."""
    data = np.load(path, allow_pickle=False)
    if not isinstance(data, np.lib.npyio.NpzFile):
        raise ValueError("a single array, not an .npz archive")
    with data:
        if "positions" in data.files:
            positions = np.asarray(data["positions"], float)  # (T, M, 2)
            u = 2.0 * np.asarray(data["u"], float) - 1.0
            return {f"{path.parent.name}/{path.stem}": (u, positions.reshape(len(positions), -1))}
        names = sorted(k[2:] for k in data.files if k.startswith("u_") and f"x_{k[2:]}" in data.files)
        return {n: (np.asarray(data[f"u_{n}"], float), np.asarray(data[f"x_{n}"], float)) for n in names}


def check_system(name: str, u: np.ndarray, x: np.ndarray) -> None:
    """Raise ValueError naming what is wrong with one system's input ``u`` and states ``x``."""
    start = max(WASHOUT, MAX_DELAY)
    if u.ndim != 1 or x.ndim != 2 or len(u) != len(x):
        raise ValueError(f"{name}: u must be (T,) and x (T, N) with the same T, got {u.shape} and {x.shape}")
    if len(u) <= start + 1:
        raise ValueError(f"{name}: {len(u)} samples, more than {start + 1} needed")
    if not (np.isfinite(u).all() and np.isfinite(x).all()) or np.abs(u).max() > 1:
        raise ValueError(f"{name}: u must lie in [-1, 1] and u, x be finite")


def timed_calls(repeats: int, compute) -> tuple[list[float], tuple[list[float], int]]:
    """Wall times [s] of ``repeats`` calls of ``compute`` and its last value."""
    times, value = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        value = compute()
        times.append(time.perf_counter() - t0)
    return times, value


def ours(u: np.ndarray, x: np.ndarray) -> tuple[list[float], int]:
    from bptsb_ros.analysis.ipc import ipc

    res = ipc(u, x, max_degree=MAX_DEGREE, max_delay=MAX_DELAY, washout=WASHOUT, surrogates=SURROGATES, seed=SEED)
    return [float(v) for v in res.by_degree()[0]], int(res.rank[0])


def reference(u: np.ndarray, x: np.ndarray) -> tuple[list[float], int]:
    from ipc_module import config
    from ipc_module.profiler import UnivariateProfiler

    config.SHOW_PROGRESS_BAR = False
    profiler = UnivariateProfiler(u[:, None], x, poly_name="Legendre", surrogate_num=SURROGATES,
                                  surrogate_seed=SEED, offset=max(WASHOUT, MAX_DELAY))
    profiler.calc(degree_sum=list(range(1, MAX_DEGREE + 1)), delay_max=MAX_DELAY + 1)  # delays 0 … MAX_DELAY
    frame, rank = profiler.to_dataframe(squeeze=True)
    column = next(c for c in frame.columns if c.startswith("ipc"))
    by_degree = [float(frame.filter(frame["degree"] == n)[column].sum()) for n in range(1, MAX_DEGREE + 1)]
    return by_degree, int(np.asarray(rank).ravel()[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mode", choices=("states", "ours", "reference"))
    parser.add_argument("states", type=Path, help="the .npz of input and states")
    parser.add_argument("--repeats", type=int, default=3, help="calls per system; the shortest is reported")
    args = parser.parse_args()
    if args.mode == "states":
        if args.states.suffix != ".npz" or args.states.exists():
            parser.error(f"{args.states}: give a new file name ending in .npz (an existing file is never replaced)")
        write_states(args.states)
        print(f"wrote {args.states}")
        return
    if args.repeats < 1:
        parser.error(f"--repeats {args.repeats}: give 1 or more")
    try:
        found = systems(args.states)
        for name, (u, x) in found.items():
            check_system(name, u, x)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        parser.error(f"{args.states}: {exc}")
    if not found:
        parser.error(f"{args.states}: no u_NAME/x_NAME pair and no trained job's positions")
    compute = ours if args.mode == "ours" else reference
    for name, (u, x) in found.items():
        times, (by_degree, rank) = timed_calls(args.repeats, lambda u=u, x=x: compute(u, x))
        print(json.dumps({"definition": args.mode, "system": name, "states": x.shape[1], "rank": rank,
                          "by_degree": [round(v, 4) for v in by_degree], "seconds": round(min(times), 3),
                          "first_call_seconds": round(times[0], 3)}))


if __name__ == "__main__":
    main()
