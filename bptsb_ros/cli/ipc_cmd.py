"""`bptsb ipc`: information processing capacity of states driven by an i.i.d. input."""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

NAME = "ipc"
HELP = ("Information processing capacity (Dambre et al. 2012) of states driven by an i.i.d. input: from an .npz "
        "(u (T,) in [-1, 1], states (T, N) or (T,)) or from a recorded live NARMA/memory bag (input from task/input, "
        "states from body/positions: the output CMP y, every movable mass's x and y, and all of them). Writes "
        "ipc.json (every basis function's capacity, totals per degree, total, rank) and ipc.png (bars stacked by "
        "degree, shaded by delay).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--input", help=".npz with u (T,) in [-1, 1] and states (T, N) or (T,)")
    src.add_argument("--bag", help="bag directory of a live NARMA/memory run (u in [0, 1] is mapped to [-1, 1])")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--max-degree", type=int, default=3)
    parser.add_argument("--max-delay", type=int, default=20, help="longest input delay [task steps]")
    parser.add_argument("--washout", type=int, default=100, help="samples discarded at the start")
    parser.add_argument("--min-delay", type=int, default=0, help="shortest input delay [task steps]")
    parser.add_argument("--surrogates", type=int, default=1000,
                        help="shuffled-input surrogates per degree tuple for the threshold")
    parser.add_argument("--threshold", choices=("tuple-max", "none"), default="tuple-max",
                        help="tuple-max: keep a capacity above the largest surrogate capacity of its degree tuple "
                             "(e.g. (2, 1)) times --threshold-scale; none: raw capacities")
    parser.add_argument("--threshold-scale", type=float, default=1.0, help="factor on the surrogate maximum")
    parser.add_argument("--no-rank-cap", dest="rank_cap", action="store_false",
                        help="do not drop the smallest capacities while the total exceeds the rank")
    parser.add_argument("--orthogonalise-linear", action="store_true",
                        help="a linearity test, not the reference's definition: make the degree >= 2 functions "
                             "orthogonal in-sample to the degree-1 ones first (a linear system then has none)")
    parser.add_argument("--per-column", action="store_true",
                        help="--input: also the IPC of every state column on its own")
    parser.add_argument("--tau", type=int, default=0, help="--bag: steps per input (default: inferred)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the surrogate permutations")


#: most basis functions (all degrees together) a run may ask for; the default basis (degree 3, delay 20) has 2,023
MAX_BASIS_FUNCTIONS = 100_000
#: most bytes of the largest degree's basis matrix (functions × samples × 8); the default is ~32 MB at 2,000 samples
MAX_BASIS_BYTES = 4 * 2**30


def basis_size(max_degree: int, max_delay: int) -> list[int]:
    """Number of basis functions of each degree n = 1..max_degree over delays 0..max_delay, in closed form.

    A function of degree n with k factors picks k distinct delays of the D + 1 (C(D+1, k) ways) and splits n
    into k positive orders in delay order (C(n−1, k−1) compositions): F_n = Σ_k C(D+1, k)·C(n−1, k−1).
    """
    return [sum(math.comb(max_delay + 1, k) * math.comb(n - 1, k - 1) for k in range(1, n + 1))
            for n in range(1, max_degree + 1)]


def _check_basis(max_degree: int, max_delay: int, samples: int | None = None) -> None:
    """Refuse a basis too large to compute (IPCError naming its size) before any work is done."""
    from bptsb_ros.analysis.ipc import IPCError

    if max_degree < 1 or max_delay < 0:
        return  # ipc_groups names these
    sizes = basis_size(max_degree, max_delay)
    total = sum(sizes)
    if total > MAX_BASIS_FUNCTIONS:
        shown = f"{total:,}" if total < 10**12 else f"{total:.3e}"
        raise IPCError(f"--max-degree {max_degree} --max-delay {max_delay} is a basis of {shown} functions, "
                       f"more than the maximum of {MAX_BASIS_FUNCTIONS:,}; lower --max-degree or --max-delay")
    if samples is not None and samples > 0 and max(sizes) * samples * 8 > MAX_BASIS_BYTES:
        raise IPCError(f"--max-degree {max_degree} --max-delay {max_delay}: the degree-{sizes.index(max(sizes)) + 1}"
                       f" basis ({max(sizes):,} functions × {samples:,} samples) needs "
                       f"{max(sizes) * samples * 8 / 2**30:.1f} GiB, more than the maximum of "
                       f"{MAX_BASIS_BYTES / 2**30:.0f} GiB; lower --max-degree or --max-delay or use fewer samples")


