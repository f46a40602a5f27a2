"""Sweeps: many independent jobs (trainings of one config over seeds, agents of a population), run in a local
process pool or on a Dask distributed cluster, each in its own run directory, resumable.

A job is a name and a picklable callable ``fn(run_dir: Path) -> dict`` that does its work inside ``run_dir``
and returns a flat mapping of results (numbers and short strings) for the aggregate table, or, for a job that
runs several trainings at once, a mapping of each training's name to its flat mapping. :class:`TrainJob`
is the callable for ``bptsb sweep CONFIG``: train one config with overrides and a seed.

Layout of a sweep directory::

    OUT/jobs/NAME/        one run directory per job (whatever the job writes)
    OUT/jobs/NAME/job.json  {"name", "key", "status": "done"|"failed", "wall_s", "result"|"error", "files",
                          "ran_on": {"host", "pid", "dask_worker"}},
                          written last
    OUT/sweep.json        every job's record, in job order
    OUT/sweep.csv         the same as a table: name, status, wall_s, error, then the result keys; a job whose
                          result maps trainings to their results (a population) has a row per training,
                          named JOB/TRAINING, with the job's status and wall_s
    OUT/.bptsb.lock       held while a sweep runs there (:mod:`bptsb_ros.files.run_dir_lock`): one sweep per OUT

Resuming: a job whose ``job.json`` is a valid finished record *of this job* is skipped and its record reused:
status ``done``, the job's name, its ``key`` (a hash of what the job is: its callable and arguments, for
:class:`TrainJob` also the config file's content), a number ``wall_s``, a ``result`` mapping, and ``files``
(path → size of every file the job left in its directory) matching the directory now. Any other record is not
trusted: the job runs again (with one line saying why); so does a record whose result does not fit the job
(:func:`result_problem`: another seed, a population's result naming other trainings). Failed and unfinished jobs
run again. A job that raises is recorded as failed with its error and traceback; the other jobs go on. A job that
does not end by itself — its worker process dies, the Dask scheduler goes away, no worker is left — is *lost*
(status ``lost`` in the tables): the sweep finishes the others, writes its tables and raises :class:`JobsLost`
naming them, so no result is ever made of the jobs that did finish alone; running it again runs the lost ones.

Where jobs run (:mod:`bptsb_ros.jobs.runner`, the one runner of the package): ``workers`` local processes
(``concurrent.futures`` with the ``spawn`` start method; 0: this process), or, with
``scheduler="tcp://HOST:8786"``, the workers of an existing Dask distributed cluster (a lab cluster or SLURM
through dask-jobqueue; docs, "Reproducing"). Cluster workers must import ``bptsb_ros`` and see ``OUT`` on a
shared file system. The scheduler address is ``tcp://HOST:PORT`` or ``HOST:PORT``; connecting gives up after
``connect_timeout`` seconds, whatever the other end does (:mod:`bptsb_ros.jobs.dask_cluster`). Inside every job,
local or on the cluster, BLAS/OpenMP and torch run one thread (``threads``), and the record names where the
job ran (``ran_on``).
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import hashlib
import io
import json
import math
import os
import re
import sys
import time
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bptsb_ros.files.run_dir_lock import LOCK_NAME, hold_run_dir
from bptsb_ros.files.safe_write import write_atomic
from bptsb_ros.jobs.runner import JobLost, Placement, RunInfo, close_client, connect_placement, ran_on, run_calls
from bptsb_ros.jobs.sweep_errors import SchedulerError, SweepError  # noqa: F401 - callers import both from here


class JobsLost(SweepError):
    """Jobs of a sweep did not end by themselves (:class:`~bptsb_ros.jobs.runner.JobLost`: a worker died, the Dask
    cluster cancelled or lost them); the sweep's tables record them with status ``lost``, and a rerun runs them."""


JOB_FILE = "job.json"
SWEEP_JSON = "sweep.json"
SWEEP_CSV = "sweep.csv"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._=+-]*$")
MAX_JOBS = 100_000
"""Most seeds one ``--seeds`` may name (a larger sweep is almost surely a typo, and would not fit in memory)."""
MAX_SEED = 2**63 - 1
#: the status of a job that did not end by itself (its worker died, the cluster lost it)
LOST = "lost"
DEFAULT_CONNECT_TIMEOUT = 20.0
"""Seconds to wait for a Dask scheduler to answer (``bptsb sweep --connect-timeout``)."""

