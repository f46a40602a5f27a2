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
