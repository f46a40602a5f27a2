"""The one job runner: independent jobs in this process, a local process pool, or on a Dask cluster.

Every independent training of the package goes through here: ``bptsb sweep`` and the sweeps of the
experiments (:func:`bptsb_ros.jobs.sweep.run_sweep`, run directories and resume) and the experiments' in-memory jobs
(:func:`run_jobs`, results in job order). Where the jobs run is a :class:`Placement`:

- ``workers=0``: one after another in this process;
- ``workers=N`` (N ≥ 1): N ``spawn``ed worker processes (``None``: one per CPU available), at most one per job;
- ``scheduler="tcp://HOST:PORT"``: the workers of a Dask distributed cluster (``workers`` is then unused).

Threads inside each job, wherever it runs: the BLAS/OpenMP pools already loaded in the worker are limited with
``threadpoolctl``, the thread-count variables (:data:`THREAD_VARS`) are set for libraries the job loads itself,
and torch runs ``threads`` intra-op threads (in this process only for the job's duration; a worker process keeps
them: :func:`call_limited`). On a busy 2-core machine a default
multi-threaded OpenBLAS made one ridge fit (1,000 × 48) take 8.4 s instead of 0.25 s (measured), and the
workers are already one per core. Each job also reports where it ran (host, process id, Dask worker address),
which :class:`RunInfo` sums up for the provenance of a result.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import socket
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

#: thread-count variables of the BLAS/OpenMP libraries under numpy, scipy and torch, set to the job's thread
#: count while it runs (read by a library when it is loaded; threadpoolctl limits those already loaded)
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
IN_PROCESS = "this process"
LOCAL_POOL = "local pool"


class JobFailed(RuntimeError):
    """One job of :func:`run_jobs` raised; the message names the job and the error."""


class JobLost(RuntimeError):
    """A job that did not end by itself: its worker process died, or the Dask cluster cancelled or lost it (the
    scheduler went away, no worker was left). It is a failed job, never a result; the message says what happened."""


#: how long a Dask run waits for a worker [s]: before the first job (with a line saying so), and whenever none is
#: left while jobs are still to run (then the rest are lost)
WORKER_WAIT_S = 300.0
#: how often a Dask run checks its scheduler and workers while no job ends [s]
DASK_POLL_S = 2.0


@dataclass(frozen=True)
class Placement:
    """Where independent jobs run: ``workers`` local processes (None: the CPUs; 0: this process) or, when
    ``scheduler`` is set (a Dask scheduler address), that cluster's workers."""

    workers: int | None = None
    scheduler: str | None = None

    def __post_init__(self) -> None:
        if self.workers is not None and (isinstance(self.workers, bool) or not isinstance(self.workers, int)
                                         or self.workers < 0):
            raise ValueError(f"--workers must be a whole number >= 0, got {self.workers!r}")

    @property
    def where(self) -> str:
        """The scheduler address, :data:`LOCAL_POOL` or :data:`IN_PROCESS`."""
        if self.scheduler:
            return self.scheduler
        return IN_PROCESS if self.workers == 0 else LOCAL_POOL

    def pool_size(self, jobs: int) -> int:
        """Worker processes a local pool starts for ``jobs`` jobs (0: in this process)."""
        if self.workers == 0 or jobs == 0:
            return 0
        return max(1, min(self.workers or cpus(), jobs))


@dataclass
class RunInfo:
    """What a batch of jobs really used: ``where`` (scheduler address, local pool, this process), ``workers``
    (pool processes, or the cluster's workers when the jobs were submitted), ``jobs`` submitted and ``ran_in``:
    the distinct processes (host, pid) the jobs reported running in."""

    where: str
    workers: int
    jobs: int
    places: set[tuple[str, int, str | None]] = field(default_factory=set)

    def add(self, ran_on: dict[str, Any] | None) -> None:
        if isinstance(ran_on, dict):
            self.places.add((str(ran_on.get("host")), int(ran_on.get("pid", -1)), ran_on.get("dask_worker")))

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"scheduler": self.where, "workers": self.workers, "jobs": self.jobs,
                               "ran_in": len(self.places)}
        dask = sorted({w for *_, w in self.places if w})
        if dask:
            out["dask_workers"] = dask
        return out


def cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def ran_on() -> dict[str, Any]:
    """Where the calling code runs: host name, process id, and the Dask worker's address (None outside one)."""
    worker = None
    if "distributed" in sys.modules:
        try:
            worker = sys.modules["distributed"].get_worker().address
        except (ValueError, AttributeError):  # not inside a Dask task
            worker = None
    return {"host": socket.gethostname(), "pid": os.getpid(), "dask_worker": worker}


def call_limited(fn: Callable[..., Any], args: tuple, threads: int | None,
                 restore: bool = False, caller_pid: int | None = None) -> tuple[Any, dict[str, Any]]:
    """``fn(*args)`` with ``threads`` BLAS/OpenMP and torch threads (None: as they are); returns (its value,
    :func:`ran_on`). Runs inside the worker.

    ``restore`` (the jobs run in the caller's own process): the thread settings are put back afterwards. In a
    worker process (a local pool's, a Dask worker) they stay: OpenBLAS's pthreads pool is process-wide and
    threadpoolctl lets only one Python thread set it, so a Dask worker running several jobs in its threads must
    not have one job's end undo the limit another job still runs under (every job of the package wants it).
    ``caller_pid``: the submitting process; a Dask worker that turns out to be that process (an in-process
    cluster) restores too, so the caller is not left single-threaded."""
    restore = restore or caller_pid == os.getpid()
    if threads is None:
        return fn(*args), ran_on()
    from threadpoolctl import threadpool_limits

    saved_env = {k: os.environ.get(k) for k in THREAD_VARS}
    os.environ.update({k: str(threads) for k in THREAD_VARS})
    torch = sys.modules.get("torch")  # not imported for it: OMP_NUM_THREADS covers an import inside fn
    saved_torch = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(threads)
    limits = threadpool_limits(limits=threads)
    try:
        return fn(*args), ran_on()
    finally:
        if restore:
            limits.restore_original_limits()
            for k, v in saved_env.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            if torch is not None and saved_torch is not None:
                torch.set_num_threads(saved_torch)


#: one job: (name, fn, args); fn(*args) runs in the worker and must be picklable with its arguments
Call = tuple[str, Callable[..., Any], tuple]
#: called once per job as it ends: (index, value, ran_on, error); error is the exception the job raised, or a
#: :class:`JobLost` when it did not end by itself (its worker died, the cluster lost it); value and ran_on are then
#: None
OnDone = Callable[[int, Any, "dict[str, Any] | None", "BaseException | None"], None]


def run_calls(calls: Sequence[Call], placement: Placement, *, threads: int | None = 1, client: Any = None,
              on_done: OnDone, report: Callable[[int], None] | None = None,
              notice: Callable[[str], None] | None = None, worker_wait_s: float | None = None) -> RunInfo:
    """Run every call where ``placement`` says (``client``: a connected ``distributed.Client`` for its
    scheduler); ``on_done`` hears of each as it ends, ``report`` the number running after every change,
    ``notice`` (default: stderr) what a Dask run waits for. Returns what was used.

    On a Dask cluster without a worker, the run says so and waits up to ``worker_wait_s`` (default
    :data:`WORKER_WAIT_S`) for one, then raises :class:`~bptsb_ros.jobs.sweep_errors.SchedulerError`; jobs the cluster
    cancels or loses (the scheduler goes away, no worker is left for that long) end as :class:`JobLost`."""
    report = report or (lambda running: None)
    if not calls:
        return RunInfo(placement.where, 0, 0)
    if placement.scheduler:
        if client is None:
            raise ValueError("a scheduler placement needs a connected client")
        wait_s = WORKER_WAIT_S if worker_wait_s is None else float(worker_wait_s)
        _wait_for_a_worker(client, placement.scheduler, wait_s, notice or _stderr)
        info = RunInfo(placement.where, _cluster_workers(client), len(calls))
        _run_dask(calls, client, threads, info, on_done, report, wait_s)
    elif placement.pool_size(len(calls)) == 0:
        info = RunInfo(IN_PROCESS, 1 if calls else 0, len(calls))
        for i, (_, fn, args) in enumerate(calls):
            report(1)
            try:
                value, where = call_limited(fn, args, threads, restore=True)
            except Exception as err:  # noqa: BLE001 - the caller decides what a failed job means
                on_done(i, None, None, err)
                continue
            info.add(where)
            on_done(i, value, where, None)
        report(0)
    else:
        info = RunInfo(LOCAL_POOL, placement.pool_size(len(calls)), len(calls))
        _run_pool(calls, info.workers, threads, info, on_done, report)
    return info


