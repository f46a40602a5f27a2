"""The one job runner (bptsb_ros.jobs.runner): results in order, failures named, thread limits inside each job (this
process, a spawned pool, a Dask LocalCluster), what a Context records; and, for an experiment of each family,
that `--workers 1` and `--scheduler` of `bptsb reproduce` decide where its jobs run (planted marker jobs record
the process and the Dask worker they ran in)."""

from __future__ import annotations

import json
import operator
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from bptsb_ros.cli import main
from bptsb_ros.experiments import run_experiment
from bptsb_ros.experiments.registry import Context
from bptsb_ros.experiments.result import ExperimentResult
from bptsb_ros.jobs.runner import JobFailed, Placement, cpus, run_jobs

distributed = pytest.importorskip("distributed")

MARKS = "BPTSB_TEST_RUNNER_MARKS"


class MarkerStop(RuntimeError):
    """Raised by every planted job after it recorded where it ran (the experiment stops there)."""


def _threads_now() -> dict:
    """BLAS thread counts of the loaded libraries (threadpoolctl's own view), the variable, torch's count."""
    import sys

    torch = sys.modules.get("torch")
    return {"blas": sorted({p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"}),
            "env": os.environ.get("OPENBLAS_NUM_THREADS"),
            "torch": torch.get_num_threads() if torch is not None else None, "pid": os.getpid()}


def _mark(family: str) -> None:
    """Append where this job runs (pid, Dask worker address or None, BLAS threads) to $BPTSB_TEST_RUNNER_MARKS."""
    worker = None
    try:
        worker = distributed.get_worker().address
    except ValueError:
        pass
    with open(os.environ[MARKS], "a") as fh:
        fh.write(json.dumps({"family": family, "worker": worker, **_threads_now()}) + "\n")
    import time

    time.sleep(0.2)  # long enough that a second pool process would take the next job


def _marks(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


# planted jobs, one per family, with the signatures of the jobs they replace (top level: spawned workers import
# this module to unpickle them)
def marker_agent_job(settings, seed: int, run_dir: Path) -> dict:
    _mark("locomotion")
    raise MarkerStop("planted locomotion job")


@dataclass(frozen=True)
class MarkerNarmaJob:
    config: str
    overrides: tuple
    seed: int
    stages: tuple
    eval_inputs: int
    eval_seed: int = 777
    washout: int = 100

    def __call__(self, run_dir: Path) -> dict:
        _mark("timeseries")
        raise MarkerStop("planted time-series job")


def marker_scheme_job(*args) -> dict:
    _mark("schemes")
    raise MarkerStop("planted scheme job")


def marker_drawing_job(**kwargs) -> dict:
    _mark("mnist")
    raise MarkerStop("planted MNIST job")


@pytest.fixture
def marks(tmp_path, monkeypatch) -> Path:
    path = tmp_path / "marks.jsonl"
    monkeypatch.setenv(MARKS, str(path))
    return path


@pytest.fixture(scope="module")
def cluster():
    # tcp, as a real cluster: the address goes through the validation and the probe that --scheduler uses
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  dashboard_address=None, silence_logs=40) as c:
        yield c


def _worker_address(cluster) -> str:
    (address,) = cluster.scheduler_info["workers"]
    return address


# -- the runner ------------------------------------------------------------------------------------------------
def test_results_in_order_and_a_failure_names_its_job():
    results, info = run_jobs(operator.add, [(1, 2), (3, 4), (5, 6)], Placement(0))
    assert results == [3, 7, 11]
    assert info.to_json() == {"scheduler": "this process", "workers": 1, "jobs": 3, "ran_in": 1}
    with pytest.raises(JobFailed, match="second: ZeroDivisionError"):
        run_jobs(operator.truediv, [(1, 1), (1, 0), (2, 1)], Placement(0), names=["first", "second", "third"])
    with pytest.raises(ValueError, match="--workers must be"):
        Placement(-1)


# Not marked slow (4 to 6 s): test_an_in_process_dask_worker_leaves_the_callers_threads_as_they_were passes only
# after it in the same process (threadpoolctl lets only the first thread that sets OpenBLAS's limit set it).
def test_thread_limits_inside_every_job():
    """One BLAS thread (threadpoolctl's view in the job) and one torch thread inside each job, in this process, in
    a spawned pool and on a Dask worker process, while this process runs two BLAS threads; restored here after."""
    import dask
    import torch

    from bptsb_ros.jobs.runner import cpus

    if cpus() < 2:
        pytest.skip("OpenBLAS runs at most one thread per CPU: one CPU shows no limit")
    torch_before = torch.get_num_threads()
    two = {k: "2" for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    # Dask starts its worker processes with one BLAS thread unless told otherwise: two, so that a limit shows
    with dask.config.set({"distributed.nanny.pre-spawn-environ": two}), \
            distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=None,
                                     silence_logs=40) as procs, threadpool_limits(limits=2, user_api="blas"):
        assert _threads_now()["blas"] == [2]
        (before,), _ = run_jobs(_threads_now, [()], Placement(scheduler=procs.scheduler_address), threads=None)
        assert before["blas"] == [2]  # the worker process as it started
        env_before = os.environ.get("OPENBLAS_NUM_THREADS")  # as Dask's nanny left it
        for placement in (Placement(0), Placement(1), Placement(scheduler=procs.scheduler_address)):
            inside, info = run_jobs(_threads_now, [(), ()], placement)
            assert all(i["blas"] == [1] and i["env"] == "1" for i in inside), (placement, inside)
            assert all(i["torch"] in (1, None) for i in inside)  # None: torch never imported in a fresh worker
            assert all((i["pid"] == os.getpid()) == (placement.where == "this process") for i in inside)
            assert _threads_now()["blas"] == [2]  # this process: as before
            assert os.environ.get("OPENBLAS_NUM_THREADS") == env_before
        assert info.to_json()["dask_workers"] == list(procs.scheduler_info["workers"])
    assert torch.get_num_threads() == torch_before


def test_context_records_where_jobs_ran(tmp_path, cluster):
    ctx = Context("short", 0, tmp_path, ExperimentResult("x", "ref", "short", 0), workers=1, log=lambda m: None)
    assert ctx.run_jobs(operator.mul, [(2, 3), (4, 5)]) == [6, 20]
    addr = cluster.scheduler_address
    dask = Context("short", 0, tmp_path, ExperimentResult("x", "ref", "short", 0), scheduler=addr, log=lambda m: None)
    assert dask.run_jobs(operator.mul, [(2, 3)], what="products") == [6]
    smoke = Context("smoke", 0, tmp_path, ExperimentResult("x", "ref", "smoke", 0), log=lambda m: None)
    assert smoke.placement() == Placement(0) and ctx.placement() == Placement(1)
    assert ctx.result.provenance["jobs"] == [{"what": "mul", "scheduler": "local pool", "workers": 1, "jobs": 2,
                                              "ran_in": 1}]
    assert dask.result.provenance["jobs"] == [{"what": "products", "scheduler": addr, "workers": 1, "jobs": 1,
                                               "ran_in": 1, "dask_workers": [_worker_address(cluster)]}]


# -- every family: --workers 1 and --scheduler decide where the experiment's jobs run ----------------------------
#: (experiment, module attribute replaced by a planted job, the planted job, the error the run then ends with; None:
#: the run ends with a result whose claims are all not testable)
FAMILIES = {
    "locomotion": ("locomotion-headwind", "bptsb_ros.experiments.locomotion_common.forward_agent_job",
                   marker_agent_job, None),
    "timeseries": ("narma-emulation", "bptsb_ros.experiments.timeseries.NarmaJob", MarkerNarmaJob, RuntimeError),
    "schemes": ("closed-loop-schemes", "bptsb_ros.experiments.closed_loop_schemes.scheme_job", marker_scheme_job,
                JobFailed),
    "mnist": ("mnist-drawing", "bptsb_ros.experiments.mnist_drawing.train_drawing_job", marker_drawing_job,
              JobFailed),
}


@pytest.fixture(scope="module")
def mnist_dir(tmp_path_factory):
    from bptsb_ros.data.mnist import write_custom_set

    rng = np.random.default_rng(0)
    labels = (np.arange(150) % 10).astype(np.uint8)
    return write_custom_set(tmp_path_factory.mktemp("mnist"), rng.integers(0, 255, (150, 28, 28)).astype(np.uint8),
                            labels)


def _run_family(family: str, out: Path, monkeypatch, mnist_dir, **where) -> None:
    name, target, planted, error = FAMILIES[family]
    monkeypatch.setattr(target, planted)
    data = {"data_dir": mnist_dir} if family == "mnist" else {}
    if error is None:  # a failed forward agent is a result of the run (every claim not testable), not a failure
        _, result = run_experiment(name, scale="smoke", out_dir=out, progress=False, log=lambda m: None, **data,
                                   **where)
        assert result["claims"] and all(c["holds"] is None and "planted" in c["evidence"]
                                        for c in result["claims"])
        return
    with pytest.raises(error, match="planted|MarkerStop|forward agent failed"):
        run_experiment(name, scale="smoke", out_dir=out, progress=False, log=lambda m: None, **data, **where)


@pytest.mark.parametrize("family", [pytest.param(f, marks=pytest.mark.slow) if f == "locomotion" else f
                                    for f in FAMILIES])
def test_workers_1_is_honoured(family, tmp_path, marks, monkeypatch, mnist_dir):
    """--workers 1: every job in one spawned worker process (not this one, whatever the scale's default)."""
    _run_family(family, tmp_path / "run", monkeypatch, mnist_dir, workers=1)
    seen = _marks(marks)
    assert seen and {m["family"] for m in seen} == {family}
    assert len({m["pid"] for m in seen}) == 1 and seen[0]["pid"] != os.getpid()
    assert all(m["worker"] is None and m["blas"] == [1] for m in seen)  # a pool process: its limits in force


@pytest.mark.parametrize("family", list(FAMILIES))
def test_scheduler_is_used(family, tmp_path, marks, monkeypatch, mnist_dir, cluster):
    """--scheduler: every job on the cluster's worker (its threads run in this process: the BLAS limits on a
    worker process are test_thread_limits_inside_every_job's)."""
    _run_family(family, tmp_path / "run", monkeypatch, mnist_dir, scheduler=cluster.scheduler_address)
    seen = _marks(marks)
    assert seen and all(m["worker"] == _worker_address(cluster) for m in seen)


def test_reproduce_cli_passes_the_scheduler(tmp_path, marks, monkeypatch, cluster, capsys):
    """`bptsb reproduce --scheduler tcp://...` reaches the runner (and a bad --workers is one usage line)."""
    monkeypatch.setattr(FAMILIES["schemes"][1], marker_scheme_job)
    assert main(["reproduce", "closed-loop-schemes", "--scale", "smoke", "--out", str(tmp_path / "cli"),
                 "--no-progress", "--scheduler", cluster.scheduler_address]) == 1  # a job failed: runtime
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]  # after the progress lines: the failure, one line
    assert last.startswith("bptsb reproduce: ") and "planted" in last and "Traceback" not in err, err
    assert [m["worker"] for m in _marks(marks)] == [_worker_address(cluster)]
    assert main(["reproduce", "closed-loop-schemes", "--scale", "smoke", "--out", str(tmp_path / "bad"),
                 "--workers", "-1"]) == 2
    assert "--workers must be a whole number >= 0" in capsys.readouterr().err


def _square(x: int, run_dir: Path) -> dict:
    (run_dir / "out.txt").write_text(str(x * x))
    return {"square": x * x}


def test_locomotion_agents_are_adopted_only_from_own_reproduce_runs(tmp_path):
    """Finished jobs of a sibling `bptsb reproduce` run are copied in (and not run again); a sibling that is not
    such a run, and a record of another job, are not."""
    import functools

    from bptsb_ros.experiments.locomotion_common import AGENTS_DIR, adopt_sibling_agents
    from bptsb_ros.experiments.registry import RUN_MARKER
    from bptsb_ros.jobs.sweep import Job, run_sweep

    def jobs(*xs):
        return [Job(f"seed-{x}", functools.partial(_square, x)) for x in xs]

    for name, xs, marked in (("a", (1,), True), ("b", (2,), False)):
        run_sweep(jobs(*xs), tmp_path / name / AGENTS_DIR, workers=0, threads=None)
        if marked:
            (tmp_path / name / RUN_MARKER).write_text("bptsb reproduce x\n")
    # a sibling run holding seed-3's directory with the record of another job (x = 4 under the name seed-3)
    run_sweep([Job("seed-3", functools.partial(_square, 4))], tmp_path / "d" / AGENTS_DIR, workers=0, threads=None)
    (tmp_path / "d" / RUN_MARKER).write_text("bptsb reproduce x\n")
    out = tmp_path / "c"
    out.mkdir()
    where = out / AGENTS_DIR
    assert adopt_sibling_agents(jobs(1, 2, 3), where, out, lambda m: None) == ["seed-1"]
    res = run_sweep(jobs(1, 2, 3), where, workers=0, threads=None)
    assert res.skipped == ["seed-1"] and res.results()["seed-3"] == {"square": 9}
    assert (where / "jobs" / "seed-1" / "out.txt").read_text() == "1"


def test_an_in_process_dask_worker_leaves_the_callers_threads_as_they_were(cluster):
    """A cluster of processes=False runs its tasks in this very process: the thread variables and torch's count hold
    inside the job and are put back after it, as for --workers 0 (else every process this one starts later, a Dask
    worker included, starts single-threaded). OpenBLAS's own count is not checked here: the job runs in a worker
    thread, and a count set from a thread other than the main one does not show in that thread's own reading (it
    read 2 alone, and 1 only after another test had set it from the main thread)."""
    import torch

    if cpus() < 2:
        pytest.skip("OpenBLAS runs at most one thread per CPU: one CPU shows no limit")
    torch_before = torch.get_num_threads()
    with threadpool_limits(limits=2, user_api="blas"):
        env_before = os.environ.get("OPENBLAS_NUM_THREADS")
        (inside,), _ = run_jobs(_threads_now, [()], Placement(scheduler=cluster.scheduler_address))
        assert inside["pid"] == os.getpid() and inside["env"] == "1" and inside["torch"] == 1
        assert _threads_now()["env"] == env_before and torch.get_num_threads() == torch_before


def test_pool_workers_end_when_the_process_that_started_them_is_killed(tmp_path):
    """SIGTERM to the caller (not to its process group) used to leave the spawned workers training on."""
    import signal
    import subprocess
    import sys
    import time

    (tmp_path / "slow_job.py").write_text(
        "import os, time\n"
        "def job(path):\n"
        "    open(path, 'w').write(str(os.getpid()))\n"
        "    time.sleep(60)\n")
    pid_file = tmp_path / "worker.pid"
    script = ("import sys; sys.path.insert(0, sys.argv[1])\n"
              "from bptsb_ros.jobs.runner import Placement, run_jobs\n"
              "import slow_job\n"
              "run_jobs(slow_job.job, [(sys.argv[2],)], Placement(1))\n")
    caller = subprocess.Popen([sys.executable, "-c", script, str(tmp_path), str(pid_file)])
    try:
        deadline = time.monotonic() + 60
        while not (pid_file.is_file() and pid_file.read_text()) and time.monotonic() < deadline:
            time.sleep(0.1)
        worker = int(pid_file.read_text())
        caller.send_signal(signal.SIGTERM)
        caller.wait(10)

        deadline = time.monotonic() + 10
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(worker), "the worker outlived the process that started it"
    finally:
        caller.kill()
        caller.wait()
        if pid_file.is_file() and pid_file.read_text() and _alive(int(pid_file.read_text())):
            os.kill(int(pid_file.read_text()), signal.SIGKILL)


def _alive(pid: int) -> bool:
    """The process runs (a zombie, dead but not yet collected by its new parent, does not count)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state != "Z"