def _option_problem(args: argparse.Namespace) -> str | None:
    """Why the option values cannot make an IPC run (checked before any file is read), or None."""
    if args.max_degree < 1:
        return f"--max-degree must be >= 1, got {args.max_degree}"
    for name in ("max_delay", "min_delay", "washout", "surrogates", "tau"):
        if getattr(args, name) < 0:
            return f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}"
    if args.min_delay > args.max_delay:
        return f"--min-delay ({args.min_delay}) must not exceed --max-delay ({args.max_delay})"
    if args.threshold != "none" and args.surrogates < 1:
        return f"--threshold {args.threshold} needs --surrogates >= 1"
    if not (math.isfinite(args.threshold_scale) and args.threshold_scale >= 0):
        return f"--threshold-scale must be a finite number >= 0, got {args.threshold_scale}"
    return None


def _check_out(out: Path) -> str | None:
    """Why ``out`` cannot become the output directory (checked before computing), or None when it can."""
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        return f"{existing} is not a directory"
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        return f"{existing} is not writable ({err.strerror or err})"
    return None


def _from_npz(path: str, per_column: bool):
    import numpy as np

    from bptsb_ros.analysis.ipc import IPCError
    from bptsb_ros.files.npz import NpzError, load_npz

    try:
        arrays = load_npz(path, ("u", "states"))
    except NpzError as err:
        raise IPCError(str(err)) from None
    for name, array in arrays.items():
        if array.dtype.kind not in "biuf":
            raise IPCError(f"{path}: array {name!r} must be real numbers, got dtype {array.dtype}")
    u, states = np.asarray(arrays["u"], float), np.asarray(arrays["states"], float)
    groups, labels = [states], ["states"]
    if per_column and states.ndim == 2:
        groups += [states[:, i] for i in range(states.shape[1])]
        labels += [f"column {i}" for i in range(states.shape[1])]
    return u, groups, labels


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.ipc import IPCError, bag_series, ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.plots import plot_ipc_bars
    from bptsb_ros.bags.errors import BagError
    from bptsb_ros.cli.options import USAGE, fail

    problem = _option_problem(args)
    try:
        _check_basis(args.max_degree, args.max_delay)  # the basis the options ask for is too large to compute
    except IPCError as err:
        problem = problem or str(err)
    if problem is not None:
        return fail(NAME, problem, USAGE)
    out = Path(args.out)
    problem = _check_out(out)
    if problem is not None:
        return fail(NAME, f"cannot write --out {out}: {problem}")
    try:
        if args.input:
            u, groups, labels = _from_npz(args.input, args.per_column)
        else:
            series = bag_series(args.bag, args.tau or None)
            u = to_unit_interval(series.u)
            groups, labels = mass_groups(series.positions, series.movable, series.cmp_index)
        if getattr(u, "ndim", 0) == 1:  # other shapes: ipc_groups names them
            _check_basis(args.max_degree, args.max_delay, len(u) - max(args.washout, args.max_delay))
        res = ipc_groups(u, groups, labels, max_degree=args.max_degree, max_delay=args.max_delay,
                         min_delay=args.min_delay, washout=args.washout, surrogates=args.surrogates,
                         threshold=args.threshold, threshold_scale=args.threshold_scale, rank_cap=args.rank_cap,
                         orthogonalise_linear=args.orthogonalise_linear, seed=args.seed, progress=True)
    except (IPCError, BagError) as err:  # the .npz's or the bag's contents (too short, wrong shapes, too large)
        return fail(NAME, err)
    data = res.to_json()
    data["source"] = {"input": args.input, "bag": args.bag}
    if args.bag:
        data["source"]["tau"] = series.tau
    import json

    from bptsb_ros.files.safe_write import UnsafeFileError, write_atomic

    shown = [lab for lab in res.labels if not lab.startswith("all ")] if args.bag else res.labels
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_atomic(out / "ipc.json", json.dumps(data))
        plot_ipc_bars(out / "ipc.png", res, shown, title=f"IPC of {args.bag or args.input}")
    except UnsafeFileError as err:  # a link or a device planted where a result goes
        return fail(NAME, f"cannot write --out: {err}")
    except OSError as err:  # --out was checked before computing; it changed since
        return fail(NAME, f"cannot write --out {out}: {err.strerror or err}")
    for s in res.summary():
        degrees = ", ".join(f"deg {n}: {c:.3f}" for n, c in s["by_degree"].items())
        print(f"{s['label']}: total {s['total']:.3f} (rank {s['rank']}; {degrees})")
    print(f"wrote {out / 'ipc.json'} and {out / 'ipc.png'}")
    return 0
