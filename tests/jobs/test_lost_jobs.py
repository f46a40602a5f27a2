"""A job that does not end by itself is a failed job, never a result: a Dask scheduler killed while jobs run, every
worker gone, a local pool's worker process that dies. The run exits 1 naming the lost jobs, writes no result.json,
and running it again (``--resume``) finishes them; a cluster without a worker is waited for with one line saying so,
then given up. The cluster is real: a scheduler and a worker spawned as processes and killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from bptsb_ros.cli import main
from bptsb_ros.experiments import registry
from bptsb_ros.jobs import runner
from bptsb_ros.jobs.sweep import Job, JobsLost, run_sweep

distributed = pytest.importorskip("distributed")


@dataclass(frozen=True)
class Waits:
    """A job that returns at once, or (``slow``) once ``release`` exists (at most 120 s)."""

    slow: bool
    release: str

    def __call__(self, run_dir: Path) -> dict:
        deadline = time.monotonic() + 120
        while self.slow and not Path(self.release).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        return {"slow": self.slow}


def _jobs(release: Path) -> list[Job]:
    return [Job(f"job{i}", Waits(i >= 2, str(release))) for i in range(4)]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _spawn(*argv: str) -> subprocess.Popen:
    """``python -m ARGV`` in its own session; it can import this test module (the jobs are pickled by reference)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    return subprocess.Popen([sys.executable, "-m", *argv], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            stdin=subprocess.DEVNULL, start_new_session=True, env=env)


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)


@pytest.fixture
def scheduler():
    """(address, process) of a Dask scheduler in its own process; killed at the end."""
    port = _free_port()
    proc = _spawn("distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard",
                  "--no-show")
    deadline = time.monotonic() + 60
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            assert proc.poll() is None and time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.2)
    yield f"tcp://127.0.0.1:{port}", proc
    _kill(proc)


@pytest.fixture
def worker(scheduler):
    procs = []

    def start() -> subprocess.Popen:
        procs.append(_spawn("distributed.cli.dask_worker", scheduler[0], "--nthreads", "4", "--no-dashboard",
                            "--no-nanny"))
        with distributed.Client(scheduler[0], timeout="30s") as client:
            client.wait_for_workers(len(procs), timeout=60)
        return procs[-1]

    yield start
    for proc in procs:
        _kill(proc)


def _test_experiment(monkeypatch, tmp_path: Path) -> str:
    """Register an experiment whose one sweep has two quick and two slow jobs (released by a file)."""
    def run(ctx: registry.Context) -> None:
        res = ctx.sweep(_jobs(tmp_path / "release"), ctx.out_dir / "sweep", what="waits")
        ctx.row("jobs", "done", "jobs", len(res.results()))

    name = "lost-jobs-probe"
    monkeypatch.setitem(registry._REGISTRY, name, registry.Experiment(name, "none", "a test", run, {}))
    return name


def test_a_killed_scheduler_fails_the_run_and_resume_finishes_it(scheduler, worker, monkeypatch, tmp_path, capsys):
    address, sched = scheduler
    worker_proc = worker()
    name = _test_experiment(monkeypatch, tmp_path)
    out = tmp_path / "run"
    real_sweep = registry.Context.sweep

    def kill_once_two_are_done(self, jobs, out_dir, **kwargs):  # the run's own progress lines drive the kill
        log = self.log

        def watch(line: str) -> None:
            log(line)
            if line.startswith("sweep: 2/4 done") and sched.poll() is None:
                sched.send_signal(signal.SIGKILL)

        self.log = watch
        return real_sweep(self, jobs, out_dir, **kwargs)

    monkeypatch.setattr(registry.Context, "sweep", kill_once_two_are_done)
    t0 = time.monotonic()
    code = main(["reproduce", name, "--scheduler", address, "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert time.monotonic() - t0 < 60
    last = err.strip().splitlines()[-1]
    assert code == 1 and last.startswith("bptsb reproduce: 2 of 4 jobs did not finish: job2, job3 (lost: JobLost: "
                                         "the Dask cluster lost it"), err
    assert "Traceback" not in err
    assert not (out / "result.json").exists()
    import json

    summary = json.loads((out / "sweep" / "sweep.json").read_text())
    assert [r["status"] for r in summary["records"]] == ["done", "done", "lost", "lost"]
    _kill(worker_proc)  # its two orphaned jobs must not finish behind the resumed run's back
    (tmp_path / "release").touch()
    assert main(["reproduce", name, "--resume", "--workers", "0", "--out", str(out), "--no-progress"]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["rows"][0]["ours"] == 4


def test_no_worker_is_waited_for_with_a_line_then_given_up(scheduler, monkeypatch, tmp_path, capsys):
    address, _ = scheduler
    monkeypatch.setattr(runner, "WORKER_WAIT_S", 1.5)
    name = _test_experiment(monkeypatch, tmp_path)
    out = tmp_path / "run"
    t0 = time.monotonic()
    assert main(["reproduce", name, "--scheduler", address, "--out", str(out), "--no-progress"]) == 1
    assert time.monotonic() - t0 < 30
    err = capsys.readouterr().err
    assert f"waiting up to 1.5 s for a worker to join the Dask scheduler at {address} (it has none" in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"bptsb reproduce: no worker joined the Dask scheduler at {address} within 1.5 s; nothing "
                           f"was run (start workers with `dask worker {address}`, then run the command again)")
    assert last.endswith(f"the unfinished run stays in {out}: add --resume to continue it, or --force to start again")
    assert not (out / "result.json").exists() and not any((out / "sweep" / "jobs").iterdir())


@pytest.mark.slow
def test_jobs_left_without_a_worker_are_lost(scheduler, worker, tmp_path):
    address, _ = scheduler
    worker_proc = worker()
    seen = []

    def progress(p) -> None:
        seen.append(p)
        if p.done == 2 and worker_proc.poll() is None:
            _kill(worker_proc)  # the scheduler stays; nothing is left to run the two slow jobs

    t0 = time.monotonic()
    with pytest.raises(JobsLost, match=r"2 of 4 jobs did not finish: job2, job3 \(lost: JobLost: no Dask worker "
                                       r"was left for 1\.5 s\)"):
        run_sweep(_jobs(tmp_path / "release"), tmp_path / "sweep", scheduler=address, progress=progress,
                  worker_wait_s=1.5)
    assert time.monotonic() - t0 < 60


def _dies(run_dir: Path) -> dict:
    os._exit(3)  # the worker process dies under the job


def _quick(run_dir: Path) -> dict:
    return {"ok": 1}


def test_a_dead_pool_worker_is_a_lost_job(tmp_path):
    jobs = [Job("quick", _quick), Job("dies", _dies)]
    with pytest.raises(JobsLost, match=r"1 of 2 jobs did not finish: dies \(lost: JobLost: its worker process died"):
        run_sweep(jobs, tmp_path, workers=1, threads=None)
    with pytest.raises(runner.JobFailed, match="dies: JobLost: its worker process died"):
        runner.run_jobs(_dies, [(tmp_path,)], runner.Placement(1), names=["dies"])