JobFn = Callable[[Path], dict[str, Any]]
#: how often a gang of jobs says how far it is [s] (its jobs finish together, at the end)
GANG_REPORT_S = 60.0


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
    #: where the jobs that ran this time ran (None: built by hand)
    info: RunInfo | None = None

    def provenance(self) -> dict[str, Any]:
        """What this sweep used, for a result's provenance: :meth:`RunInfo.to_json` plus the jobs reused."""
        out = self.info.to_json() if self.info is not None else {}
        out["reused"] = len(self.skipped)
        return out

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.records if r["status"] != "done"]

    def results(self) -> dict[str, dict[str, Any]]:
        """name → result mapping of the jobs that finished; a non-finite float, which the JSON records hold as
        the text ``"nan"``, ``"inf"`` or ``"-inf"``, is a float again."""
        return {r["name"]: _from_json(r["result"]) for r in self.records if r["status"] == "done"}


@dataclass(frozen=True)
class TrainJob:
    """``bptsb train CONFIG --set ... --seed SEED`` as a sweep job; returns the scalar metrics.

    Results: ``seed``, ``updates``, ``loss_last``, ``train_seconds`` and every number of the task's evaluation
    (e.g. ``mean_forward_speed``, ``closed_over_open`` for locomotion).
    """

    config: str
    overrides: tuple[str, ...] = ()
    seed: int = 0

    def identity(self) -> dict[str, Any]:
        """What makes this job this job (for :func:`job_key`): the config file's content and its stem (the run's
        default name), the overrides and the seed; not the path spelling (``config/x.yaml`` or an absolute one)."""
        try:
            content = hashlib.sha256(Path(self.config).read_bytes()).hexdigest()
        except OSError:
            content = f"unreadable: {self.config}"
        return {"config_stem": Path(self.config).stem, "config_sha256": content,
                "overrides": list(self.overrides), "seed": self.seed}

    def __call__(self, run_dir: Path) -> dict[str, Any]:
        from bptsb_ros.config import load_config
        from bptsb_ros.workflows.train import train

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
    """``"0-19"``, ``"3"``, ``"0,2,5-7"`` → sorted distinct seeds (ASCII digits; 0 … :data:`MAX_SEED`; at most
    :data:`MAX_JOBS` of them)."""
    seeds: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        m = re.fullmatch(r"([0-9]{1,19})(?:-([0-9]{1,19}))?", part)
        if not m:
            raise SweepError(f"--seeds {text[:60]!r}: {part[:40]!r} is not a seed or a range like 0-19 "
                             f"(digits 0-9, seeds 0 to {MAX_SEED})")
        lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
        if hi > MAX_SEED:
            raise SweepError(f"--seeds {text[:60]!r}: seed {hi} is above the largest, {MAX_SEED}")
        if hi < lo:
            raise SweepError(f"--seeds {text[:60]!r}: range {part} runs backwards")
        if hi - lo + 1 <= MAX_JOBS:  # checked before building anything: 0-9999999999 must not fill the memory
            seeds.update(range(lo, hi + 1))
        if hi - lo + 1 > MAX_JOBS or len(seeds) > MAX_JOBS:
            raise SweepError(f"--seeds {text[:60]!r} names more than {MAX_JOBS:,} seeds (the most one sweep runs)")
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


_NON_FINITE = {"nan": math.nan, "inf": math.inf, "-inf": -math.inf}


