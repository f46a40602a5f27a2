"""The anchor of ``bptsb bench --live`` (:mod:`bptsb_ros.ros.anchor`): a bare rclpy ping-pong with a recorder, in
three processes (split) or with ping and pong in one process (composed), reports round trips per second measured
after its warm-up, and a wrong shape is refused."""

from __future__ import annotations

import pytest
from ros_live import env_for

pytest.importorskip("rclpy")


@pytest.mark.parametrize("shape", ["split", "composed"])
def test_the_anchor_measures_round_trips(shape, ros_env):
    from bptsb_ros.ros.anchor import WARM_UP, run_anchor

    result = run_anchor(shape, 1.0, env=env_for(ros_env))
    assert "error" not in result, result
    assert result["shape"] == shape and result["round_trips"] > 10
    assert result["round_trips_per_s"] == pytest.approx(result["round_trips"] / result["wall_s"], rel=1e-3)
    assert 0.0 < result["rtt_p50_ms"] < 1000.0 and result["process_cpu_us_per_round_trip"] > 0
    assert result["wall_s"] >= 0.9 and WARM_UP == 200  # the timed second comes after 200 untimed round trips


def test_a_wrong_shape_is_refused():
    from bptsb_ros.ros.anchor import run_anchor

    with pytest.raises(ValueError, match="shape must be one of"):
        run_anchor("both", 1.0)


def test_the_paced_anchor_ticks_at_its_period_and_judges_like_the_body(ros_env):
    """The ``paced`` anchor of ``bptsb bench --realtime`` (normal scheduler: a test cannot count on SCHED_FIFO):
    one tick per period for the seconds asked, each judged by the body's rule."""
    from bptsb_ros.ros.anchor import run_paced_anchor

    r = run_paced_anchor(1.0, 0.01, env=env_for(ros_env))
    assert "error" not in r, r
    assert r["ticks"] == r["steps"] == 100 and r["period_ms"] == pytest.approx(10.0)
    assert r["pongs"] >= 90 and r["rt_priority"] == 0  # (the last pongs may come after the last tick)
    assert 0.0 <= r["lateness_p50_ms"] <= r["lateness_max_ms"]
    assert 0.0 < r["compute_p50_ms"] <= r["compute_p99_ms"]  # the publish of each ping


def test_a_tick_is_a_miss_when_it_ends_after_the_next_is_due():
    """``_Tick.result`` on planted times (hand values): 4 ticks every 10 ms; the third starts 9 ms late and
    publishes for 2 ms (ends 11 ms after its due time: a miss), the second ends 9.9 ms after its due time (no miss);
    a run stopped before its first tick reports none."""
    import numpy as np

    from bptsb_ros.ros.anchor import _Tick

    tick = object.__new__(_Tick)
    tick.period, tick.pongs = 0.01, 4
    due = np.arange(4) * 0.01
    began = due + [0.0, 9.8e-3, 9e-3, 0.0]
    tick.times = np.stack([due, began, began + [1e-4, 1e-4, 2e-3, 1e-4]])
    r = tick.result(4)
    assert (r["ticks"], r["deadline_misses"], r["period_ms"]) == (4, 1, 10.0)
    assert r["lateness_max_ms"] == pytest.approx(9.8) and r["compute_max_ms"] == pytest.approx(2.0)
    assert tick.result(2)["deadline_misses"] == 0 and r["pongs"] == 4
    assert tick.result(0) == {"ticks": 0, "pongs": 4, "period_ms": 10.0, "steps": 0}


@pytest.mark.parametrize("argv, message", [
    (["tick", "--period", "0"], "--period 0 is out of range"),
    (["tick", "--busy", "-1"], "--busy -1 is out of range"),
    (["tick", "--rt-priority", "100"], "--rt-priority 100 is out of range"),
    (["pong", "--cpus", "x"], "--cpus: 'x' is not a CPU number"),
])
def test_bad_anchor_options_are_one_line(argv, message):
    from bptsb_ros.ros.anchor import main

    said: list[str] = []
    assert main(argv, out=said.append) == 2
    assert len(said) == 1 and message in said[0], said


class _FakeProc:
    """A finished subprocess as ``_stop_all`` sees it."""

    def __init__(self, argv, code, stdout=None, said=""):
        self.argv, self.returncode = argv, code
        if stdout is not None:
            stdout.write(said)

    def poll(self):
        return self.returncode

    def wait(self, timeout=None):
        return self.returncode


