"""The sweep runner: jobs in a local process pool and on a real Dask LocalCluster, failures, resume, tables, CLI."""

from __future__ import annotations

import csv
import functools
import json
from pathlib import Path

import pytest

from bptsb_ros.cli import main
from bptsb_ros.jobs.sweep import JOB_FILE, Job, SweepError, parse_seeds, run_sweep


def _square_job(x: int, run_dir: Path) -> dict:
    """Planted job: counts its runs in run_dir/calls.txt, fails on x = 3, else returns x² and x/2."""
    with (run_dir / "calls.txt").open("a") as fh:
        fh.write("run\n")
    if x == 3:
        raise ValueError(f"planted failure for x = {x}")
    return {"x": x, "square": x * x, "half": x / 2}


def _jobs(values) -> list[Job]:
    return [Job(f"x{v}", functools.partial(_square_job, v)) for v in values]


def _calls(out: Path, name: str) -> int:
    return len((out / "jobs" / name / "calls.txt").read_text().splitlines())


def _check_tables(out: Path, values, failed=(3,)) -> None:
    summary = json.loads((out / "sweep.json").read_text())
    assert summary["jobs"] == len(values)
    assert summary["failed"] == [f"x{v}" for v in values if v in failed]
    rows = {r["name"]: r for r in csv.DictReader((out / "sweep.csv").open())}
    assert list(rows) == [f"x{v}" for v in values]
    for v in values:
        row = rows[f"x{v}"]
        if v in failed:
            assert row["status"] == "failed" and "planted failure for x = 3" in row["error"]
        else:
            assert row["status"] == "done" and int(row["square"]) == v * v and float(row["half"]) == v / 2


def test_parse_seeds():
    assert parse_seeds("0-3,7") == [0, 1, 2, 3, 7]
    assert parse_seeds("5") == [5]
    assert parse_seeds("2,1-2") == [1, 2]
    for bad in ("3-1", "a", "1-", ""):
        with pytest.raises(SweepError):
            parse_seeds(bad)


def test_bad_job_names_are_refused(tmp_path):
    with pytest.raises(SweepError, match="distinct"):
        run_sweep(_jobs([1, 1]), tmp_path, workers=0)
    with pytest.raises(SweepError, match="letters"):
        run_sweep([Job("../evil", functools.partial(_square_job, 1))], tmp_path, workers=0)


def test_local_pool_failure_and_resume(tmp_path):
    values = [0, 1, 2, 3, 4]
    seen = []
    res = run_sweep(_jobs(values), tmp_path, workers=2, progress=seen.append, threads=None)
    _check_tables(tmp_path, values)
    assert [r["name"] for r in res.failed] == ["x3"]
    assert "ValueError" in res.failed[0]["error"] and "Traceback" in res.failed[0]["traceback"]
    last = seen[-1]
    assert (last.total, last.done, last.running, last.failed) == (5, 4, 0, 1)
    assert max(p.running for p in seen) == 2  # never more than the workers
    # every job wrote in its own directory, once
    assert all(_calls(tmp_path, f"x{v}") == 1 for v in values)

    # a sweep killed while x4 ran: x4 left its directory but no job.json
    (tmp_path / "jobs" / "x4" / JOB_FILE).unlink()
    res = run_sweep(_jobs(values), tmp_path, workers=2, threads=None)
    assert sorted(res.skipped) == ["x0", "x1", "x2"]
    assert [_calls(tmp_path, f"x{v}") for v in values] == [1, 1, 1, 2, 2]  # failed and unfinished ran again
    _check_tables(tmp_path, values)


def test_dask_local_cluster(tmp_path):
    distributed = pytest.importorskip("distributed")
    values = [0, 1, 2, 3]
    # tcp, as a real cluster: the address goes through the validation and the probe that bptsb sweep uses
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp://",
                                  dashboard_address=None, silence_logs=40) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        seen = []
        res = run_sweep(_jobs(values), tmp_path, scheduler=cluster.scheduler_address, progress=seen.append)
        _check_tables(tmp_path, values)
        assert res.results()["x2"]["square"] == 4
        assert (seen[-1].done, seen[-1].failed, seen[-1].running) == (3, 1, 0)
        # resume on the cluster: only the failed job runs again
        res = run_sweep(_jobs(values), tmp_path, scheduler=cluster.scheduler_address)
        assert sorted(res.skipped) == ["x0", "x1", "x2"]
        assert [_calls(tmp_path, f"x{v}") for v in values] == [1, 1, 1, 2]


