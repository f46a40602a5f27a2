"""``bptsb bench --realtime`` without DDS: the statistics from planted per-step records (hand values), the body's
records in a realtime loop driven by a fake clock, the timing file, the report and table, and the CLI's options on
both sides (the runs themselves replaced by a planted report, the --out file rewritten after each condition). A real
body's records are checked in ``test_ros_loop`` (its realtime Ctrl-C run writes them)."""

from __future__ import annotations

import argparse
import array
import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT
from live_fakes import FakePort, core

from bptsb_ros.interface.params import ParameterError
from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.step_times import FIELDS, StepTimes, load_step_times, timing_statistics

PERIOD = 0.01


def planted() -> dict[str, np.ndarray]:
    """101 steps at 100 Hz: compute k·0.05 ms (half integrating, half publishing), on time except steps 10 (9 ms
    late: 9.5 ms in all, no miss), 30 (8.6 ms late + 1.5 ms = 10.1 ms: a miss) and 90 (7 ms + 4.5 ms: a miss)."""
    k = np.arange(101)
    due = k * PERIOD
    late = np.zeros(101)
    late[[10, 30, 90]] = [9e-3, 8.6e-3, 7e-3]
    began = due + late
    compute = k * 5e-5
    return {"due": due, "began": began, "integrated": began + compute / 2, "done": began + compute}


def test_statistics_of_planted_records_are_the_hand_values():
    s = timing_statistics(**planted(), period=PERIOD)
    assert s["steps"] == 101 and s["deadline_misses"] == 2
    assert s["deadline_miss_pct"] == pytest.approx(100 * 2 / 101)
    # compute 0, 0.05, ..., 5 ms: linear p50 of 0..100 is 50, p99 is 99 (x 0.05 ms)
    assert (s["compute_p50_ms"], s["compute_p99_ms"], s["compute_max_ms"]) == pytest.approx((2.5, 4.95, 5.0))
    assert (s["integrate_p99_ms"], s["publish_max_ms"]) == pytest.approx((2.475, 2.5))
    # period jitter: |late_k - late_(k-1)| = 9, 9, 8.6, 8.6, 7, 7 ms and 94 zeros (100 periods): p99 at rank 98.01
    assert (s["period_jitter_p50_ms"], s["period_jitter_p99_ms"], s["period_jitter_max_ms"]) == pytest.approx(
        (0.0, 9.0, 9.0))
    assert (s["lateness_p50_ms"], s["lateness_max_ms"]) == pytest.approx((0.0, 9.0))


def test_a_deadline_is_the_next_steps_due_time():
    r = planted()
    assert timing_statistics(**r, period=0.0106)["deadline_misses"] == 1  # 10.1 ms is inside a 10.6 ms period
    assert timing_statistics(**r, period=0.0094)["deadline_misses"] == 3  # 9.5 ms is not inside 9.4 ms


def test_step_times_grow_save_and_load(tmp_path: Path):
    times = StepTimes(rows=2)
    rows = [(k, 0.01 * k, 0.01 * k + 1e-4, 0.01 * k + 3e-4, 0.01 * k + 7e-4) for k in range(5)]
    for row in rows:
        times.append(*row)
    assert len(times) == 5
    times.save(tmp_path / "t" / "times.npz", PERIOD, {"executor": "events"})
    back = load_step_times(tmp_path / "t" / "times.npz")
    for i, name in enumerate(FIELDS):
        np.testing.assert_array_equal(back[name], [row[i] for row in rows])
    assert back["period"] == PERIOD and back["executor"] == "events"
    assert [p.name for p in (tmp_path / "t").iterdir()] == ["times.npz"]  # no temporary file left
    long = StepTimes()  # ten minutes at 100 Hz: the executor is still read (a 4 KiB bound on the file lost it)
    for k in range(60_001):
        long.append(k, 0.01 * k, 0.01 * k, 0.01 * k, 0.01 * k)
    long.save(tmp_path / "long.npz", PERIOD, {"executor": "events"})
    assert load_step_times(tmp_path / "long.npz")["executor"] == "events"


def test_a_bad_timing_file_is_one_line(tmp_path: Path):
    np.savez(tmp_path / "bad.npz", step=np.zeros(3), due=np.zeros(3), began=np.zeros(2), integrated=np.zeros(3),
             done=np.zeros(3), period=np.array(0.01))
    with pytest.raises(ValueError, match="equal length"):
        load_step_times(tmp_path / "bad.npz")
    np.savez(tmp_path / "p.npz", **{n: np.zeros(3) for n in FIELDS}, period=np.array(-1.0))
    with pytest.raises(ValueError, match="period must be a positive"):
        load_step_times(tmp_path / "p.npz")


