"""`bptsb bench`: physics throughput and memory of the standard workloads, as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

NAME = "bench"
HELP = ("Benchmark steps/s (forward; forward+backward+update) and peak memory of the standard workloads "
        "(Lissajous, NARMA, locomotion batch 20, MNIST-like batch 100) and batch scaling; writes JSON.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="1 s per measurement and fewer batch sizes")
    parser.add_argument("--out", required=True, help="JSON file to write")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.bench import run_benchmarks, workload_table

    report = run_benchmarks(quick=args.quick, progress=lambda m: print(m, file=sys.stderr, flush=True))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2))
    print(workload_table(report))
    scaling = ", ".join(f"B={b}: {v.get('train_body_steps_per_s')}" for b, v in report["batch_scaling"].items())
    print(f"Lissajous training, body-steps/s by batch size: {scaling}")
    if "ipc" in report:
        print(f"{report['ipc']['workload']}: {report['ipc']['seconds']} s")
    t = report["target"]
    print(f"target ≥ {t['lissajous_train_steps_per_s']} Lissajous training steps/s: measured {t['measured']} "
          f"({'met' if t['met'] else 'NOT met'}); wrote {out}")
    return 0
