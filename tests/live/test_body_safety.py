"""The live body's safety rules, ROS-free: physical bounds on commands and wind,
commands stamped beyond the next step, the publisher rule, and divergence recovery."""

from __future__ import annotations

import numpy as np
import pytest

from bptsb_ros.live.channels import CommandChannel
from bptsb_ros.live.safety import (
    CommandLimits,
    DivergenceRecovery,
    PublisherRule,
    WindIntake,
    body_extent,
    rest_length_floor,
)

LIMITS = CommandLimits(max_rest_length=5.0, max_force=100.0, max_wind=10.0)


def test_body_extent_and_default_rest_length_limit():
    square = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0], [0.0, 4.0]])
    assert body_extent(square) == 5.0
    assert CommandLimits.for_body(square).max_rest_length == 50.0  # 10 × the extent
    assert CommandLimits.for_body(square, max_rest_length=2.0).max_rest_length == 2.0
    with pytest.raises(ValueError, match="max_force"):
        CommandLimits(1.0, max_force=float("inf"))


@pytest.mark.parametrize("values, bad", [([1.0, -1.0], "-1 at index 1"), ([1.0, 0.0], "0 at index 1"),
                                         ([1e30, 1.0], "1e+30 at index 0"), ([5.0000001, 1.0], "at index 0")])
def test_rest_lengths_must_lie_in_zero_to_max(values, bad):
    assert bad in LIMITS.check("rest_length", np.array(values)) and "(0, 5] m" in LIMITS.check("rest_length",
                                                                                               np.array(values))
    assert LIMITS.check("rest_length", np.array([5.0, 1e-9])) is None


def test_forces_and_wind_are_bounded():
    assert LIMITS.check("force", np.array([100.0, -100.0])) is None
    assert "[-100, 100] N" in LIMITS.check("force", np.array([0.0, -100.5]))
    wind = WindIntake(LIMITS)
    assert wind.offer(np.array([10.0, -10.0])) is None
    assert "[-10, 10] N" in wind.offer(np.array([1e30, 0.0]))
    assert "NaN/inf" in wind.offer(np.array([np.nan, 0.0]))
    assert wind.counts() == {"accepted": 1, "rejected_non_finite": 1, "rejected_out_of_bounds": 1,
                             "rejected_untrusted_publisher": 0}


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_channel_rejects_out_of_bounds_and_future_commands(mode):
    ch = CommandChannel("rest_length", 2, ["s0", "s1"], mode, bounds=lambda v: LIMITS.check("rest_length", v))
    assert ch.offer(3, np.array([1.0, -1.0]), 3, 0.0).reason == "out_of_bounds"
    assert ch.offer(5, np.array([1.0, 1.0]), 3, 0.0).reason == "too_far_ahead"  # two steps beyond the next
    assert ch.offer(4, np.array([1.0, 2.0]), 3, 0.0) is None  # the step after the next one is fine
    late = ch.offer(3, np.array([1.0, 1.0]), 3, 0.0)  # the next step, offered after the one beyond it
    if mode == "lockstep":  # buffered by step: step 3 is still to come, so it is queued beside step 4
        assert late is None and ch.has(3) and ch.has(4)
    else:  # realtime takes the newest: a command older than the latest accepted is stale
        assert late.reason == "stale" and "not newer than the latest (4)" in late.message
    counts = ch.counts()
    assert counts["rejected_stale"] == (1 if mode == "realtime" else 0)
    assert counts["rejected_out_of_bounds"] == counts["rejected_too_far_ahead"] == 1
    assert ch.reject(3, "untrusted_publisher", "x").reason == "untrusted_publisher"
    assert ch.counts()["rejected_untrusted_publisher"] == 1


def test_publisher_rule():
    rule = PublisherRule("rest_length")
    assert rule.allowed == ("swg_brain", "feedback_brain")
    assert rule.untrusted([("/", "swg_brain"), ("/", "feedback_brain")]) == []
    assert rule.untrusted([("/", "swg_brain"), ("/evil", "intruder"), ("/", "_NODE_NAME_UNKNOWN_")]) == [
        "/_NODE_NAME_UNKNOWN_", "/evil/intruder"]
    assert PublisherRule("force").untrusted([("/", "swg_brain")]) == ["/swg_brain"]
    pinned = PublisherRule("force", ("/robot/mlp_brain",))
    assert pinned.untrusted([("/robot", "mlp_brain"), ("/other", "mlp_brain")]) == ["/other/mlp_brain"]
    assert PublisherRule("force", ("*",)).untrusted([("/", "anyone")]) == []


def _problem(state):
    return None if np.isfinite(state).all() else "diverged"


def test_divergence_recovery_restores_resets_or_stops():
    good, bad = np.zeros(2), np.array([np.inf, 0.0])
    calls = []
    guard = DivergenceRecovery("restore")
    state, text = guard.recover(7, lambda: calls.append("retry") or good, lambda: calls.append("reset") or good,
                                _problem)
    assert state is good and calls == ["retry"] and "last good state (step 6)" in text
    state, text = guard.recover(8, lambda: bad, lambda: calls.append("reset") or good + 1, _problem)
    assert (state == 1).all() and calls[-1] == "reset" and "initial layout" in text
    state, text = guard.recover(9, lambda: bad, lambda: bad, _problem)
    assert state is None and "stopping" in text
    assert guard.events == 3
    stop = DivergenceRecovery("stop")
    state, text = stop.recover(1, lambda: good, lambda: good, _problem)
    assert state is None and "on_divergence: stop" in text and stop.events == 1
    with pytest.raises(ValueError, match="policy"):
        DivergenceRecovery("ignore")


def test_rest_length_floor_follows_the_agents_own_swg():
    rest = np.array([1.0, 2.0])
    assert rest_length_floor(rest, None) == 0.0
    assert rest_length_floor(rest, np.array([0.5, -0.9])) == 0.0  # l·(1 − |A|) > 0: commands stay positive
    # |A| = 1.5 on spring 0: its SWG reaches 1·(1 − 1.5) = −0.5; minus the largest swing max(1·1.5, 2·0.2) = 1.5
    assert rest_length_floor(rest, np.array([1.5, 0.2])) == -2.0
    limits = CommandLimits(5.0, min_rest_length=-2.0)
    assert limits.check("rest_length", np.array([-1.9, 1.0])) is None
    assert "(-2, 5] m" in limits.check("rest_length", np.array([-2.0, 1.0]))