@pytest.mark.parametrize("cost, misses", [(0.004, 0), (0.012, 11)])
def test_the_realtime_loop_records_every_step(cost: float, misses: int):
    """A fake clock: each step's publishing costs ``cost``; the records hold the schedule, the planted cost, and
    misses that agree with the body's own counter (0 below the 10 ms period, every step above it)."""
    c = core(mode="realtime", max_steps=10, timing_path="unused.npz")
    port = FakePort(c, cost=cost)
    BodyLoop(c, port).run()
    r = c.step_times.columns()
    assert r["step"].tolist() == list(range(11))
    np.testing.assert_allclose(r["due"] - r["due"][0], np.arange(11) * PERIOD, atol=1e-12)
    np.testing.assert_allclose(r["done"] - r["integrated"], cost, atol=1e-12)  # the fake port's publishing
    np.testing.assert_array_equal(r["integrated"], r["began"])  # the fake clock does not move while integrating
    s = timing_statistics(r["due"], r["began"], r["integrated"], r["done"], PERIOD)
    assert s["deadline_misses"] == misses == c.stats.deadline_misses


def test_timing_records_are_realtime_only():
    with pytest.raises(ParameterError, match="timing_path.*realtime only"):
        core(mode="lockstep", timing_path="t.npz")
    assert core(mode="realtime").step_times is None


def test_condition_result_counts_late_commands_and_targets():
    from bptsb_ros.bench.realtime import condition_result, realtime_table

    summary = {"deadline_misses": 2, "rest_length_rejected_stale": 3, "force_rejected_stale": 2,
               "rest_length_rejected_wrong_length": 7, "safe_command_steps": 1, "cpus": "1,3"}
    r = condition_result(summary, {**planted(), "period": PERIOD, "executor": "single"})
    assert r["late_commands"] == 5 and r["deadline_misses_counted_by_body"] == 2 and r["executor"] == "single"
    assert r["cpus"] == "1,3"  # what the body got, from its summary
    assert r["targets_met"] == {"deadline_misses": False, "compute_p99_ms": False, "period_jitter_p99_ms": False}
    calm = {"due": np.arange(5) * PERIOD, "began": np.arange(5) * PERIOD + 1e-4}
    calm.update(integrated=calm["began"] + 1e-4, done=calm["began"] + 2.9e-4)  # compute 0.29 ms: within 0.3
    ok = condition_result({}, {**calm, "period": PERIOD})
    assert ok["cpus"] == "any"  # a summary without it: not pinned
    assert ok["targets_met"] == {"deadline_misses": True, "compute_p99_ms": True, "period_jitter_p99_ms": True}
    calm["done"] = calm["began"] + 3.1e-4
    assert condition_result({}, {**calm, "period": PERIOD})["targets_met"]["compute_p99_ms"] is False
    table = realtime_table({"conditions": {
        "idle": {**r, "busy_processes": 0, "launch_exit_code": 1, "launch_problem": "brain silent"},
        "busy": {"error": "planted", "busy_processes": 1}}})
    lines = table.splitlines()
    assert lines[1].split()[:6] == ["idle", "(0", "busy)", "101", "2", "1.98"]
    assert "4.950" in lines[1] and lines[2:4] == ["idle: the launch exited 1: brain silent", "busy: error: planted"]
    assert "idle: no deadline miss: NOT met" in table


# -- the CLI ------------------------------------------------------------------------------------------------------
def parse(argv: list[str]) -> argparse.Namespace:
    from bptsb_ros.cli import bench_cmd

    parser = argparse.ArgumentParser()
    bench_cmd.add_arguments(parser)
    return parser.parse_args(argv)