def _from_json(value: Any) -> Any:
    """Undo :func:`_jsonable`'s text for non-finite floats, in nested dicts and lists."""
    if isinstance(value, str):
        return _NON_FINITE.get(value, value)
    if isinstance(value, dict):
        return {k: _from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value


def _describe(obj: Any) -> Any:
    """A JSON-able description of a job's callable and its arguments, equal for equal jobs across processes.

    Objects without a stable description (``repr`` with a memory address) make a key that never matches: such
    jobs simply run again on resume.
    """
    if obj is None or isinstance(obj, (bool, int, str)):
        return obj
    if isinstance(obj, float):
        return repr(obj)
    if isinstance(obj, (list, tuple)):
        return [_describe(v) for v in obj]
    if isinstance(obj, dict):
        return [[_describe(k), _describe(v)] for k, v in sorted(obj.items(), key=lambda kv: repr(kv[0]))]
    if isinstance(obj, os.PathLike):
        return {"path": os.fspath(obj)}
    if hasattr(obj, "identity") and callable(obj.identity):
        return {"type": _qualname(type(obj)), "identity": _describe(obj.identity())}
    if isinstance(obj, functools.partial):
        return {"partial": _describe(obj.func), "args": _describe(obj.args), "keywords": _describe(obj.keywords)}
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {"type": _qualname(type(obj)),
                "fields": {f.name: _describe(getattr(obj, f.name)) for f in dataclasses.fields(obj)}}
    if hasattr(obj, "tobytes") and hasattr(obj, "dtype") and hasattr(obj, "shape"):  # numpy arrays
        return {"array": str(obj.dtype), "shape": list(obj.shape), "sha256": hashlib.sha256(obj.tobytes()).hexdigest()}
    if callable(obj) and hasattr(obj, "__qualname__"):
        return {"callable": _qualname(obj)}
    return {"repr": repr(obj)}


def _qualname(obj: Any) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__qualname__)}"