def _cluster_workers(client: Any) -> int:
    try:
        return len(client.scheduler_info().get("workers", {}))
    except Exception:  # noqa: BLE001 - a count for the record only
        return 0


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _wait_for_a_worker(client: Any, address: str, wait_s: float, notice: Callable[[str], None]) -> None:
    """Return once the cluster has a worker; say what the run waits for when it has none; SchedulerError after
    ``wait_s`` seconds without one."""
    from bptsb_ros.jobs.sweep_errors import SchedulerError

    if _live_workers(client) > 0:
        return
    notice(f"waiting up to {wait_s:g} s for a worker to join the Dask scheduler at {address} (it has none; start "
           f"one with `dask worker {address}`)")
    try:
        client.wait_for_workers(1, timeout=wait_s)
    except Exception:  # noqa: BLE001 - distributed's TimeoutError, or the scheduler went away meanwhile
        raise SchedulerError(f"no worker joined the Dask scheduler at {address} within {wait_s:g} s; nothing was "
                             f"run (start workers with `dask worker {address}`, then run the command again)") from None


def _live_workers(client: Any) -> int:
    """Workers the scheduler knows now (-1: the scheduler cannot be asked)."""
    try:
        return len(client.scheduler_info(n_workers=-1).get("workers", {}))
    except TypeError:  # an older distributed without n_workers
        return _cluster_workers(client)
    except Exception:  # noqa: BLE001 - the connection is gone
        return -1


#: how often a pool worker checks that the process that started it is still alive [s]
PARENT_POLL_S = 1.0


def _exit_with_parent(parent: int, poll_s: float = PARENT_POLL_S) -> None:
    """Pool initializer: a daemon thread that ends this worker when its parent ``parent`` is gone (its parent
    process id changes). A ``bptsb`` killed by SIGTERM (a scheduler's time limit, ``kill``) does not take its
    spawned workers with it: they went on training their jobs and writing into the run directory, where a new
    run of the same command then found their locks and files. Ctrl-C in a terminal reaches the whole process
    group and was never affected."""
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)  # no cleanup: the job's run directory is left as a killed job leaves it

    threading.Thread(target=watch, name="bptsb-parent-watch", daemon=True).start()


def _run_pool(calls: Sequence[Call], workers: int, threads: int | None, info: RunInfo, on_done: OnDone,
              report: Callable[[int], None]) -> None:
    saved = {k: os.environ.get(k) for k in THREAD_VARS}
    if threads is not None:  # inherited by the spawned workers: their libraries start with this many threads
        os.environ.update({k: str(threads) for k in THREAD_VARS})
    ctx = multiprocessing.get_context("spawn")  # no forked torch/ROS state in the workers
    try:
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_exit_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            pending = {pool.submit(call_limited, fn, args, threads): i for i, (_, fn, args) in enumerate(calls)}
            report(min(workers, len(pending)))
            while pending:
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    i = pending.pop(fut)
                    try:
                        value, where = fut.result()
                    except BrokenProcessPool as err:  # its worker process died under it
                        on_done(i, None, None, JobLost(f"its worker process died ({_first_line(err)})"))
                        continue
                    except Exception as err:  # noqa: BLE001 - the job raised
                        on_done(i, None, None, err)
                        continue
                    info.add(where)
                    on_done(i, value, where, None)
                report(min(workers, len(pending)))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_dask(calls: Sequence[Call], client: Any, threads: int | None, info: RunInfo, on_done: OnDone,
              report: Callable[[int], None], wait_s: float) -> None:
    from distributed import wait as dask_wait

    stamp = time.time_ns()  # fresh task keys: a resumed sweep never reuses an old result held by the cluster
    futures = {client.submit(call_limited, fn, args, threads, False, os.getpid(), key=f"bptsb-{name}-{i}-{stamp}",
                             pure=False): i for i, (name, fn, args) in enumerate(calls)}

    def running() -> int:
        try:
            return min(len(futures), sum(len(v) for v in client.processing().values()))
        except Exception:  # noqa: BLE001 - counts only
            return 0

    def lose_the_rest(why: str) -> None:
        for fut in list(futures):
            with contextlib.suppress(Exception):
                fut.cancel()
            on_done(futures.pop(fut), None, None, JobLost(why))

    report(running())
    no_worker_since: float | None = None
    while futures:
        done = [f for f in futures if f.done()]
        if not done:
            # distributed's wait raises on its timeout and on cancelled futures: both are seen below
            with contextlib.suppress(Exception):
                dask_wait(list(futures), timeout=DASK_POLL_S, return_when="FIRST_COMPLETED")
            done = [f for f in futures if f.done()]
        for fut in done:
            i = futures.pop(fut)
            try:
                value, where = fut.result()
            except Exception as err:  # noqa: BLE001 - the job raised, or the cluster cancelled or lost it
                lost = fut.status != "error" or _is_lost(err)
                on_done(i, None, None, JobLost(f"the Dask cluster lost it ({type(err).__name__}: "
                                               f"{_first_line(err)})") if lost else err)
                continue
            info.add(where)
            on_done(i, value, where, None)
        if done:
            report(running())
            continue
        if client.status not in ("running", "newly-created"):
            lose_the_rest(f"the connection to the Dask scheduler was lost (client {client.status})")
            break
        workers = _live_workers(client)
        if workers == 0:
            no_worker_since = no_worker_since or time.monotonic()
            if time.monotonic() - no_worker_since > wait_s:
                lose_the_rest(f"no Dask worker was left for {wait_s:g} s")
        else:
            no_worker_since = None


