"""`bptsb reproduce`: run one of the paper's experiments and write its result.json."""

from __future__ import annotations

import argparse
import json
import sys

NAME = "reproduce"
HELP = ("Reproduce one experiment of the paper (--list names them): train, evaluate, compare with the paper's "
        "numbers and claims; writes DIR/result.json and figures.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", nargs="?", help="experiment name (see --list)")
    parser.add_argument("--list", action="store_true",
                        help="a table of every experiment: its measured time at each scale and the paper figure it "
                             "reproduces")
    parser.add_argument("--scale", choices=("smoke", "short", "paper"), default="short",
                        help="smoke: seconds (tests); short: minutes on 2 cores; paper: the paper's settings")
    seed = parser.add_mutually_exclusive_group()
    seed.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    seed.add_argument("--seeds", default=None, metavar="LIST",
                      help="one run per seed (e.g. 0-9 or 0,3,5), each in OUT/seed-N/, then OUT/result.json with "
                           "every row's mean, sd and range and every claim's verdict over the seeds (k of n)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                        help="override one of the experiment's settings at this scale (repeatable; the value is "
                             "YAML, checked as the setting's type; --show-config lists them)")
    parser.add_argument("--show-config", action="store_true",
                        help="print the experiment's settings at --scale (with --set applied) and exit")
    parser.add_argument("--out", default=None, help="run directory (default runs/reproduce/NAME)")
    what = parser.add_mutually_exclusive_group()
    what.add_argument("--force", action="store_true", help="replace an existing result.json in --out")
    what.add_argument("--resume", action="store_true",
                      help="continue an unfinished run in --out (no result.json): trainings that are jobs keep what "
                           "finished (the sweep resumes); the rest runs again; with --seeds, finished seeds are kept "
                           "(more seeds extend a finished run)")
    what.add_argument("--rejudge", action="store_true",
                      help="train nothing: judge the claims of the finished run in --out again with this version's "
                           "claim code, from the numbers it stored, and rewrite its result.json")
    parser.add_argument("--data", default=None,
                        help="data directory for experiments that read a data set (MNIST: the IDX files; "
                             "default $BPTSB_MNIST_DIR)")
    parser.add_argument("--split", default="auto", choices=("auto", "paper", "test-8k-2k"),
                        help="MNIST split: paper = 60k train / 10k test; test-8k-2k = the first 8,000 / last "
                             "2,000 images of the test set; auto (default) = paper when the training files "
                             "exist, else test-8k-2k")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars and no phase lines")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None,
                       help="the experiment's independent trainings: N local worker processes, 0: this process "
                            "(default: the CPUs; --scale smoke: this process)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="... or the Dask distributed scheduler to run them on (tcp://HOST:8786)")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.cli.options import USAGE, fail
    from bptsb_ros.config import ConfigError
    from bptsb_ros.data.mnist import MnistError
    from bptsb_ros.experiments import ExperimentError, experiments, get_experiment, run_experiment
    from bptsb_ros.experiments.experiment_settings import SettingsError, resolve_settings
    from bptsb_ros.experiments.result import ResultError, claim_mark
    from bptsb_ros.experiments.seed_dirs import SeedsError, parse_seeds
    from bptsb_ros.experiments.seeds import run_seeds
    from bptsb_ros.files.run_dir_lock import RunDirLocked
    from bptsb_ros.jobs.dask_cluster import scheduler_address
    from bptsb_ros.jobs.runner import JobFailed
    from bptsb_ros.jobs.sweep import SchedulerError, SweepError

    if args.list:
        from bptsb_ros.experiments.durations import durations, reproduce_table, seed_plan

        rows = ((e.name, e.paper_ref, e.parallel) for e in experiments().values())
        print("\n".join(reproduce_table(rows, durations(), seed_plan())))
        print("Wall times measured on 2 CPU cores (bptsb_ros/experiments/durations.yaml says when and how); "
              "paper × seeds: bptsb reproduce NAME --scale paper --seeds 0-(seeds-1) --workers 2 "
              "(and the entry's args there). "
              "bptsb reproduce NAME --show-config --scale SCALE shows what a scale runs.")
        return 0
    if not args.name:
        return fail(NAME, "name an experiment (bptsb reproduce --list)", USAGE)
    try:  # the arguments: the experiment's name, --set, --workers, --scheduler
        exp = get_experiment(args.name)
        settings = resolve_settings(exp.name, args.scale, args.settings)
        if args.workers is not None and args.workers < 0:
            raise ExperimentError(f"--workers must be a whole number >= 0 (0: in this process), "
                                  f"got {args.workers}")
        scheduler = scheduler_address(args.scheduler) if args.scheduler is not None else None
    except (ExperimentError, SettingsError, SweepError) as err:
        return fail(NAME, err, USAGE)
    if args.show_config:
        print(settings.show(), end="")
        return 0
    if args.rejudge:
        return _rejudge(args)
    try:
        if args.seeds is not None:
            path, result = run_seeds(args.name, parse_seeds(args.seeds), scale=args.scale, out_dir=args.out,
                                     force=args.force, resume=args.resume, progress=not args.no_progress,
                                     workers=args.workers, scheduler=scheduler, data_dir=args.data,
                                     split=args.split, settings=args.settings)
            _print_aggregate(result, path)
            return 0
        path, result = run_experiment(args.name, scale=args.scale, seed=args.seed or 0, out_dir=args.out,
                                      force=args.force, resume=args.resume, progress=not args.no_progress,
                                      workers=args.workers, scheduler=scheduler, data_dir=args.data,
                                      split=args.split, settings=args.settings)
    except (SchedulerError, RunDirLocked, JobFailed, ExperimentError, SettingsError, ConfigError, SweepError,
            MnistError, SeedsError, ResultError, OSError) as err:  # the arguments were fine: --out, data, ...
        hint = "" if isinstance(err, (RunDirLocked, ExperimentError)) else _unfinished_hint(args)  # refused up front
        return fail(NAME, f"{err}{hint}")
    except (RuntimeError, ValueError) as err:  # raised by an experiment's own code: failed jobs, a bad setting
        return fail(NAME, f"{args.name} failed: {err}{_unfinished_hint(args)}")
    print("\n".join(summary_table(result["rows"])))
    for claim in result["claims"]:
        print(f"{claim_mark(claim['holds'])} {claim['claim']} ({claim['evidence']})")
    print(json.dumps({"result": str(path), "wall_s": result["wall_s"], "figures": result["figures"]}))
    return 0


def _unfinished_hint(args: argparse.Namespace) -> str:
    """What to do with the unfinished run a failed attempt left in its output directory (it made something there:
    a run that failed before that leaves nothing, and the same command runs again as it is); else nothing."""
    from pathlib import Path

    from bptsb_ros.experiments.registry import RUN_MARKER
    from bptsb_ros.experiments.result import RESULT_FILE

    out = Path(args.out) if args.out is not None else Path("runs") / "reproduce" / args.name
    if (out / RUN_MARKER).is_file() and not (out / RESULT_FILE).exists():
        return f"; the unfinished run stays in {out}: add --resume to continue it, or --force to start again"
    return ""


def _cell(value: object) -> str:
    """A number or text of the summary: — where there is none, 4 significant digits, texts whole."""
    if value is None:
        return "—"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    return f"{value:.4g}"


def summary_table(rows: list[dict]) -> list[str]:
    """The rows of a result as an aligned table (system, metric, ours, paper, unit), every text whole."""
    if not rows:
        return []
    head = ("system", "metric", "ours", "paper", "unit")
    body = [(str(r["system"]), str(r["metric"]), _cell(r["ours"]), _cell(r["paper"]), str(r["unit"])) for r in rows]
    widths = [max(len(row[i]) for row in [head, *body]) for i in range(len(head))]
    return ["  ".join(c.rjust(w) if i in (2, 3) else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths))).rstrip()
            for row in [head, *body]]