@pytest.fixture
def calls(monkeypatch):
    """The bench's runs replaced by a planted report; the arguments they were given."""
    import bptsb_ros.bench.realtime as rb
    import bptsb_ros.bench.soak as soak

    seen: list[tuple] = []
    seen_out: list[str] = []

    def fake_bench(seconds, busy, *, executor, rt_priority, cpus, workdir, update, progress, factor, anchor_seconds):
        seen.append(("realtime", seconds, busy, executor, rt_priority) + ((factor,) if factor else ())
                    + ((cpus,) if cpus else ()) + ((("anchor", anchor_seconds),) if anchor_seconds != seconds else ()))
        report = {"conditions": {"idle": {"steps": 7, "busy_processes": 0}}}
        update(report)  # the first condition done: on disk, marked incomplete, before the second one runs
        seen.append(("on disk", json.loads(Path(seen_out[0]).read_text())))
        return report

    def fake_soak(realtime_seconds, lockstep_seconds, realtime_busy, lockstep_busy, workdir, progress):
        seen.append(("soak", realtime_seconds, realtime_busy))
        return {}

    monkeypatch.setattr(rb, "run_realtime_bench", fake_bench)
    monkeypatch.setattr(soak, "run_soak", fake_soak)
    return seen, seen_out


def test_realtime_options_and_their_defaults(tmp_path: Path, calls, capsys):
    from bptsb_ros.cli import bench_cmd

    seen, seen_out = calls
    out = tmp_path / "rt.json"
    seen_out.append(str(out))
    assert bench_cmd.run(parse(["--realtime", "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 600.0, 1, "events", 0)  # the default: 10 minutes, one core busy
    assert seen[-1] == ("on disk", {"complete": False, "conditions": {"idle": {"steps": 7, "busy_processes": 0}}})
    assert json.loads(out.read_text()) == {"complete": True, "conditions": {"idle": {"steps": 7,
                                                                                     "busy_processes": 0}}}
    assert bench_cmd.run(parse(["--realtime", "--realtime-seconds", "30", "--realtime-busy", "2", "--executor",
                                "single", "--rt-priority", "99", "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 30.0, 2, "single", 99)
    factor = ["--realtime", "--realtime-factor", "10", "--rt-priority", "10", "--out", str(out)]
    assert bench_cmd.run(parse(factor)) == 0
    assert seen[-2] == ("realtime", 600.0, 1, "events", 10, 10.0)  # the 10x real-time condition too
    assert bench_cmd.run(parse(["--realtime", "--cpus", "1", "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 600.0, 1, "events", 0, "1")  # the body and its brains on CPU 1
    assert bench_cmd.run(parse(["--realtime", "--cpus", "010,3-4", "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 600.0, 1, "events", 0, "3,4,10")  # plain numbers: ROS reads 010 as octal 8
    assert bench_cmd.run(parse(["--realtime", "--realtime-anchor-seconds", "0", "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 600.0, 1, "events", 0, ("anchor", 0.0))  # no paced anchor
    assert bench_cmd.run(parse(["--realtime", "--realtime-seconds", "60", "--realtime-anchor-seconds", "30",
                                "--out", str(out)])) == 0
    assert seen[-2] == ("realtime", 60.0, 1, "events", 0, ("anchor", 30.0))  # (by default as long as a condition)
    assert bench_cmd.run(parse(["--soak", "--out", str(out)])) == 0
    assert seen[-1] == ("soak", 60.0, 1)  # the soak keeps its own default
    assert "idle (0 busy)  7" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--realtime-seconds", "0"], "--realtime-seconds must be > 0"),
    (["--realtime-seconds", "nan"], "--realtime-seconds must be > 0"),
    (["--realtime-busy", "0"], "--realtime-busy must be >= 1"),
    (["--rt-priority", "100"], "--rt-priority must be in 0..99"),
    (["--rt-priority", "-1"], "--rt-priority must be in 0..99"),
    (["--realtime-factor", "-2"], "--realtime-factor must be in 0..1000"),
    (["--realtime-factor", "inf"], "--realtime-factor must be in 0..1000"),
    (["--soak"], "--soak and --realtime are two different benches"),
    (["--realtime-anchor-seconds", "-1"], "--realtime-anchor-seconds must be >= 0"),
    (["--realtime-anchor-seconds", "nan"], "--realtime-anchor-seconds must be >= 0"),
    (["--cpus", "1-0"], "--cpus: the range '1-0' runs backwards"),
    (["--cpus", "one"], "--cpus: 'one' is not a CPU number"),
])
def test_bad_realtime_options_are_one_line(tmp_path: Path, calls, capsys, argv, message):
    from bptsb_ros.cli import bench_cmd

    assert bench_cmd.run(parse(["--realtime", *argv, "--out", str(tmp_path / "x.json")])) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and not calls[0]


@pytest.mark.parametrize("bad", ["multi", "auto"])
def test_executor_choices_are_the_nodes(capsys, bad):
    """--executor takes the values of the nodes' executor parameter (events, single) and nothing else."""
    assert parse(["--realtime", "--executor", "single", "--out", "x"]).executor == "single"
    with pytest.raises(SystemExit) as exit_:
        parse(["--realtime", "--executor", bad, "--out", "x"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and f"invalid choice: '{bad}'" in err
    assert err.split("(choose from ")[1].replace("'", "").startswith("events, single)")


def test_fifo_priority_is_set_or_refused_in_one_line():
    """In a child process (the policy sticks to the thread): priority 0 is not a SCHED_FIFO priority, so it is
    refused with the reason; priority 1 is taken where the process may (root), else refused the same way."""
    import os
    import subprocess
    import sys

    code = ("import os; from bptsb_ros.live.scheduling import set_fifo_priority as s; "
            "print(repr(s(0))); print(repr(s(1))); print(os.sched_getscheduler(0) == os.SCHED_FIFO)")
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env=env).stdout.split("\n")
    assert "SCHED_FIFO priority 0 refused (Invalid argument" in lines[0]
    privileged = os.geteuid() == 0
    assert (lines[1] == "''") == privileged and lines[2] == str(privileged)
    if not privileged:
        assert "SCHED_FIFO priority 1 refused" in lines[1]


def test_a_process_goes_realtime_with_its_other_threads_one_below():
    """``set_fifo_priority_of_process`` in a child process with a second thread: refused at priority 0 (nothing
    changed, no thread counted); at priority 2, where allowed (root), the calling thread at 2 and the other at 1."""
    import os
    import subprocess
    import sys

    code = ("import os, threading; from bptsb_ros.live.scheduling import set_fifo_priority_of_process as go\n"
            "hold = threading.Event(); ids = []\n"
            "t = threading.Thread(target=lambda: (ids.append(threading.get_native_id()), hold.wait())); t.start()\n"
            "while not ids: pass\n"
            "print(repr(go(0)))\n"
            "print(repr(go(2)))\n"
            "print([os.sched_getparam(i).sched_priority for i in (0, ids[0])])\n"
            "hold.set(); t.join()")
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env=env).stdout.split("\n")
    assert lines[0].startswith("('SCHED_FIFO priority 0 refused") and lines[0].endswith(", 0)")
    if os.geteuid() == 0:
        assert lines[1].startswith("('', ") and int(lines[1][5:-1]) >= 1 and lines[2] == "[2, 1]"
    else:
        assert "SCHED_FIFO priority 2 refused" in lines[1] and lines[2] == "[0, 0]"


@pytest.mark.parametrize("text, cpus", [("", set()), ("  ", set()), ("1", {1}), ("0,2", {0, 2}), ("0-3", {0, 1, 2, 3}),
                                        (" 1 , 3-4 ", {1, 3, 4}), ("2-2", {2}), ("1023", {1023})])
def test_cpus_are_read_as_taskset_writes_them(text, cpus):
    from bptsb_ros.live.scheduling import parse_cpus

    assert parse_cpus(text) == cpus


@pytest.mark.parametrize("text, message", [("x", "'x' is not a CPU number"), ("1-", "'1-' is not a CPU number"),
                                           ("-1", "'-1' is not a CPU number"), ("1,,2", "'' is not a CPU number"),
                                           ("3-1", "the range '3-1' runs backwards"), ("1.5", "'1.5' is not"),
                                           ("1024", "CPU 1024 is beyond 1023"), ("0-5000", "CPU 5000 is beyond")])
def test_bad_cpus_are_one_line(text, message):
    from bptsb_ros.interface.params import ParameterError
    from bptsb_ros.live.scheduling import parse_cpus

    with pytest.raises(ParameterError, match="^parameter 'cpus': " + re.escape(message)):
        parse_cpus(text)
    with pytest.raises(ParameterError, match="^--cpus: " + re.escape(message)):
        parse_cpus(text, "--cpus")


@pytest.mark.parametrize("value, text", [("0-1", "0-1"), (1, "1"), ([0, 2], "0,2"), ((3,), "3"),
                                         (array.array("q", [0, 2]), "0,2")])
def test_the_cpus_parameter_takes_what_ros_makes_of_a_list(value, text):
    """-p cpus:=1 arrives as an int and -p cpus:=[0,2] as an int array: both read as taskset text; a bool or a
    float does not."""
    from bptsb_ros.interface.params import CPUS, ParameterError, validate_values

    assert validate_values([CPUS], {"cpus": value}) == {"cpus": text}
    for bad in (True, 1.0, [1.5], [True]):
        with pytest.raises(ParameterError, match="parameter 'cpus' must be CPU numbers"):
            validate_values([CPUS], {"cpus": bad})


def test_threads_are_pinned_or_refused_in_one_line():
    """In a child process (affinity sticks to its threads): every thread, one started before and one started after,
    runs on the one CPU asked for; a CPU the process may not use is refused with the reason, nothing changed."""
    import os
    import subprocess
    import sys

    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one CPU allowed: pinned and not pinned look the same")
    cpu = max(os.sched_getaffinity(0))
    code = f"""
import os, threading
from bptsb_ros.live.scheduling import pin_threads
stop = threading.Event()
before = threading.Thread(target=stop.wait)
before.start()
print(repr(pin_threads(frozenset({{4095}}))), os.sched_getaffinity(0) == os.sched_getaffinity(before.native_id))
print(repr(pin_threads(frozenset({{{cpu}}}))))
after = threading.Thread(target=stop.wait)
after.start()
print(sorted(set().union(*(os.sched_getaffinity(int(t)) for t in os.listdir("/proc/self/task")))))
stop.set()
"""
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env=env).stdout.splitlines()
    assert lines[0].startswith("'CPU(s) 4095 not available to this process (it may use ") and lines[0].endswith(
        "True"), lines
    assert lines[1] == "''" and lines[2] == f"[{cpu}]", lines


def test_a_condition_sets_the_executor_of_the_body_and_every_brain(tmp_path: Path, monkeypatch):
    """The launch a condition runs (subprocess replaced): the body's timing path and rt_priority (the brain's one
    below), and the same executor for body_sim and the loop's brain; a run that leaves no records is an error, not
    numbers."""
    import subprocess

    import bptsb_ros.bench.realtime as rb

    argvs = []
    monkeypatch.setattr(rb.subprocess, "run", lambda argv, **kw: argvs.append(argv) or subprocess.CompletedProcess(
        argv, 0))
    r = rb.realtime_run("idle", 3.0, 0, tmp_path, loop="lissajous_closed", agent="a", executor="single",
                        rt_priority=5, progress=lambda _: None, cpus="1")
    params = [argvs[0][i + 1] for i, arg in enumerate(argvs[0]) if arg == "--param"]
    assert sorted(params) == sorted([f"body_sim:timing_path:={tmp_path / 'idle' / 'step_times.npz'}",
                                     "body_sim:rt_priority:=5", "body_sim:executor:=single",
                                     "feedback_brain:executor:=single", "feedback_brain:rt_priority:=4",
                                     "body_sim:cpus:=1", "feedback_brain:cpus:=1"])
    assert r["cpus_asked"] == "1"
    assert argvs[0][argvs[0].index("--duration") + 1] == "3" and argvs[0][argvs[0].index("--agent") + 1] == "a"
    assert r["launch_exit_code"] == 0 and "no body summary or no timing records" in r["error"]
    assert argvs[0][argvs[0].index("--rate-scale") + 1] == "1"
    fast = rb.realtime_run("factor", 3.0, 0, tmp_path, loop="lissajous_closed", agent="a", executor="events",
                           rate_scale=10.0, progress=lambda _: None)
    assert argvs[1][argvs[1].index("--rate-scale") + 1] == "10" and fast["rate_scale"] == 10.0
    assert fast["cpus_asked"] == "any" and not any(":cpus:=" in arg for arg in argvs[1])  # none given: none set


@pytest.mark.ros
def test_the_loop_status_waits_for_slack_in_two_parts_and_not_forever():
    """``body_sim.diagnostics`` with the time left before the next step (``slack``): the summary and the message are
    two parts, each done only in a turn with more slack than twice what it took; overdue by 5 periods, both at once."""
    pytest.importorskip("rclpy")
    import time
    from types import SimpleNamespace

    from bptsb_ros.ros.body_outputs import DIAGNOSTICS_OVERDUE, BodyOutputs

    due = lambda: time.monotonic() - 0.01  # noqa: E731 - the status is due, not overdue
    published, summaries = [], []
    core = SimpleNamespace(summary=lambda: summaries.append(1) or {}, status=lambda s, e="": ("OK", "m", []))
    node = SimpleNamespace(p={"diagnostics_period": 1.0}, next_diagnostics=due(), _pending_status=None,
                           _diagnostics_cost=[0.001, 0.001], core=core,
                           _status=lambda *args: published.append(args), _refresh_graph=lambda slack: None)
    node._loop_status = lambda force=False, error="", slack=0.0: BodyOutputs._loop_status(node, force, error, slack)
    node.after_step = lambda: steps.append(1)
    steps = []
    BodyOutputs.diagnostics(node, slack=0.0005)  # 0.5 ms left, the summary took up to 1 ms: wait
    assert summaries == [] and published == []
    BodyOutputs.diagnostics(node, slack=1.0)  # plenty: both parts in one turn
    assert len(summaries) == 1 and len(published) == 1 and node._pending_status is None
    assert node.next_diagnostics > time.monotonic()  # the next one a period on
    node.next_diagnostics, node._diagnostics_cost = due(), [0.0, 0.001]  # the summary fits, the message does not
    BodyOutputs.diagnostics(node, slack=0.0005)
    assert len(summaries) == 2 and len(published) == 1 and node._pending_status is not None
    node._diagnostics_cost = [1.0, 1.0]
    BodyOutputs.diagnostics(node, slack=0.0005)  # still no time: nothing more
    assert len(published) == 1
    node.next_diagnostics = time.monotonic() - (DIAGNOSTICS_OVERDUE + 1) * 1.0  # overdue: whatever the slack
    BodyOutputs.diagnostics(node, slack=0.0)
    assert len(published) == 2 and len(summaries) == 2 and node._pending_status is None
    BodyOutputs.diagnostics(node, force=True)  # the final status: at once
    assert len(published) == 3 and len(summaries) == 3
    assert len(steps) == 6  # after every call, whether the status went out or not (a hosted recorder's turn)


@pytest.mark.ros
@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
def test_the_periodic_graph_query_of_a_realtime_body_waits_for_slack_and_not_forever(mode):
    """``body_sim._untrusted``: the publishers of a command topic are looked up again when their count changes (at
    once) and every GRAPH_PERIOD; a realtime body does the periodic lookup in the slack after a step
    (``_refresh_graph``, when the slack exceeds what a lookup took), at once when it is DIAGNOSTICS_OVERDUE periods
    late; a lockstep body at once."""
    pytest.importorskip("rclpy")
    from types import SimpleNamespace

    from bptsb_ros.ros.body_graph import GRAPH_PERIOD
    from bptsb_ros.ros.body_outputs import DIAGNOSTICS_OVERDUE
    from bptsb_ros.ros.body_sim import BodySim

    count, names, lookups = [1], [[("/", "feedback_brain")]], []
    rule = SimpleNamespace(untrusted=lambda found: [n for _, n in found if n != "feedback_brain"])
    node = SimpleNamespace(p={"mode": mode}, _intruders={}, _graph_due=set(), _graph_cost=0.001,
                           subs={"rest_length": SimpleNamespace(get_publisher_count=lambda: count[0], topic_name="/t")},
                           core=SimpleNamespace(publisher_rules={"rest_length": rule}),
                           _publisher_names=lambda topic: lookups.append(topic) or names[0])
    node._query_untrusted = lambda *a: BodySim._query_untrusted(node, *a)
    untrusted = lambda now: BodySim._untrusted(node, "rest_length", now)  # noqa: E731
    assert untrusted(0.0) == [] and len(lookups) == 1
    names[0] = [("/", "intruder")]  # the trusted publisher replaced, the count the same
    assert untrusted(0.9 * GRAPH_PERIOD) == [] and len(lookups) == 1
    late = 1.1 * GRAPH_PERIOD
    if mode == "lockstep":
        assert untrusted(late) == ["intruder"] and len(lookups) == 2
        return
    assert untrusted(late) == [] and len(lookups) == 1 and node._graph_due == {"rest_length"}
    BodySim._refresh_graph(node, slack=0.0005)  # less slack than a lookup took: later
    assert len(lookups) == 1 and node._graph_due == {"rest_length"}
    BodySim._refresh_graph(node, slack=0.01)
    assert len(lookups) == 2 and node._graph_due == set() and untrusted(late) == ["intruder"]
    names[0] = [("/", "feedback_brain")]
    seen = node._intruders["rest_length"][1]
    assert untrusted(seen + (DIAGNOSTICS_OVERDUE + 0.1) * GRAPH_PERIOD) == [] and len(lookups) == 3  # overdue
    count[0] = 2  # a publisher more: at once
    names[0] = [("/", "feedback_brain"), ("/", "intruder")]
    assert untrusted(seen + (DIAGNOSTICS_OVERDUE + 0.2) * GRAPH_PERIOD) == ["intruder"] and len(lookups) == 4


def test_a_condition_runs_the_paced_anchor_at_the_loops_period_priority_and_cpus(tmp_path: Path, monkeypatch):
    """After the launch (replaced: it leaves a planted summary and timing records at 1 kHz, and takes 60 s of a
    fake clock), the paced anchor runs at the records' period, the body's priority and default busy_wait, the CPUs
    asked for (another 60 s), and only then are the busy processes stopped; the condition's wall time is the
    launch's; the anchor's numbers go into the condition and the table, its failure (returned or raised) into a
    note; ``anchor_seconds`` 0 runs none."""
    import subprocess

    import bptsb_ros.bench.realtime as rb
    import bptsb_ros.bench.soak as soak
    import bptsb_ros.ros.anchor as anchor

    events: list = []
    clock = [1000.0]

    def launch(argv, **kw):
        work = tmp_path / argv[argv.index("--log-dir") + 1].rsplit("/", 1)[-1]
        times = StepTimes()
        for k in range(3):
            times.append(k, 1e-3 * k, 1e-3 * k, 1e-3 * k + 1e-4, 1e-3 * k + 2e-4)
        times.save(work / "step_times.npz", 1e-3, {"executor": "events"})
        (work / "body_summary.json").write_text(json.dumps({"deadline_misses": 0}))
        events.append("launch")
        clock[0] += 60.0
        return subprocess.CompletedProcess(argv, 0)

    def paced(seconds, period, **kw):
        events.append(("anchor", seconds, period, kw["priority"], kw["busy"], kw["cpus"]))
        clock[0] += 60.0
        if isinstance(planted[0], Exception):
            raise planted[0]
        return planted[0]

    kept = {"ticks": 5000, "pongs": 4999, "rt_priority": 10, "deadline_misses": 3, "deadline_miss_pct": 0.06,
            "compute_p50_ms": 0.05, "compute_p99_ms": 0.07, "lateness_p50_ms": 0.01, "lateness_p99_ms": 0.03,
            "lateness_max_ms": 1.5, "period_ms": 1.0, "pong_problem": "refused"}
    planted: list[dict | Exception] = [{**kept, "steps": 5000, "integrate_p99_ms": 0.0}]
    monkeypatch.setattr(rb.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(rb.subprocess, "run", launch)
    monkeypatch.setattr(anchor, "run_paced_anchor", paced)
    monkeypatch.setattr(soak, "start_busy", lambda n: events.append(("busy", n)) or [])
    monkeypatch.setattr(soak, "stop_busy", lambda procs: events.append("stop busy"))
    r = rb.realtime_run("factor", 5.0, 1, tmp_path, loop="lissajous_closed", agent="a", executor="events",
                        rt_priority=10, rate_scale=10.0, cpus="1", anchor_seconds=5.0, progress=lambda _: None)
    assert events == [("busy", 1), "launch", ("anchor", 5.0, 1e-3, 10, 0.002, "1"), "stop busy"]
    assert r["wall_s"] == 60.0  # the launch alone, not the anchor after it
    assert r["anchor"] == {**kept, "seconds": 5.0}  # what ANCHOR_KEYS keep: not the step-loop-only statistics
    assert (r["anchor_deadline_misses"], r["anchor_compute_p99_ms"]) == (3, 0.07)
    heads = rb.realtime_table({"conditions": {"factor": r}}).splitlines()[:2]
    assert heads[0].split()[-4:] == ["anchor", "misses", "anchor", "p99"] and heads[1].split()[-2:] == ["3", "0.070"]
    for planted[0], said in (({"error": "the paced anchor exited 1: refused"}, "the paced anchor exited 1: refused"),
                             (ValueError("bad JSON"), "the paced anchor could not run: bad JSON")):
        failed = rb.realtime_run("idle", 5.0, 0, tmp_path, loop="lissajous_closed", agent="a", executor="events",
                                 anchor_seconds=5.0, progress=lambda _: None)
        assert failed["anchor"] == {"error": said, "seconds": 5.0}
        assert "anchor_deadline_misses" not in failed and failed["deadline_misses"] == 0
        assert f"idle: the paced anchor failed: {said}" in rb.realtime_table({"conditions": {"idle": failed}})
    events.clear()
    none = rb.realtime_run("idle", 5.0, 0, tmp_path, loop="lissajous_closed", agent="a", executor="events",
                           progress=lambda _: None)
    assert "anchor" not in none and not [e for e in events if e[0] == "anchor"]


def test_the_bench_runs_the_anchor_as_long_as_a_condition_unless_told(tmp_path: Path, monkeypatch):
    """``run_realtime_bench``: anchor_seconds None is each condition's length, 0 none, S that long."""
    import bptsb_ros.bench.realtime as rb

    seen: list[float] = []
    monkeypatch.setattr(rb, "realtime_run", lambda name, seconds, busy, work, **kw: seen.append(kw["anchor_seconds"])
                        or {})
    for asked in (None, 0.0, 7.0):
        rb.run_realtime_bench(30.0, agent="a", workdir=tmp_path, anchor_seconds=asked, progress=lambda _: None)
    assert seen == [30.0, 30.0, 0.0, 0.0, 7.0, 7.0]  # two conditions each


def test_a_failed_anchor_fails_the_bench(tmp_path: Path, monkeypatch, capsys):
    """The CLI's exit status: 1 when a condition's anchor failed, as when its launch did."""
    import bptsb_ros.bench.realtime as rb
    from bptsb_ros.cli import bench_cmd

    report = {"conditions": {"idle": {"steps": 7, "busy_processes": 0, "anchor": {"error": "planted"}}}}
    monkeypatch.setattr(rb, "run_realtime_bench", lambda *a, **kw: report)
    assert bench_cmd.run(parse(["--realtime", "--out", str(tmp_path / "rt.json")])) == 1
    assert "idle: the paced anchor failed: planted" in capsys.readouterr().out
    report["conditions"]["idle"]["anchor"] = {"deadline_misses": 0}
    assert bench_cmd.run(parse(["--realtime", "--out", str(tmp_path / "rt.json")])) == 0


@pytest.mark.parametrize("realtime, preempt, config, cmdline, expected", [
    ("1\n", "none voluntary (full) lazy\n", "CONFIG_PREEMPT_NONE=y\n", "", "full (realtime) ({realtime})"),
    ("0\n", "none voluntary (full) lazy\n", None, None, "full ({preempt})"),
    (None, None, "CONFIG_PREEMPT_BUILD=y\nCONFIG_PREEMPT_NONE=y\n# CONFIG_PREEMPT is not set\n", "quiet\n",
     "none (CONFIG_PREEMPT_NONE=y)"),
    (None, None, "CONFIG_PREEMPT_NONE=y\nCONFIG_PREEMPT_DYNAMIC=y\n", "quiet preempt=full\n",
     "full (preempt= boot option; built none)"),
    (None, None, "CONFIG_PREEMPT_NONE=y\n", "quiet preempt=full\n", "none (CONFIG_PREEMPT_NONE=y)"),  # not honoured
    (None, None, "CONFIG_PREEMPT_RT=y\nCONFIG_PREEMPT_DYNAMIC=y\n", "preempt=none\n",
     "full (realtime) (CONFIG_PREEMPT_RT=y)"),
    (None, None, "CONFIG_PREEMPT=y\nCONFIG_PREEMPT_COUNT=y\n", None, "full (CONFIG_PREEMPT=y)"),  # no cmdline
    (None, None, "CONFIG_PREEMPT_VOLUNTARY=y\n", "", "voluntary (CONFIG_PREEMPT_VOLUNTARY=y)"),
    (None, None, "CONFIG_HZ=250\n", "", "unknown"),
    (None, None, None, None, "unknown"),
])
def test_the_kernels_preemption_model_is_read_from_what_it_says(tmp_path: Path, realtime, preempt, config, cmdline,
                                                               expected):
    import gzip
    import os

    from bptsb_ros.bench.realtime import kernel_facts

    files = {name: tmp_path / name for name in ("realtime", "preempt", "config.gz", "config-plain", "cmdline")}
    for name, text in (("realtime", realtime), ("preempt", preempt), ("cmdline", cmdline)):
        if text is not None:
            files[name].write_text(text)
    if config is not None:
        files["config.gz"].write_bytes(gzip.compress(config.encode()))
    facts = kernel_facts(files["realtime"], files["preempt"], (files["config.gz"], files["config-plain"]),
                         files["cmdline"])
    assert facts["preemption"] == expected.format(realtime=files["realtime"], preempt=files["preempt"])
    assert facts["kernel"].split()[0] == os.uname().release
    if config is not None:  # the same configuration as a plain file (/boot/config-<release>) reads the same
        files["config.gz"].unlink()
        files["config-plain"].write_text(config)
        again = kernel_facts(files["realtime"], files["preempt"], (files["config.gz"], files["config-plain"]),
                             files["cmdline"])
        assert again["preemption"] == facts["preemption"]