@pytest.mark.parametrize("pong, tick, expected", [
    ((0, '{"warning": "SCHED_FIFO priority 9 refused"}\n'), (0, '{"ticks": 10, "pongs": 10}\n', ""),
     {"ticks": 10, "pongs": 10, "pong_problem": "SCHED_FIFO priority 9 refused"}),
    ((0, ""), (0, '{"ticks": 10, "pongs": 0}\n', ""),
     {"ticks": 10, "pongs": 0, "error": "the paced anchor's pong answered none of its 10 ticks"}),
    ((0, ""), (1, '{"error": "the paced anchor\'s pong did not match within 60 s"}\n', "a warning\n"),
     {"error": "the paced anchor: the paced anchor's pong did not match within 60 s"}),
    ((1, "Traceback\nboom\n"), (0, '{"ticks": 10, "pongs": 10}\n', ""),
     {"error": "the paced anchor's pong exited 1: boom"}),
    ((0, ""), (1, "", "Traceback\nRuntimeError: x\n"), {"error": "the paced anchor exited 1: RuntimeError: x"}),
])
def test_the_paced_anchor_starts_both_sides_and_reports_what_went_wrong(monkeypatch, pong, tick, expected):
    """``run_paced_anchor`` with its two processes replaced: the pong one priority below the tick, the period, busy
    time and CPUs passed on; the pong's refusal as ``pong_problem``; no answer, a tick's own error line, a pong
    that failed and a tick without a result each one ``error`` line."""
    import subprocess

    import bptsb_ros.ros.anchor as anchor

    argvs: list[list[str]] = []

    def popen(argv, **kw):
        argvs.append(argv)
        return _FakeProc(argv, pong[0], kw["stdout"], pong[1])

    def run(argv, **kw):
        argvs.append(argv)
        return subprocess.CompletedProcess(argv, tick[0], tick[1], tick[2])

    monkeypatch.setattr(anchor.subprocess, "Popen", popen)
    monkeypatch.setattr(anchor.subprocess, "run", run)
    assert anchor.run_paced_anchor(2.0, 0.001, priority=10, busy=0.002, cpus="1") == expected
    pong_argv, tick_argv = argvs
    for argv, role, priority in ((pong_argv, "pong", "9"), (tick_argv, "tick", "10")):
        assert argv[3] == role and argv[argv.index("--rt-priority") + 1] == priority
        assert argv[argv.index("--period") + 1] == "0.001" and argv[argv.index("--seconds") + 1] == "2.0"
        assert argv[argv.index("--cpus") + 1] == "1"
    assert tick_argv[tick_argv.index("--busy") + 1] == "0.002" and "--busy" not in pong_argv


@pytest.mark.parametrize("busy, polls", [(0.002, True), (0.0, False)])
def test_a_tick_sleeps_then_polls_until_its_due_time(monkeypatch, busy, polls):
    """``_Tick.run`` on a fake clock (each spin advances it by its timeout, 0.1 ms for a poll): tick k is due one
    period after the start plus k periods, starts no earlier, and under ``busy`` the last part before it is polled
    (timeout 0; at most half a period: 2 ms of a 3 ms period is cut to 1.5 ms); a stop ends it after the tick done."""
    import numpy as np

    import bptsb_ros.ros.anchor as anchor

    clock = [50.0]
    timeouts: list[float] = []
    published: list[float] = []
    stop: list[int] = []
    armed: list[bool] = []

    class Executor:
        def spin_once(self, timeout_sec):
            timeouts.append(timeout_sec)
            clock[0] += timeout_sec or 1e-4

    class Pub:
        def publish(self, _payload):
            published.append(clock[0])
            clock[0] += 5e-5
            if armed and len(published) == 3:
                stop.append(2)

    monkeypatch.setattr(anchor.time, "monotonic", lambda: clock[0])
    tick = object.__new__(anchor._Tick)
    tick.payload, tick.pub, tick.period, tick.busy = b"", Pub(), 0.003, min(busy, 0.0015)
    tick.times = np.zeros((3, 5))
    assert tick.run(Executor(), []) == 5
    due, began, done = tick.times
    np.testing.assert_allclose(due, 50.0 + 0.003 * np.arange(1, 6))
    assert np.all(began >= due) and np.all(began - due < 1.5e-4) and np.allclose(done - began, 5e-5)
    zero = sum(1 for t in timeouts if t == 0.0)
    assert (zero >= 5 * 14) if polls else zero == 0  # 1.5 ms of 0.1 ms polls before each of the 5 ticks
    assert max(timeouts) <= 0.05
    published.clear()
    armed.append(True)
    assert tick.run(Executor(), stop) == 3  # stopped after the third tick