def test_unreachable_scheduler_is_one_error(tmp_path):
    pytest.importorskip("distributed")
    with pytest.raises(SweepError, match="cannot reach the Dask scheduler"):
        run_sweep(_jobs([1]), tmp_path, scheduler="tcp://127.0.0.1:9", connect_timeout=2)


def test_cli_trains_each_seed(tmp_path, repo_root, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", str(repo_root / "config" / "locomotion_forward.yaml"), "--seeds", "0-1", "--out", str(out),
            "--workers", "0", "--set", "sim_time=2", "--set", "locomotion.warmup_windows=0",
            "--set", "feedback.fit_time=2", "--set", "locomotion.eval_time=1"]
    assert main(args) == 0
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [r["name"] for r in rows] == ["seed-0", "seed-1"]
    for row, seed in zip(rows, (0, 1), strict=True):
        metrics = json.loads((out / "jobs" / f"seed-{seed}" / "metrics.json").read_text())
        assert metrics["seed"] == seed and int(row["seed"]) == seed
        assert float(row["mean_forward_speed"]) == pytest.approx(metrics["evaluation"]["mean_forward_speed"])
    assert rows[0]["mean_forward_speed"] != rows[1]["mean_forward_speed"]
    # a rerun skips both; a bad override fails once, before any job
    assert main(args) == 0
    assert "skipped 2 finished job(s)" in capsys.readouterr().err
    assert main([*args[:-2], "--set", "locomotion.eval_time=-1"]) == 2
    assert "locomotion.eval_time" in capsys.readouterr().err


@pytest.mark.parametrize("workers, ok", [(0, True), (-1, False), (True, False), (1.5, False)])
def test_a_bad_worker_count_is_a_sweep_error_that_creates_nothing(tmp_path, workers, ok):
    out = tmp_path / "new" / "sweep"
    if ok:
        res = run_sweep([], out, workers=workers)  # no jobs: nothing runs, the folder is the sweep's
        assert res.failed == [] and out.is_dir()
        return
    with pytest.raises(SweepError, match="--workers must be a whole number >= 0"):
        run_sweep([], out, workers=workers)
    assert not (tmp_path / "new").exists()


def _non_finite_job(run_dir: Path) -> dict:
    return {"nan": float("nan"), "inf": float("inf"), "neg": [float("-inf"), 1.5], "text": "nan-ish", "n": 2}


def test_results_give_non_finite_floats_back_as_floats(tmp_path):
    import math

    res = run_sweep([Job("a", _non_finite_job)], tmp_path, workers=0)
    on_disk = json.loads((tmp_path / "jobs" / "a" / JOB_FILE).read_text())["result"]
    assert on_disk["nan"] == "nan" and on_disk["inf"] == "inf"  # JSON has no NaN: the record holds text
    got = res.results()["a"]
    assert math.isnan(got["nan"]) and got["inf"] == math.inf and got["neg"] == [-math.inf, 1.5]
    assert got["text"] == "nan-ish" and got["n"] == 2
    again = run_sweep([Job("a", _non_finite_job)], tmp_path, workers=0)  # reused from its record
    assert math.isnan(again.results()["a"]["nan"])


def _population_job(run_dir: Path) -> dict:
    """Planted job running two trainings at once: a result per training, one of them diverged."""
    return {"a": {"seed": 0, "nmse": 0.25}, "b": {"diverged": "TrainingDiverged: planted"}}


def _empty_job(run_dir: Path) -> dict:
    return {}


def _mixed_job(run_dir: Path) -> dict:
    """A flat result with one nested value (outside the contract): one row, the nested value left out."""
    return {"loss": 0.5, "history": {"a": 1}}


def test_a_population_job_has_a_table_row_per_training(tmp_path):
    jobs = [*_jobs([2]), Job("pop", _population_job), Job("empty", _empty_job), Job("mixed", _mixed_job)]
    run_sweep(jobs, tmp_path, workers=0)
    rows = {r["name"]: r for r in csv.DictReader((tmp_path / "sweep.csv").open())}
    assert list(rows) == ["x2", "pop/a", "pop/b", "empty", "mixed"]
    assert rows["empty"]["status"] == "done" and float(rows["mixed"]["loss"]) == 0.5 and "history" not in rows["mixed"]
    assert rows["x2"]["square"] == "4" and rows["x2"]["nmse"] == ""
    assert rows["pop/a"]["status"] == "done" and float(rows["pop/a"]["nmse"]) == 0.25 and rows["pop/a"]["seed"] == "0"
    assert rows["pop/b"]["diverged"] == "TrainingDiverged: planted" and rows["pop/b"]["nmse"] == ""
    assert json.loads((tmp_path / "sweep.json").read_text())["records"][1]["result"]["a"]["nmse"] == 0.25
