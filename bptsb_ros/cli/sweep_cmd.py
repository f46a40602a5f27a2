"""`bptsb sweep`: train one config over many seeds, locally or on a Dask cluster, resumable."""

from __future__ import annotations

import argparse
import sys

NAME = "sweep"
HELP = ("Train CONFIG once per seed as independent jobs (local process pool, or a Dask distributed cluster with "
        "--scheduler); each job in OUT/jobs/seed-N; a rerun skips finished jobs; writes OUT/sweep.json and sweep.csv.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", help="experiment YAML (as for bptsb train)")
    parser.add_argument("--seeds", required=True, help="seeds: 0-19, or 0,3,5-7")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="config override for every job (repeatable), e.g. --set sim_time=100")
    parser.add_argument("--out", required=True, help="sweep directory")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None,
                       help="local worker processes (default: the CPUs available; 0: run in this process)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="Dask distributed scheduler, tcp://HOST:PORT or HOST:PORT, e.g. tcp://10.0.0.5:8786 "
                            "(workers must see --out)")
    parser.add_argument("--connect-timeout", type=_timeout, default=None, metavar="SECONDS",
                        help="give up on the --scheduler after this many seconds (default 20)")
    parser.add_argument("--gang", type=int, default=None, metavar="N",
                        help="run the seeds N at a time as one gang: one process, a thread per training, their "
                             "NARMA / memory-task episodes one batched simulation (same numbers; speed: docs, Speed)")


def _timeout(text: str) -> float:
    from bptsb_ros.cli.options import finite_float

    value = finite_float(text)
    if not 0 < value <= 3600:
        raise argparse.ArgumentTypeError(f"must be in (0, 3600] seconds, got {text[:40]!r}")
    return value


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.cli.options import USAGE, config_error_code, fail
    from bptsb_ros.config import ConfigError, load_config
    from bptsb_ros.files.run_dir_lock import RunDirLocked
    from bptsb_ros.jobs.dask_cluster import scheduler_address
    from bptsb_ros.jobs.sweep import (
        DEFAULT_CONNECT_TIMEOUT,
        SchedulerError,
        SweepError,
        parse_seeds,
        run_sweep,
        train_jobs,
    )

    try:  # the arguments: --seeds, --workers, --scheduler, --connect-timeout
        seeds = parse_seeds(args.seeds)
        if args.workers is not None and args.workers < 0:
            raise SweepError(f"--workers must be >= 0, got {args.workers}")
        if args.connect_timeout is not None and args.scheduler is None:
            raise SweepError("--connect-timeout applies to --scheduler only")
        if args.gang is not None and args.gang < 1:
            raise SweepError(f"--gang must be >= 1 trainings, got {args.gang}")
        scheduler = scheduler_address(args.scheduler) if args.scheduler is not None else None
    except SweepError as err:
        return fail(NAME, err, USAGE)
    try:
        load_config(args.config, args.overrides, seeds[0])  # a bad config fails here, once, not in every job
    except ConfigError as err:  # the file's fault (1), or the --set arguments' (2)
        return fail(NAME, err, config_error_code(args.config, args.overrides, seeds[0]))
    try:
        jobs = train_jobs(args.config, seeds, args.overrides)
        last = [""]

        def show(p) -> None:
            line = p.line()
            if line != last[0]:
                print(line, file=sys.stderr, flush=True)
                last[0] = line

        result = run_sweep(jobs, args.out, workers=args.workers, scheduler=scheduler, progress=show,
                           connect_timeout=args.connect_timeout or DEFAULT_CONNECT_TIMEOUT, gang=args.gang)
    except (SchedulerError, RunDirLocked, SweepError, ConfigError, OSError) as err:  # the arguments were fine
        return fail(NAME, err)
    if result.skipped:
        print(f"skipped {len(result.skipped)} finished job(s): {', '.join(result.skipped)}", file=sys.stderr)
    for rec in result.failed:
        print(f"FAILED {rec['name']}: {rec.get('error')}", file=sys.stderr)
    print(f"{args.out}/sweep.json, {args.out}/sweep.csv: {len(result.records) - len(result.failed)} done, "
          f"{len(result.failed)} failed")
    return 1 if result.failed else 0
