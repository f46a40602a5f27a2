"""Independent trainings as jobs: a small process pool (to be swapped for the sweep runner ``bptsb_ros.sweep``
once it exists). Each job is a picklable top-level function with picklable arguments; results come back in
the order of the jobs. A job that fails raises in the caller, naming the job."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any, TypeVar

R = TypeVar("R")

#: thread-count variables of the BLAS/OpenMP libraries under numpy and torch, set to 1 for the workers: on a
#: busy 2-core machine a default multi-threaded OpenBLAS made one ridge fit (1,000 × 48) take 8.4 s instead
#: of 0.25 s (measured), and the workers are already one per core
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class JobFailed(RuntimeError):
    """One job of a pool raised; the message names the job and the error."""


def _available_cpus() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _one_thread(fn: Callable[..., R], args: tuple) -> R:
    if "torch" in sys.modules:  # imported with fn's module (OMP_NUM_THREADS = 1 covers a later import)
        sys.modules["torch"].set_num_threads(1)
    return fn(*args)


def run_jobs(fn: Callable[..., R], jobs: Sequence[tuple], *, workers: int | None = None,
             names: Sequence[str] | None = None) -> list[R]:
    """Run ``fn(*args)`` for every ``args`` in ``jobs`` in a pool of ``workers`` processes (default: the CPUs
    available, at most the number of jobs; 1 runs in this process). Each worker uses one torch thread."""
    names = list(names) if names is not None else [f"job {i}" for i in range(len(jobs))]
    if len(names) != len(jobs):
        raise ValueError(f"{len(names)} names for {len(jobs)} jobs")
    workers = min(workers or _available_cpus(), len(jobs)) or 1
    if workers == 1:
        out: list[Any] = []
        for name, args in zip(names, jobs, strict=True):
            try:
                out.append(fn(*args))
            except Exception as err:  # noqa: BLE001 - re-raised with the job's name
                raise JobFailed(f"{name}: {type(err).__name__}: {err}") from err
        return out
    saved = {k: os.environ.get(k) for k in BLAS_THREAD_VARS}
    os.environ.update({k: "1" for k in BLAS_THREAD_VARS})  # inherited by the spawned workers
    try:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(_one_thread, fn, args) for args in jobs]
            results = []
            for name, fut in zip(names, futures, strict=True):
                try:
                    results.append(fut.result())
                except Exception as err:  # noqa: BLE001 - re-raised with the job's name
                    raise JobFailed(f"{name}: {type(err).__name__}: {err}") from err
            return results
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
