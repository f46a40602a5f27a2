"""`bptsb reproduce`: run one of the paper's experiments and write its result.json."""

from __future__ import annotations

import argparse
import json

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
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
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
                           "finished (the sweep resumes); the rest runs again")
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
    from bptsb_ros.cli.common import USAGE, fail
    from bptsb_ros.config import ConfigError
    from bptsb_ros.dask_connect import scheduler_address
    from bptsb_ros.data.mnist import MnistError
    from bptsb_ros.experiments import ExperimentError, experiments, get_experiment, run_experiment
    from bptsb_ros.experiments.experiment_settings import SettingsError, resolve_settings
    from bptsb_ros.experiments.result import claim_mark
    from bptsb_ros.rundir_lock import RunDirLocked
    from bptsb_ros.runner import JobFailed
    from bptsb_ros.sweep import SchedulerError, SweepError

    if args.list:
        from bptsb_ros.experiments.durations import durations, reproduce_table

        print("\n".join(reproduce_table(((e.name, e.paper_ref) for e in experiments().values()), durations())))
        print("Wall times measured on 2 CPU cores (bptsb_ros/experiments/durations.yaml says when and how); "
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
    try:
        path, result = run_experiment(args.name, scale=args.scale, seed=args.seed, out_dir=args.out,
                                      force=args.force, resume=args.resume, progress=not args.no_progress,
                                      workers=args.workers, scheduler=scheduler, data_dir=args.data,
                                      split=args.split, settings=args.settings)
    except (SchedulerError, RunDirLocked, JobFailed, ExperimentError, SettingsError, ConfigError, SweepError,
            MnistError, OSError) as err:  # the arguments were fine: --out, data, training, the scheduler, I/O
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
