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
    assert 0 <= r["deadline_misses"] <= 100 and 0.0 <= r["lateness_p50_ms"] <= r["lateness_max_ms"]
    assert 0.0 < r["compute_p50_ms"] <= r["compute_p99_ms"]  # the publish of each ping


def test_a_tick_is_a_miss_when_it_ends_after_the_next_is_due():
    """``_Tick.result`` on planted times (hand values): 4 ticks every 10 ms; the third starts 9 ms late and
    publishes for 2 ms (ends 11 ms after its due time: a miss), the second ends 9.9 ms after its due time (no miss);
    a run stopped before its first tick reports none."""
    import numpy as np

    from bptsb_ros.ros.anchor import _Tick

    tick = object.__new__(_Tick)
    tick.period = 0.01
    due = np.arange(4) * 0.01
    began = due + [0.0, 9.8e-3, 9e-3, 0.0]
    tick.times = np.stack([due, began, began + [1e-4, 1e-4, 2e-3, 1e-4]])
    r = tick.result(4)
    assert (r["ticks"], r["deadline_misses"], r["period_ms"]) == (4, 1, 10.0)
    assert r["lateness_max_ms"] == pytest.approx(9.8) and r["compute_max_ms"] == pytest.approx(2.0)
    assert tick.result(2)["deadline_misses"] == 0 and tick.result(0) == {"ticks": 0, "period_ms": 10.0, "steps": 0}


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
