"""Sweeps: many independent jobs (trainings of one config over seeds, agents of a population), run in a local
process pool or on a Dask distributed cluster, each in its own run directory, resumable.

A job is a name and a picklable callable ``fn(run_dir: Path) -> dict`` that does its work inside ``run_dir``
and returns a flat mapping of results (numbers and short strings) for the aggregate table. :class:`TrainJob`
is the callable for ``bptsb sweep CONFIG``: train one config with overrides and a seed.

Layout of a sweep directory::

    OUT/jobs/NAME/        one run directory per job (whatever the job writes)
    OUT/jobs/NAME/job.json  {"name", "status": "done"|"failed", "wall_s", "result"|"error"}, written last
    OUT/sweep.json        every job's record, in job order
    OUT/sweep.csv         the same as a table: name, status, wall_s, error, then the result keys

Resuming: a job whose ``job.json`` says ``done`` is skipped and its record reused; failed and unfinished jobs run
again. A job that raises is recorded as failed with its error and traceback; the other jobs go on.

Where jobs run: ``workers`` local processes (``concurrent.futures`` with the ``spawn`` start method,
one torch thread each), or, with ``scheduler="tcp://HOST:8786"``, the workers of an existing Dask distributed
cluster (a lab cluster or SLURM through dask-jobqueue; docs/reproducing.md, "Sweeps"). Cluster workers must import
``bptsb_ros`` and see ``OUT`` on a shared file system.
"""

from __future__ import annotations

import csv
import json
import math
import multiprocessing
import os
import re
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

JOB_FILE = "job.json"
SWEEP_JSON = "sweep.json"
SWEEP_CSV = "sweep.csv"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+-]*$")

JobFn = Callable[[Path], dict[str, Any]]


class SweepError(ValueError):
    """A sweep cannot start (bad job names, bad seeds, unreachable scheduler); one line for the user."""


@dataclass(frozen=True)
class Job:
    """One independent unit of a sweep: ``fn(run_dir)`` does the work and returns its results."""

    name: str
    fn: JobFn


@dataclass(frozen=True)
class Progress:
    """Counts of a running sweep (jobs skipped because already done count as done)."""

    total: int
    done: int
    running: int
    failed: int

    @property
    def waiting(self) -> int:
        return self.total - self.done - self.running - self.failed

    def line(self) -> str:
        return (f"sweep: {self.done}/{self.total} done, {self.running} running, {self.failed} failed, "
                f"{self.waiting} waiting")


@dataclass
class SweepResult:
    """The records of every job, in job order (see the module docstring for their fields)."""

    out_dir: Path
    records: list[dict[str, Any]]
    skipped: list[str] = field(default_factory=list)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.records if r["status"] != "done"]

    def results(self) -> dict[str, dict[str, Any]]:
        """name → result mapping of the jobs that finished."""
        return {r["name"]: r["result"] for r in self.records if r["status"] == "done"}


@dataclass(frozen=True)
class TrainJob:
    """``bptsb train CONFIG --set ... --seed SEED`` as a sweep job; returns the scalar metrics.

    Results: ``seed``, ``updates``, ``loss_last``, ``train_seconds`` and every number of the task's evaluation
    (e.g. ``mean_forward_speed``, ``closed_over_open`` for locomotion).
    """

    config: str
    overrides: tuple[str, ...] = ()
    seed: int = 0

    def __call__(self, run_dir: Path) -> dict[str, Any]:
        from bptsb_ros.config import load_config
        from bptsb_ros.training.trainer import train

        cfg = load_config(self.config, list(self.overrides), self.seed)
        res = train(cfg, run_dir, overwrite=True, progress=False)  # the sweep owns run_dir; a failed job reruns
        out: dict[str, Any] = {"seed": self.seed, "updates": res.metrics["updates"],
                               "loss_last": res.losses[-1] if res.losses else None,
                               "train_seconds": res.metrics["train_seconds"]}
        for key, value in res.metrics.get("evaluation", {}).items():
            if isinstance(value, (bool, int, float)) and not isinstance(value, str):
                out[key] = value
        return out


