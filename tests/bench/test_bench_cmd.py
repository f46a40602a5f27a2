"""`bptsb bench` writes its --out JSON after every measurement: a bench killed half-way leaves a valid file with
what it measured, marked incomplete. The measurements are planted (no benchmark runs here)."""

from __future__ import annotations

import json

import pytest

from bptsb_ros.bench import gang_speed as bench_gang
from bptsb_ros.bench import mnist_speed as bench_mnist
from bptsb_ros.bench import suite as bench
from bptsb_ros.cli import main

PLANTED = {"forward_steps_per_s": 11.0, "forward_body_steps_per_s": 11.0, "train_steps_per_s": 7.0,
           "train_body_steps_per_s": 7.0, "peak_rss_mib": 3.0, "first_call_s": 0.5}


def _plant(monkeypatch, interrupt_at: int | None) -> list[tuple[str, str]]:
    """Planted measurements; the one numbered ``interrupt_at`` (0-based) raises KeyboardInterrupt. Returns the
    (workload, backend) list of the measurements started."""
    started: list[tuple[str, str]] = []

    def fake(w, adjoint, dtype="float32", min_seconds=3.0, backend="torch", numba_cache=None):
        started.append((w.name, backend))
        if len(started) - 1 == interrupt_at:
            raise KeyboardInterrupt
        return dict(PLANTED, backend=backend)

    monkeypatch.setattr(bench, "measure_isolated", fake)
    monkeypatch.setattr(bench, "measure_compile", lambda min_seconds: {"cold_compile": {"x": 1.0},
                                                                     "cached": {"x": 0.1}})
    monkeypatch.setattr(bench, "_ipc_entry", lambda quick, progress: {})
    monkeypatch.setattr(bench_mnist, "run_isolated", lambda quick: {"error": "planted"})
    monkeypatch.setattr(bench_gang, "run_isolated", lambda quick: {"error": "planted"})
    return started


def test_a_bench_interrupted_at_its_second_measurement_keeps_the_first(tmp_path, monkeypatch, capsys):
    out = tmp_path / "sub" / "bench.json"
    started = _plant(monkeypatch, interrupt_at=1)
    assert main(["bench", "--quick", "--out", str(out)]) == 130
    assert started == [("lissajous", "torch"), ("lissajous", "numba")]
    report = json.loads(out.read_text())
    assert report["complete"] is False
    assert report["workloads"]["lissajous"]["torch"] == dict(PLANTED, backend="torch")
    assert "numba" not in report["workloads"]["lissajous"] and "narma" not in report["workloads"]
    assert [p.name for p in out.parent.iterdir()] == ["bench.json"]  # no temporary file left beside it
    assert "bench lissajous (numba) ..." in capsys.readouterr().err


def test_a_bench_that_fails_before_any_measurement_leaves_an_empty_incomplete_file(tmp_path, monkeypatch):
    out = tmp_path / "bench.json"
    _plant(monkeypatch, interrupt_at=0)
    assert main(["bench", "--quick", "--out", str(out)]) == 130
    assert json.loads(out.read_text()) == {"complete": False}


def _measured_in(path) -> int:
    """How many planted measurements the file at ``path`` holds (workload entries and batch-scaling figures)."""
    report = json.loads(path.read_text())
    entries = sum(1 for e in report.get("workloads", {}).values() for v in e.values()
                  if isinstance(v, dict) and v.get("first_call_s") == PLANTED["first_call_s"])
    return entries + sum(1 for row in report.get("batch_scaling", {}).values() for b in ("torch", "numba") if b in row)


def test_a_finished_bench_is_marked_complete_and_each_measurement_is_on_disk_before_the_next(tmp_path, monkeypatch):
    out = tmp_path / "bench.json"
    started = _plant(monkeypatch, interrupt_at=None)
    on_disk: list[int] = []
    planted = bench.measure_isolated

    def fake(*args, **kwargs):
        on_disk.append(_measured_in(out))
        return planted(*args, **kwargs)

    monkeypatch.setattr(bench, "measure_isolated", fake)
    assert main(["bench", "--quick", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["complete"] is True and list(report)[0] == "complete"
    assert report["workloads"]["sweep"]["numba"] == dict(PLANTED, backend="numba")
    n = len(started)
    assert n == sum(2 + (not w.forward_only) + (name in bench.FUSED_WORKLOADS) + 2 * (name in bench.TASK_WORKLOADS)
                    for name, w in bench.WORKLOADS.items()) + 2 * 2  # --quick: batch sizes 1 and 64
    assert on_disk == list(range(n)) and _measured_in(out) == n


def test_an_unwritable_out_fails_before_any_measurement(tmp_path, monkeypatch, capsys):
    (tmp_path / "afile").write_text("x")
    started = _plant(monkeypatch, interrupt_at=None)
    assert main(["bench", "--quick", "--out", str(tmp_path / "afile" / "b.json")]) == 1
    assert started == []
    err = capsys.readouterr().err
    assert err.startswith("bptsb bench: cannot write --out") and err.count("\n") == 1


@pytest.mark.parametrize("kind", [KeyboardInterrupt, RuntimeError])
def test_run_benchmarks_reports_each_measurement_as_it_goes(monkeypatch, kind):
    snapshots: list[str] = []
    calls = {"n": 0}

    def fake(w, adjoint, dtype="float32", min_seconds=3.0, backend="torch", numba_cache=None):
        calls["n"] += 1
        if calls["n"] == 3:
            raise kind("stop")
        return {"train_steps_per_s": float(calls["n"])}

    monkeypatch.setattr(bench, "measure_isolated", fake)
    with pytest.raises(kind):
        bench.run_benchmarks(quick=True, progress=lambda _: None, update=lambda r: snapshots.append(json.dumps(r)))
    assert len(snapshots) == 2
    assert json.loads(snapshots[0])["workloads"]["lissajous"]["torch"] == {"train_steps_per_s": 1.0}
    assert json.loads(snapshots[1])["workloads"]["lissajous"]["numba"] == {"train_steps_per_s": 2.0}