def job_key(job: Job) -> str:
    """SHA-256 (hex) of the job's name and what it runs; a finished record is reused only under the same key."""
    text = json.dumps({"name": job.name, "fn": _describe(job.fn)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


_OWN_FILES = {JOB_FILE, JOB_FILE + ".tmp", LOCK_NAME}


def _manifest(run_dir: Path) -> dict[str, int]:
    """relative path → size in bytes of every regular file under ``run_dir`` but the sweep's own (symlinks not
    followed, not listed)."""
    files: dict[str, int] = {}
    for root, dirs, names in os.walk(run_dir):
        dirs.sort()
        for name in sorted(names):
            path = Path(root, name)
            rel = path.relative_to(run_dir).as_posix()
            if rel in _OWN_FILES or path.is_symlink() or not path.is_file():
                continue
            files[rel] = path.stat().st_size
    return files


def execute_job(job: Job, run_dir: str | Path, key: str | None = None) -> dict[str, Any]:
    """Run one job in ``run_dir`` and write its ``job.json``; never raises for the job's own errors.

    ``key``: :func:`job_key` of ``job`` (computed here if not given; the sweep passes the one it checks against).
    The record names where the job ran (``ran_on``: host, process id, Dask worker address or None). Threads are
    the runner's business (:func:`bptsb_ros.jobs.runner.call_limited` wraps this call).
    """
    run_dir = Path(run_dir)
    key = key if key is not None else job_key(job)
    run_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    try:
        result = job.fn(run_dir)
        if not isinstance(result, dict):
            raise TypeError(f"job {job.name!r} returned {type(result).__name__}, not a dict of results")
        record: dict[str, Any] = {"name": job.name, "key": key, "status": "done",
                                  "wall_s": round(time.perf_counter() - t0, 3), "result": _jsonable(result),
                                  "files": _manifest(run_dir), "ran_on": ran_on()}
    except Exception as err:  # noqa: BLE001 - a failing job is reported, the sweep goes on
        record = {"name": job.name, "key": key, "status": "failed", "wall_s": round(time.perf_counter() - t0, 3),
                  "error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc(), "ran_on": ran_on()}
    write_atomic(run_dir / JOB_FILE, json.dumps(record, indent=2))  # a killed job leaves no half-written record
    return record


def execute_gang(jobs: Sequence[Job], run_dirs: Sequence[str | Path], keys: Sequence[str]) -> list[dict[str, Any]]:
    """Run ``jobs`` as one gang (:mod:`bptsb_ros.jobs.gang`: one thread each, their held-force windows batched), each
    in its run directory as :func:`execute_job` runs it; their records in order."""
    from bptsb_ros.jobs.gang import run_gang

    out = run_gang([functools.partial(execute_job, job, run_dir, key)
                    for job, run_dir, key in zip(jobs, run_dirs, keys)], report_every_s=GANG_REPORT_S)
    return [r if isinstance(r, dict) else {"name": job.name, "key": key, "status": "failed", "wall_s": None,
                                           "error": f"{type(r).__name__}: {r}", "ran_on": ran_on()}
            for job, key, r in zip(jobs, keys, out)]


def gangs_of(count: int, gang: int | None) -> list[range]:
    """The job indices of each call: one job per call when ``gang`` is None or 1, else consecutive runs of
    ``gang`` jobs (the last one shorter)."""
    if gang is not None and (isinstance(gang, bool) or not isinstance(gang, int) or gang < 1):
        raise SweepError(f"a gang is a whole number of jobs >= 1, got {gang!r}")
    size = gang or 1
    return [range(i, min(i + size, count)) for i in range(0, count, size)]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def result_problem(job: Job, result: dict[str, Any]) -> str | None:
    """Why a recorded ``result`` cannot be ``job``'s (None when it can): a job whose callable has a ``seed`` must
    report that seed; one whose callable names its ``members`` (a population of trainings) must give exactly one
    result per member, each with its own seed or ``diverged``; the callable's own ``result_problem(result)``, if it
    has one, is asked too."""
    fn = job.fn
    members = getattr(fn, "members", None)
    if isinstance(members, tuple) and all(isinstance(m, tuple) and len(m) == 2 for m in members):
        names = [str(name) for name, _ in members]
        if sorted(result) != sorted(names):
            extra = sorted(set(result) - set(names))
            what = f"names {extra[0][:40]!r}, not a member" if extra else "lacks a member's result"
            return f"its result {what} of this job ({len(names)} members)"
        for name, member in members:
            value = result[name]
            if not isinstance(value, dict):
                return f"its result of member {name} is not a mapping"
            if "diverged" in value:
                continue
            if value.get("seed") != getattr(member, "seed", value.get("seed")):
                return f"its result of member {name} is of seed {str(value.get('seed'))[:20]}, not {member.seed}"
            check = getattr(member, "result_problem", None)
            problem = check(value) if callable(check) else None
            if problem:
                return f"member {name}: {problem}"
    elif hasattr(fn, "seed") and "seed" in result and result["seed"] != fn.seed:
        return f"its result is of seed {str(result['seed'])[:20]}, not {fn.seed}"
    check = getattr(fn, "result_problem", None)
    return check(result) if callable(check) else None


def finished_record(job: Job, run_dir: Path, key: str) -> tuple[dict[str, Any] | None, str | None]:
    """(the record, None) if ``run_dir/job.json`` is a valid finished record of ``job`` (see the module
    docstring); else (None, why it is not trusted), or (None, None) when there is no record or it says failed."""
    path = run_dir / JOB_FILE
    if not path.exists():
        return None, None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        return None, f"unreadable ({type(err).__name__})"
    if not isinstance(record, dict):
        return None, "not a JSON object"
    if record.get("status") == "failed" and record.get("name") == job.name:
        return None, None
    if record.get("status") != "done":
        return None, f"status {str(record.get('status'))[:20]!r}, not 'done'"
    missing = [k for k in ("name", "key", "wall_s", "result", "files") if k not in record]
    if missing:
        return None, f"missing {', '.join(missing)}"
    if record["name"] != job.name:
        return None, f"it names another job ({str(record['name'])[:40]!r})"
    if record["key"] != key:
        return None, "it is the record of another job (its key differs: other config, overrides or seed)"
    if not _is_number(record["wall_s"]) or record["wall_s"] < 0:
        return None, "wall_s is not a non-negative number"
    if not isinstance(record["result"], dict):
        return None, "result is not a mapping"
    problem = result_problem(job, record["result"])
    if problem:
        return None, problem
    files = record["files"]
    if not isinstance(files, dict) or not all(isinstance(n, int) and not isinstance(n, bool) for n in files.values()):
        return None, "files is not a mapping of sizes"
    now = _manifest(run_dir)  # the record's file names are compared with the listing, never opened
    gone = sorted(set(files) - set(now))
    if gone:
        more = f" (and {len(gone) - 1} more)" if gone[1:] else ""
        return None, f"its result file {gone[0][:60]!r} is missing{more}"
    changed = sorted(n for n in files if now[n] != files[n])
    if changed:
        return None, f"its result file {changed[0][:60]!r} changed size"
    return record, None


def run_sweep(
    jobs: Sequence[Job],
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[Progress], None] | None = None,
    threads: int | None = 1,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
    notice: Callable[[str], None] | None = None,
    gang: int | None = None,
    n_gangs: int | None = None,
    worker_wait_s: float | None = None,
) -> SweepResult:
    """Run every job not already done in ``out_dir``; write ``sweep.json`` and ``sweep.csv``.

    Args:
        jobs: distinct names (letters, digits, ``._=+-``), each the name of its run directory.
        workers: local worker processes (default: the CPUs available); ignored with ``scheduler``.
            ``workers=0`` runs the jobs one after another in this process (debugging).
        scheduler: address of a Dask distributed scheduler (``tcp://HOST:8786``,
            :func:`bptsb_ros.jobs.dask_cluster.scheduler_address`; or
            the ``inproc://`` address of an in-process cluster) to run the jobs on.
        progress: called with the counts after every change.
        threads: BLAS/OpenMP and torch threads inside each job (1: as many jobs as cores without
            oversubscription; None: leave them), for local and Dask workers alike (:mod:`bptsb_ros.jobs.runner`).
        connect_timeout: seconds to wait for the Dask scheduler to answer.
        notice: called with one line per job whose ``job.json`` claims it finished but is not trusted (the job
            runs again); default: printed to stderr.
        gang: run the jobs still to do in runs of this many as one gang each (:mod:`bptsb_ros.jobs.gang`: one process,
            a thread per job, their held-force windows as one batched simulation); None or 1: a process per job.
        n_gangs: instead of ``gang``: split the jobs still to do into this many gangs of consecutive jobs (as many
            as there are workers: one gang each, also when a resumed sweep has fewer jobs left).
        worker_wait_s: on a Dask cluster, how long to wait for a worker (before the first job, and when none is
            left; default :data:`bptsb_ros.jobs.runner.WORKER_WAIT_S`); ``notice`` hears what the sweep waits for.

    Raises:
        SweepError: bad job names or scheduler address (nothing was created).
        SchedulerError: the scheduler did not answer as a Dask scheduler within ``connect_timeout``.
        RunDirLocked: another bptsb process holds ``out_dir`` (:mod:`bptsb_ros.files.run_dir_lock`); nothing was
            touched.
        JobsLost: jobs did not end by themselves (a worker died, the cluster cancelled or lost them); the tables
            are written (those jobs with status ``lost``) and a rerun in ``out_dir`` runs them.
    """
    names = [j.name for j in jobs]
    bad = [n for n in names if not _NAME.match(n)]
    if bad:
        raise SweepError(f"job names must be letters, digits and ._=+- (they name directories): {bad[:3]}")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SweepError(f"job names must be distinct; repeated: {dup[:3]}")
    address = None
    if scheduler:
        from bptsb_ros.jobs.dask_cluster import scheduler_address

        # inproc://: a LocalCluster(processes=False) of this very process (tests, notebooks); never from the CLI
        address = scheduler if scheduler.startswith("inproc://") else scheduler_address(scheduler)
    if not (_is_number(connect_timeout) and connect_timeout > 0):
        raise SweepError(f"the connect timeout must be a positive number of seconds, got {connect_timeout!r}")
    try:  # before the lock: a bad worker count or gang creates nothing
        placement = Placement(workers, scheduler=address)
    except ValueError as err:
        raise SweepError(str(err)) from None
    gangs_of(0, gang)
    gangs_of(0, n_gangs)
    if gang is not None and n_gangs is not None:
        raise SweepError("give the gangs' size or their number, not both")
    out = Path(out_dir)
    with hold_run_dir(out):
        keys = {job.name: job_key(job) for job in jobs}
        records: dict[str, dict[str, Any]] = {}
        skipped = []
        for job in jobs:
            prior, why = finished_record(job, out / "jobs" / job.name, keys[job.name])
            if prior is not None:
                records[job.name] = prior
                skipped.append(job.name)
            elif why is not None:
                line = f"{job.name}: {out / 'jobs' / job.name / JOB_FILE} is not trusted ({why}); running the job again"
                if notice is not None:
                    notice(line)
                else:
                    print(line, file=sys.stderr, flush=True)
        todo = [j for j in jobs if j.name not in records]
        client = connect_placement(placement, connect_timeout) if address and todo else None
        try:
            (out / "jobs").mkdir(exist_ok=True)
            counts = {"done": len(records), "running": 0, "failed": 0}

            if n_gangs is not None:
                gang = max(1, -(-len(todo) // n_gangs))
            groups = gangs_of(len(todo), gang)

            def report(running: int) -> None:  # running calls; a call runs a gang's jobs at once
                left = len(jobs) - counts["done"] - counts["failed"]
                counts["running"] = min(left, running * (gang or 1))
                if progress is not None:
                    progress(Progress(len(jobs), counts["done"], counts["running"], counts["failed"]))

            def finish(i: int, record: Any, where: dict[str, Any] | None, error: BaseException | None) -> None:
                members = [todo[j] for j in groups[i]]
                if error is not None:  # execute_job raises only where its record cannot be written
                    status = LOST if isinstance(error, JobLost) else "failed"
                    record = [{"name": job.name, "status": status, "wall_s": None,
                               "error": f"{'lost' if status == LOST else 'worker failed'}: {type(error).__name__}: "
                                        f"{error}"} for job in members]
                for job, rec in zip(members, record if isinstance(record, list) else [record]):
                    records[job.name] = rec
                    counts["done" if rec["status"] == "done" else "failed"] += 1

            report(0)
            calls = []
            for group in groups:
                members = [todo[j] for j in group]
                dirs = [str(out / "jobs" / job.name) for job in members]
                if gang is None or gang == 1:
                    calls.append((members[0].name, execute_job, (members[0], dirs[0], keys[members[0].name])))
                else:
                    calls.append((f"gang of {len(members)} from {members[0].name}", execute_gang,
                                  (members, dirs, [keys[job.name] for job in members])))
            info = run_calls(calls, placement, threads=threads, client=client, on_done=finish, report=report,
                             notice=notice, worker_wait_s=worker_wait_s)
        finally:
            if client is not None:
                close_client(client)
        ordered = [records[n] for n in names]
        write_tables(out, ordered)
    lost = [r for r in ordered if r["status"] == LOST]
    if lost:  # a job that did not end is no result: the run fails, and a rerun (--resume) runs them again
        names_lost = ", ".join(r["name"] for r in lost[:5]) + (f" and {len(lost) - 5} more" if len(lost) > 5 else "")
        raise JobsLost(f"{len(lost)} of {len(jobs)} jobs did not finish: {names_lost} ({lost[0]['error']}); the "
                       f"finished ones are kept in {out}: run the same command again to run the others")
    return SweepResult(out, ordered, skipped, info)


def write_tables(out: str | Path, records: list[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``sweep.json`` (counts and every record) and ``sweep.csv`` (one row per job, results as columns; a
    row per training of a job whose result maps trainings to their results)."""
    out = Path(out)
    summary = {"jobs": len(records), "done": sum(r["status"] == "done" for r in records),
               "failed": [r["name"] for r in records if r["status"] != "done"], "records": records}
    write_atomic(out / SWEEP_JSON, json.dumps(summary, indent=2))
    rows = [(name, r, res) for r in records for name, res in _table_rows(r)]
    keys: list[str] = []
    for _, _, res in rows:
        for k, v in res.items():
            if k not in keys and not isinstance(v, (dict, list)):
                keys.append(k)
    table = io.StringIO(newline="")
    writer = csv.writer(table)
    writer.writerow(["name", "status", "wall_s", "error", *keys])
    for name, r, res in rows:
        writer.writerow([name, r["status"], r.get("wall_s"), r.get("error", ""), *[res.get(k, "") for k in keys]])
    write_atomic(out / SWEEP_CSV, table.getvalue())
    return out / SWEEP_JSON, out / SWEEP_CSV


def _table_rows(record: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """The table rows of one job record: ``(name, result)``; a job whose result maps each of several trainings
    to its own result (a population, :mod:`bptsb_ros.workflows.population`) gives a row per training,
    ``JOB/TRAINING``."""
    result = record.get("result") or {}
    # a flat result has no mapping among its values (the sweep's contract), so all-mappings means trainings
    if result and all(isinstance(v, dict) for v in result.values()):
        return [(f"{record['name']}/{member}", res) for member, res in result.items()]
    return [(record["name"], result)]