def parse_seeds(text: str) -> list[int]:
    """``"0-19"``, ``"3"``, ``"0,2,5-7"`` → sorted distinct seeds."""
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise SweepError(f"--seeds {text!r}: {part!r} is not a seed or a range like 0-19")
        lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
        if hi < lo:
            raise SweepError(f"--seeds {text!r}: range {part} runs backwards")
        seeds.update(range(lo, hi + 1))
    return sorted(seeds)


def train_jobs(config: str | Path, seeds: Iterable[int], overrides: Sequence[str] = ()) -> list[Job]:
    """One :class:`TrainJob` per seed, named ``seed-N``."""
    return [Job(f"seed-{s}", TrainJob(str(config), tuple(overrides), int(s))) for s in seeds]


def _jsonable(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy / torch scalars
        return _jsonable(value.item())
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)


def execute_job(job: Job, run_dir: str | Path, torch_threads: int | None = None) -> dict[str, Any]:
    """Run one job in ``run_dir`` and write its ``job.json``; never raises for the job's own errors."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    if torch_threads:
        import torch

        torch.set_num_threads(torch_threads)
    t0 = time.perf_counter()
    try:
        result = job.fn(run_dir)
        if not isinstance(result, dict):
            raise TypeError(f"job {job.name!r} returned {type(result).__name__}, not a dict of results")
        record: dict[str, Any] = {"name": job.name, "status": "done", "wall_s": round(time.perf_counter() - t0, 3),
                                  "result": _jsonable(result)}
    except Exception as err:  # noqa: BLE001 - a failing job is reported, the sweep goes on
        record = {"name": job.name, "status": "failed", "wall_s": round(time.perf_counter() - t0, 3),
                  "error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc()}
    tmp = run_dir / (JOB_FILE + ".tmp")
    tmp.write_text(json.dumps(record, indent=2))
    tmp.replace(run_dir / JOB_FILE)  # atomic: a killed job leaves no half-written record
    return record


def _finished(run_dir: Path) -> dict[str, Any] | None:
    try:
        record = json.loads((run_dir / JOB_FILE).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("status") == "done" else None


def run_sweep(
    jobs: Sequence[Job],
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[Progress], None] | None = None,
    torch_threads: int | None = 1,
    connect_timeout: float = 20.0,
) -> SweepResult:
    """Run every job not already done in ``out_dir``; write ``sweep.json`` and ``sweep.csv``.

    Args:
        jobs: distinct names (letters, digits, ``._=+-``), each the name of its run directory.
        workers: local worker processes (default: the CPUs available); ignored with ``scheduler``.
            ``workers=0`` runs the jobs one after another in this process (debugging).
        scheduler: address of a Dask distributed scheduler (``tcp://HOST:8786``) to run the jobs on.
        progress: called with the counts after every change.
        torch_threads: torch threads per job (1: as many jobs as cores without oversubscription; None: leave).
        connect_timeout: seconds to wait for the Dask scheduler.
    """
    names = [j.name for j in jobs]
    bad = [n for n in names if not _NAME.match(n)]
    if bad:
        raise SweepError(f"job names must be letters, digits and ._=+- (they name directories): {bad[:3]}")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SweepError(f"job names must be distinct; repeated: {dup[:3]}")
    out = Path(out_dir)
    (out / "jobs").mkdir(parents=True, exist_ok=True)
    records: dict[str, dict[str, Any]] = {}
    skipped = []
    for job in jobs:
        prior = _finished(out / "jobs" / job.name)
        if prior is not None:
            records[job.name] = prior
            skipped.append(job.name)
    todo = [j for j in jobs if j.name not in records]
    counts = {"done": len(records), "running": 0, "failed": 0}

    def report(running: int) -> None:
        counts["running"] = running
        if progress is not None:
            progress(Progress(len(jobs), counts["done"], running, counts["failed"]))

    def finish(record: dict[str, Any]) -> None:
        records[record["name"]] = record
        counts["done" if record["status"] == "done" else "failed"] += 1

    report(0)
    if todo:
        if scheduler:
            _run_dask(todo, out, scheduler, connect_timeout, torch_threads, finish, report)
        elif workers == 0:
            for job in todo:
                report(1)
                finish(execute_job(job, out / "jobs" / job.name, torch_threads))
            report(0)
        else:
            _run_pool(todo, out, workers or _cpus(), torch_threads, finish, report)
    ordered = [records[n] for n in names]
    write_tables(out, ordered)
    return SweepResult(out, ordered, skipped)


def _cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _run_pool(todo: list[Job], out: Path, workers: int, threads: int | None,
              finish: Callable[[dict[str, Any]], None], report: Callable[[int], None]) -> None:
    workers = max(1, min(workers, len(todo)))
    ctx = multiprocessing.get_context("spawn")  # no forked torch/ROS state in the workers
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        pending = {pool.submit(execute_job, job, out / "jobs" / job.name, threads): job for job in todo}
        report(min(workers, len(pending)))
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                job = pending.pop(fut)
                try:
                    finish(fut.result())
                except Exception as err:  # noqa: BLE001 - the worker process itself died
                    finish({"name": job.name, "status": "failed", "wall_s": None,
                            "error": f"worker process failed: {type(err).__name__}: {err}"})
            report(min(workers, len(pending)))


def _run_dask(todo: list[Job], out: Path, scheduler: str, timeout: float, threads: int | None,
              finish: Callable[[dict[str, Any]], None], report: Callable[[int], None]) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise SweepError("--scheduler needs the 'distributed' package (pip install distributed)") from None
    try:
        client = Client(scheduler, timeout=f"{timeout}s")
    except (OSError, TimeoutError) as err:
        raise SweepError(f"cannot reach the Dask scheduler at {scheduler}: {err}") from None
    try:
        stamp = time.time_ns()  # fresh task keys: a resumed sweep never reuses an old result held by the cluster
        futures = {client.submit(execute_job, job, str(out / "jobs" / job.name), threads,
                                 key=f"bptsb-{job.name}-{stamp}", pure=False): job for job in todo}

        def running() -> int:
            try:
                return min(len(futures), sum(len(v) for v in client.processing().values()))
            except Exception:  # noqa: BLE001 - counts only
                return 0

        report(running())
        for fut in as_completed(list(futures)):
            job = futures.pop(fut)
            try:
                finish(fut.result())
            except Exception as err:  # noqa: BLE001 - the worker died or the task was lost
                finish({"name": job.name, "status": "failed", "wall_s": None,
                        "error": f"dask task failed: {type(err).__name__}: {err}"})
            report(running())
    finally:
        client.close()


def write_tables(out: str | Path, records: list[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``sweep.json`` (counts and every record) and ``sweep.csv`` (one row per job, results as columns)."""
    out = Path(out)
    summary = {"jobs": len(records), "done": sum(r["status"] == "done" for r in records),
               "failed": [r["name"] for r in records if r["status"] != "done"], "records": records}
    (out / SWEEP_JSON).write_text(json.dumps(summary, indent=2))
    keys: list[str] = []
    for r in records:
        for k, v in (r.get("result") or {}).items():
            if k not in keys and not isinstance(v, (dict, list)):
                keys.append(k)
    with (out / SWEEP_CSV).open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["name", "status", "wall_s", "error", *keys])
        for r in records:
            res = r.get("result") or {}
            writer.writerow([r["name"], r["status"], r.get("wall_s"), r.get("error", ""),
                             *[res.get(k, "") for k in keys]])
    return out / SWEEP_JSON, out / SWEEP_CSV