def _is_lost(err: BaseException) -> bool:
    """A Dask error that says the cluster lost the job, not that the job raised (a worker died under it)."""
    return type(err).__name__ in ("KilledWorker", "FutureCancelledError", "CancelledError", "CommClosedError")


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0][:200] if text else "no message"


def close_client(client: Any) -> None:
    """Close a ``distributed.Client`` without its logs: a client whose scheduler went away logs its failed
    reconnection as tracebacks while it closes (the run has said what happened in one line already)."""
    import logging

    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL + 1)
    try:
        client.close(timeout=10)
    except Exception:  # noqa: BLE001 - closing a client whose scheduler is gone
        pass
    finally:
        quiet.setLevel(level)


def connect_placement(placement: Placement, timeout: float) -> Any:
    """A ``distributed.Client`` of ``placement``'s scheduler (None without one); see
    :func:`bptsb_ros.jobs.dask_cluster.connect` (``inproc://`` addresses are an in-process cluster's)."""
    if not placement.scheduler:
        return None
    from bptsb_ros.jobs.dask_cluster import connect, scheduler_address

    address = placement.scheduler
    if not address.startswith("inproc://"):
        address = scheduler_address(address)
    return connect(address, timeout)


def run_jobs(fn: Callable[..., Any], jobs: Sequence[tuple], placement: Placement | None = None, *,
             names: Sequence[str] | None = None, threads: int | None = 1,
             connect_timeout: float = 20.0) -> tuple[list[Any], RunInfo]:
    """Run ``fn(*args)`` for every ``args`` in ``jobs`` where ``placement`` says (default: a local pool, one
    process per CPU); returns (the results in job order, what was used). A job that raises makes this raise
    :class:`JobFailed` naming the first failed job in job order, once every job has ended."""
    placement = placement or Placement()
    names = list(names) if names is not None else [f"job {i}" for i in range(len(jobs))]
    if len(names) != len(jobs):
        raise ValueError(f"{len(names)} names for {len(jobs)} jobs")
    results: list[Any] = [None] * len(jobs)
    errors: dict[int, BaseException] = {}

    def done(i: int, value: Any, where: dict[str, Any] | None, error: BaseException | None) -> None:
        if error is not None:
            errors[i] = error
        else:
            results[i] = value

    client = connect_placement(placement, connect_timeout) if jobs else None
    try:
        # Dask keys are made of the names: keep them to letters, digits and ._-
        safe = ["".join(c if c.isalnum() or c in "._-" else "_" for c in n)[:60] for n in names]
        info = run_calls([(s, fn, tuple(args)) for s, args in zip(safe, jobs, strict=True)], placement,
                         threads=threads, client=client, on_done=done)
    finally:
        if client is not None:
            close_client(client)
    if errors:
        first = min(errors)
        err = errors[first]
        raise JobFailed(f"{names[first]}: {type(err).__name__}: {err}") from err
    return results, info