def _rejudge(args: argparse.Namespace) -> int:
    """``--rejudge``: the claims of the finished run in ``--out`` judged again from its stored numbers."""
    from pathlib import Path

    from bptsb_ros.cli.options import fail
    from bptsb_ros.experiments.result import ResultError
    from bptsb_ros.experiments.seeds import rejudge_run
    from bptsb_ros.files.run_dir_lock import RunDirLocked, hold_run_dir

    out = Path(args.out) if args.out else Path("runs") / "reproduce" / args.name
    if not out.is_dir():
        return fail(NAME, f"--rejudge needs a finished run in --out, and {out} is not a directory")
    try:
        with hold_run_dir(out):
            data = rejudge_run(out)
    except (ResultError, RunDirLocked, OSError) as err:
        return fail(NAME, err)
    if data["experiment"] != args.name:
        print(f"note: {out} holds a run of {data['experiment']}, judged again as such", file=sys.stderr)
    if "seeds" in data:
        _print_aggregate(data, out / "result.json")
    else:
        for claim in data["claims"]:
            print(f"{_mark(claim['holds'])} {claim['claim']} ({claim['evidence']})")
    return 0


def _mark(holds: bool | None) -> str:
    from bptsb_ros.experiments.result import claim_mark

    return claim_mark(holds)


def _print_aggregate(result: dict, path) -> None:
    """An aggregate's rows (mean ± sd, range) and claims (k of n, verdict over seeds), then its path."""
    from bptsb_ros.experiments.result import verdict_mark

    n = len(result["seeds"])
    for row in result["rows"]:
        ours = "—" if row["ours"] is None else (f"{row['ours']:.4g} ± {row['ours_sd']:.2g} "
                                                f"({row['ours_min']:.4g}–{row['ours_max']:.4g}, {row['n']} seeds)")
        paper = "" if row["paper"] is None else f"  paper {row['paper']}"
        print(f"{row['system']} | {row['metric']}: {ours}{paper} {row['unit']}")
    for claim in result["claims"]:
        k, m = claim["holds_in"]
        print(f"{verdict_mark(claim['verdict'])} {k}/{m} of {n} seeds: {claim['claim']}")
    print(json.dumps({"result": str(path), "seeds": result["seeds"], "wall_s": result["wall_s"],
                      "figures": result["figures"]}))
