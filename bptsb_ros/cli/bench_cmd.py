"""`bptsb bench`: physics throughput and memory of the standard workloads, as JSON."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

NAME = "bench"
HELP = ("Benchmark steps/s (forward; forward+backward+update) and peak memory of the standard workloads "
        "(Lissajous, NARMA, locomotion batch 20, MNIST-like batch 100, forward sweeps batch 1000) on both body "
        "backends (torch, numba), Lissajous training on the fused path, batch scaling and the numba compile time; "
        "MNIST training images/s of every "
        "system of the MNIST experiments and what each experiment costs at the paper's schedule; writes JSON. "
        "With --soak: soak the live recording instead (a realtime and a lockstep recorded run under CPU load; "
        "steps published, messages recorded, drops counted). With --live: steps/s of lockstep live loops while a bag "
        "is recorded, as a ratio to a bare rclpy ping-pong anchor run between them, each step split into recorder "
        "wait, publish, wait for commands and compute, and each node process's CPU per step. With --realtime: "
        "the closed loop at 100 Hz in realtime, idle and with one core kept busy (steps, deadline misses, step "
        "compute time and period jitter from the body's own per-step records, late commands), each condition "
        "followed by a bare rclpy loop on the same schedule and priority (the paced anchor: its misses are the "
        "machine's floor).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from bptsb_ros.interface.params import EXECUTOR, EXECUTORS  # ROS-free

    parser.add_argument("--quick", action="store_true", help="1 s per measurement and fewer batch sizes")
    parser.add_argument("--out", required=True, help="JSON file to write; rewritten after each measurement, with "
                        '"complete": false until the last one (a killed bench keeps what it measured)')
    soak = parser.add_argument_group("--soak: live recording under load (bptsb_ros.bench.soak; runs bptsb launch "
                                     "lissajous_open --bag on this ROS_DOMAIN_ID)")
    soak.add_argument("--soak", action="store_true", help="run the recording soak instead of the physics benchmarks")
    soak.add_argument("--realtime-seconds", type=float, default=None, metavar="S",
                      help="wall seconds of the realtime run (--soak: 0 skips it, default 60; --realtime: of each "
                      "condition, default 600, and as long again for the paced anchor after it unless "
                      "--realtime-anchor-seconds)")
    soak.add_argument("--realtime-busy", type=int, default=1, metavar="N",
                      help="spinning processes during the realtime run (--realtime: of the busy condition; default "
                      "1: one core kept busy)")
    soak.add_argument("--lockstep-seconds", type=float, default=10.0, metavar="S",
                      help="sim seconds of the lockstep run (0: skip it; default 10)")
    soak.add_argument("--lockstep-busy", type=int, default=8, metavar="N",
                      help="spinning processes during the lockstep run (default 8)")
    live = parser.add_argument_group("--live: recorded lockstep loops beside a bare rclpy anchor "
                                     "(bptsb_ros.bench.live; runs bptsb launch <loop> --bag and the anchor on this "
                                     "ROS_DOMAIN_ID)")
    live.add_argument("--live", action="store_true", help="time recorded lockstep live loops instead")
    live.add_argument("--live-loops", default="lissajous_closed,narma", metavar="A,B",
                      help="loops to run, comma-separated (default lissajous_closed,narma)")
    live.add_argument("--live-seconds", type=float, default=10.0, metavar="S",
                      help="sim seconds of each run (default 10)")
    live.add_argument("--live-repeats", type=int, default=1, metavar="N",
                      help="interleaved rounds of one run per loop (default 1)")
    live.add_argument("--live-composed", action="store_true",
                      help="also run each loop composed (bptsb launch --composed: body and brains in one process), "
                           "beside the one-process anchor")
    live.add_argument("--live-recorder-in-body", action="store_true",
                      help="also run each loop with the recorder in the body's process (bptsb launch "
                           "--recorder-in-body), beside the split anchor")
    live.add_argument("--live-param", action="append", default=[], metavar="NODE:NAME:=VALUE",
                      help="a node parameter for every run (bptsb launch --param; repeatable)")
    soak.add_argument("--workdir", default="", metavar="DIR", help="bags, launch logs and timing records of the "
                      "soak, --live or --realtime (default: a new temporary directory, kept)")
    rt = parser.add_argument_group("--realtime: the closed loop at 100 Hz realtime, idle and with --realtime-busy "
                                   "spinning processes (bptsb_ros.bench.realtime; runs bptsb launch lissajous_closed "
                                   "with the example agent on this ROS_DOMAIN_ID)")
    rt.add_argument("--realtime", action="store_true", help="run the realtime bench instead of the physics benchmarks")
    rt.add_argument("--executor", choices=EXECUTORS, default=EXECUTOR.default,
                    help=f"rclpy executor of the body and the brains (their executor parameter; default "
                    f"{EXECUTOR.default}: events where rclpy has it)")
    rt.add_argument("--realtime-factor", type=float, default=0.0, metavar="F",
                    help="also run the loop at F times real time (rate_scale F; 10: 1 kHz wall at dt 0.01 s), idle, "
                    "for --realtime-seconds (the condition 'factor'); default 0: not")
    rt.add_argument("--realtime-anchor-seconds", type=float, default=None, metavar="S",
                    help="after each condition, under the same load, the paced anchor (a bare rclpy tick and pong on "
                    "the loop's schedule, priority and CPUs) for S seconds; default: as long as the condition; "
                    "0: none")
    rt.add_argument("--rt-priority", type=int, default=0, metavar="P",
                    help="run the body's stepping thread under SCHED_FIFO at priority P, 1-99 (its rt_priority "
                    "parameter; needs CAP_SYS_NICE or root); default 0: the normal scheduler")
    rt.add_argument("--cpus", default="", metavar="LIST",
                    help="run the body and its brains on these CPUs (their cpus parameter, taskset -c form: '1', "
                    "'0-1'); default: wherever they start")


def _check_workdir(workdir: Path | None) -> int | None:
    """None, or the exit status after one line where ``--workdir`` exists and is not empty (what is on disk: a
    runtime failure, not a usage error; the bench never writes into another run's files)."""
    from bptsb_ros.cli.options import fail

    if workdir is not None and workdir.exists() and not workdir.is_dir():
        return fail(NAME, f"--workdir {workdir} exists and is not a directory")
    if workdir is not None and workdir.exists() and any(workdir.iterdir()):
        return fail(NAME, f"--workdir {workdir} exists and is not empty")
    return None


def _write(out: Path, report: dict, complete: bool = True) -> int | None:
    """Write ``report`` as JSON to ``out``, with ``"complete"`` first (false while measurements are still to come),
    atomically and only as a regular file (:func:`bptsb_ros.files.safe_write.write_atomic`: a reader or a kill never
    sees half a file, a device or a planted link is never written through); None, or the exit status of a write that
    failed (after one line)."""
    from bptsb_ros.cli.options import fail
    from bptsb_ros.files.safe_write import UnsafeFileError, write_atomic

    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(out, json.dumps({"complete": complete, **report}, indent=2))
    except UnsafeFileError as err:
        return fail(NAME, f"cannot write --out: {err}")
    except OSError as err:
        return fail(NAME, f"cannot write --out {out}: {err.strerror or err}")
    return None


class _WriteFailed(Exception):
    """The --out file could not be rewritten after a measurement; ``code`` is the exit status (one line printed)."""

    def __init__(self, code: int):
        super().__init__(code)
        self.code = code


def _updater(out: Path) -> Callable[[dict], None]:
    """``update(report)`` for a bench's runner: rewrites ``out`` marked incomplete after each measurement (a killed
    bench keeps what it measured); raises :class:`_WriteFailed` when the file cannot be written."""

    def update(report: dict) -> None:
        if (problem := _write(out, report, complete=False)) is not None:
            raise _WriteFailed(problem)

    return update


def _soak(args: argparse.Namespace) -> int:
    import math

    from bptsb_ros.bench.soak import run_soak
    from bptsb_ros.cli.options import USAGE, fail

    if args.realtime_seconds is None:
        args.realtime_seconds = 60.0
    for name in ("realtime_seconds", "lockstep_seconds"):
        value = getattr(args, name)
        if not (math.isfinite(value) and value >= 0):
            return fail(NAME, f"--{name.replace('_', '-')} must be >= 0, got {value}", USAGE)
    if args.realtime_busy < 0 or args.lockstep_busy < 0:
        return fail(NAME, "--realtime-busy and --lockstep-busy must be >= 0", USAGE)
    workdir = Path(args.workdir) if args.workdir else None
    if (problem := _check_workdir(workdir)) is not None:
        return problem
    report = run_soak(args.realtime_seconds, args.lockstep_seconds, args.realtime_busy, args.lockstep_busy, workdir,
                      progress=lambda m: print(m, file=sys.stderr, flush=True))
    if (problem := _write(Path(args.out), report)) is not None:
        return problem
    print(json.dumps(report, indent=2))
    failed = [r for k in ("realtime", "lockstep") if isinstance(r := report.get(k), dict)
              and (r.get("error") or r.get("launch_exit_code"))]
    return 1 if failed else 0


def _live(args: argparse.Namespace) -> int:
    import math

    from bptsb_ros.bench.live import live_table, run_live
    from bptsb_ros.cli.options import USAGE, fail
    from bptsb_ros.live.loops import LOOPS

    loops = tuple(name.strip() for name in args.live_loops.split(",") if name.strip())
    unknown = [name for name in loops if name not in LOOPS]
    if not loops or unknown:
        return fail(NAME, f"--live-loops: unknown loop(s) {', '.join(unknown) or '(none given)'}; choose from "
                    f"{', '.join(LOOPS)}", USAGE)
    if any(LOOPS[name].needs_agent and not name.endswith("_closed") for name in loops):
        return fail(NAME, "--live-loops: mnist_drawing needs an MNIST system and images; not benchmarked", USAGE)
    if not (math.isfinite(args.live_seconds) and args.live_seconds > 0):
        return fail(NAME, f"--live-seconds must be > 0, got {args.live_seconds}", USAGE)
    if args.live_repeats < 1:
        return fail(NAME, f"--live-repeats must be >= 1, got {args.live_repeats}", USAGE)
    workdir = Path(args.workdir) if args.workdir else None
    if (problem := _check_workdir(workdir)) is not None:
        return problem
    report = run_live(loops, args.live_seconds, args.live_repeats, workdir, tuple(args.live_param),
                      progress=lambda m: print(m, file=sys.stderr, flush=True), composed=args.live_composed,
                      recorder_in_body=args.live_recorder_in_body)
    if (problem := _write(Path(args.out), report)) is not None:
        return problem
    print(live_table(report))
    print(f"wrote {args.out}")
    return 1 if any(r.get("error") or r.get("launch_exit_code") for r in report["runs"]) else 0


def _realtime(args: argparse.Namespace) -> int:
    import math

    from bptsb_ros.bench.realtime import example_agent, realtime_table, run_realtime_bench
    from bptsb_ros.cli.options import USAGE, fail

    seconds = 600.0 if args.realtime_seconds is None else args.realtime_seconds
    if not (math.isfinite(seconds) and seconds > 0):
        return fail(NAME, f"--realtime-seconds must be > 0, got {seconds:g}", USAGE)
    if not 0 <= args.rt_priority <= 99:
        return fail(NAME, f"--rt-priority must be in 0..99, got {args.rt_priority}", USAGE)
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.live.scheduling import cpus_text, parse_cpus

    try:
        cpus = cpus_text(parse_cpus(args.cpus, "--cpus"))
    except ParameterError as err:
        return fail(NAME, str(err), USAGE)
    if args.realtime_busy < 1:
        return fail(NAME, f"--realtime-busy must be >= 1 (the busy condition), got {args.realtime_busy}", USAGE)
    if not (math.isfinite(args.realtime_factor) and 0 <= args.realtime_factor <= 1000):
        return fail(NAME, f"--realtime-factor must be in 0..1000, got {args.realtime_factor:g}", USAGE)
    anchor_seconds = seconds if args.realtime_anchor_seconds is None else args.realtime_anchor_seconds
    if not (math.isfinite(anchor_seconds) and anchor_seconds >= 0):
        return fail(NAME, f"--realtime-anchor-seconds must be >= 0, got {anchor_seconds:g}", USAGE)
    workdir = Path(args.workdir) if args.workdir else None
    if (problem := _check_workdir(workdir)) is not None:
        return problem
    if not (example_agent() / "checkpoint.pt").is_file():
        return fail(NAME, f"the example agent {example_agent()} is missing (it ships in the source tree)")
    out = Path(args.out)
    if (problem := _write(out, {}, complete=False)) is not None:  # an unwritable --out fails now, not after the runs
        return problem
    try:
        report = run_realtime_bench(seconds, args.realtime_busy, executor=args.executor, rt_priority=args.rt_priority,
                                    cpus=cpus, workdir=workdir, update=_updater(out),
                                    progress=lambda m: print(m, file=sys.stderr, flush=True),
                                    factor=args.realtime_factor, anchor_seconds=anchor_seconds)
    except _WriteFailed as err:
        return err.code
    if (problem := _write(out, report)) is not None:
        return problem
    print(realtime_table(report))
    print(f"wrote {out}")
    return 1 if any("error" in r or r.get("launch_exit_code") or "error" in r.get("anchor", {})
                    for r in report["conditions"].values()) else 0


def run(args: argparse.Namespace) -> int:
    if args.soak and args.realtime:
        from bptsb_ros.cli.options import USAGE, fail

        return fail(NAME, "--soak and --realtime are two different benches: choose one", USAGE)
    if args.soak:
        return _soak(args)
    if args.live:
        return _live(args)
    if args.realtime:
        return _realtime(args)
    from bptsb_ros.bench.suite import run_benchmarks, workload_table

    out = Path(args.out)
    if (problem := _write(out, {}, complete=False)) is not None:  # an unwritable --out fails now, not at the end
        return problem

    try:
        report = run_benchmarks(quick=args.quick, progress=lambda m: print(m, file=sys.stderr, flush=True),
                                update=_updater(out))
    except _WriteFailed as err:
        return err.code
    if (problem := _write(out, report)) is not None:
        return problem
    print(workload_table(report))
    scaling = "; ".join(f"B={b}: torch {v['torch']}, numba {v['numba']} (×{v['numba_over_torch']})"
                        for b, v in report["batch_scaling"].items())
    print(f"Lissajous training, body-steps/s by batch size: {scaling}")
    if "ipc" in report:
        for row in (report["ipc"], report["ipc"].get("reservoir")):
            if row:
                print(f"{row['workload']}: {row['seconds']} s (orthogonalise_linear: "
                      f"{row.get('seconds_orthogonalise_linear')} s)")
    first = report["numba_first_call"]
    print(f"numba first call (s): empty cache {first['cold_compile']}, cached {first['cached']}")
    sched = report["narma_paper_schedule"]
    print(f"paper's NARMA schedule ({sched['epochs']} epochs × {sched['steps_per_epoch']} steps), projected hours: "
          + ", ".join(f"{b} {h}" for b, h in sched["projected_hours"].items()))
    mnist = report.get("mnist", {})
    if "systems" in mnist:
        from bptsb_ros.bench.mnist_speed import mnist_table

        print(mnist_table(mnist))
        sched = mnist["paper_schedule"]
        print(f"MNIST at the paper's schedule, estimated hours ({sched['workers']} workers; one core): "
              + ", ".join(f"{n} {h['pool_h']} ({h['one_core_h']})" for n, h in sched["hours"].items()
                          if isinstance(h, dict))
              + f"; all five in order {sched['hours']['all_five_in_order_h']} (load average "
              f"{mnist['load_average_at_start'][0]:.1f} → {mnist['load_average_at_end'][0]:.1f})")
    elif mnist:
        print(f"MNIST benchmark failed: {mnist.get('error')}")
    gang = report.get("memory_task_gang", {})
    if "paper_memory_task" in gang:
        est = gang["paper_memory_task"]
        population = (f"{gang['population_ms_per_member_update']} as a population ({gang['population_over_alone']}x)"
                      if "populations_h" in est else f"population failed: {gang.get('population_error')}")
        print(f"memory task: {gang['alone_ms_per_update']} ms per update alone, {gang['gang_ms_per_member_update']} "
              f"ms per member-update in a gang of {gang['members']} ({gang['gang_over_alone']}x), {population}; at "
              f"the paper's schedule on {est['workers']} workers ≈ {est['alone_h']} h alone, {est['gangs_h']} h in "
              f"gangs" + (f", {est['populations_h']} h as populations" if "populations_h" in est else ""))
    elif gang:
        print(f"memory-task gang benchmark failed: {gang.get('error')}")
    for name, t in report["targets"].items():
        if "target" in t:
            print(f"target {name} ≥ {t['target']:g}: measured {t['measured']} ({'met' if t['met'] else 'NOT met'})")
        elif "target_at_most" in t:
            print(f"target {name} ≤ {t['target_at_most']:g}: measured {t['measured']} "
                  f"({'met' if t['met'] else 'NOT met'})")
        else:
            print(f"target {name}: {'met' if t['met'] else 'NOT met'} (numba, torch MiB: "
                  f"{t['per_workload_mib_numba_torch']})")
    print(f"wrote {out}")
    return 0
