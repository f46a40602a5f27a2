"""`bptsb ipc`: information processing capacity of states driven by an i.i.d. input."""

from __future__ import annotations

import argparse
import sys
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


def _from_npz(path: str, per_column: bool):
    import numpy as np

    from bptsb_ros.analysis.ipc import IPCError

    try:
        with np.load(path, allow_pickle=False) as data:
            if "u" not in data or "states" not in data:
                raise IPCError(f"{path} must hold arrays 'u' and 'states', has {', '.join(data.files) or 'none'}")
            u, states = np.asarray(data["u"], float), np.asarray(data["states"], float)
    except (OSError, ValueError) as err:
        if isinstance(err, IPCError):
            raise
        raise IPCError(f"cannot read {path} as .npz: {err}") from None
    groups, labels = [states], ["states"]
    if per_column and states.ndim == 2:
        groups += [states[:, i] for i in range(states.shape[1])]
        labels += [f"column {i}" for i in range(states.shape[1])]
    return u, groups, labels


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.ipc import IPCError, bag_series, ipc_groups, mass_groups, to_unit_interval
    from bptsb_ros.analysis.plots import plot_ipc_bars
    from bptsb_ros.bags.errors import BagError

    try:
        if args.input:
            u, groups, labels = _from_npz(args.input, args.per_column)
        else:
            series = bag_series(args.bag, args.tau or None)
            u = to_unit_interval(series.u)
            groups, labels = mass_groups(series.positions, series.movable, series.cmp_index)
        res = ipc_groups(u, groups, labels, max_degree=args.max_degree, max_delay=args.max_delay,
                         min_delay=args.min_delay, washout=args.washout, surrogates=args.surrogates,
                         threshold=args.threshold, threshold_scale=args.threshold_scale, rank_cap=args.rank_cap,
                         orthogonalise_linear=args.orthogonalise_linear, seed=args.seed, progress=True)
    except (IPCError, BagError) as err:
        print(f"bptsb ipc: {err}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = res.to_json()
    data["source"] = {"input": args.input, "bag": args.bag}
    if args.bag:
        data["source"]["tau"] = series.tau
    import json

    (out / "ipc.json").write_text(json.dumps(data))
    shown = [lab for lab in res.labels if not lab.startswith("all ")] if args.bag else res.labels
    plot_ipc_bars(out / "ipc.png", res, shown, title=f"IPC of {args.bag or args.input}")
    for s in res.summary():
        degrees = ", ".join(f"deg {n}: {c:.3f}" for n, c in s["by_degree"].items())
        print(f"{s['label']}: total {s['total']:.3f} (rank {s['rank']}; {degrees})")
    print(f"wrote {out / 'ipc.json'} and {out / 'ipc.png'}")
    return 0
