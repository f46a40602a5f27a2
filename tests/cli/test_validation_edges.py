"""Both sides of every validation, at its edge: the accepted limit and just past it, on each side.

One-sided tests let a check lose half of itself (``<`` for ``<=``, a lost ``or`` clause, a bound on one sign
only). Each table row is (value, accepted?): the accepted rows must pass the check *and* the refused rows must
raise an error naming the problem. Every expected verdict comes from the check's documented rule (docstring,
message or field description), not from running the code.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import re
import struct

import numpy as np
import pytest
import torch

from bptsb_ros.analysis.ipc import IPCError, ipc_groups
from bptsb_ros.body.msdn import MSDN
from bptsb_ros.body.shapes import MAX_MASSES, double_circle
from bptsb_ros.cli import main as cli_main
from bptsb_ros.cli.options import finite_float
from bptsb_ros.config import ConfigError, validate
from bptsb_ros.data import mnist
from bptsb_ros.data.mnist import MnistError, read_pair
from bptsb_ros.experiments.result import MAX_SLUG_LEN, Claim, ResultError, validate_result
from bptsb_ros.live.channels import CommandChannel
from bptsb_ros.live.loops import perturbation_problem
from bptsb_ros.live.safety import CommandLimits, DivergenceRecovery, runaway
from bptsb_ros.sim import wind_schedule as ws
from bptsb_ros.sim.perturbation import perturbation
from bptsb_ros.sim.wind_schedule import WindSchedule, WindScheduleError, read_table
from bptsb_ros.training.guard import UpdateGuard

TINY = 1e-9


def _verdict(accepted: bool, error: type[BaseException] | tuple[type[BaseException], ...], call, match: str = ""):
    """``call()`` must succeed when ``accepted``, else raise ``error`` whose message matches ``match``."""
    if accepted:
        return call()
    with pytest.raises(error, match=match):
        call()
    return None


# -- config.py: pydantic field bounds and the cross-field rules --------------------------------------------------

def _deep(base: dict, dotted: str, value) -> dict:
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    keys = dotted.split(".")
    node = out
    for k in keys[:-1]:
        node[k] = dict(node.get(k, {}))
        node = node[k]
    node[keys[-1]] = value
    return out


LISSAJOUS = {"task": "lissajous"}
NARMA = {"task": "narma", "brain": {"type": "mlp"}}
LOCOMOTION = {"task": "locomotion", "body": {"shape": "caterpillar", "nodes": 10}}

CONFIG_EDGES = [
    # (base, key, value, accepted)
    (LOCOMOTION, "body.nodes", 2, True),  # the field's bound (ge=2) on the caterpillar, which builds from 2 masses
    (LOCOMOTION, "body.nodes", 1, False),
    (LISSAJOUS, "body.nodes", MAX_MASSES, True),
    (LISSAJOUS, "body.nodes", MAX_MASSES + 1, False),
    (LISSAJOUS, "body.size", 1000.0, True),
    (LISSAJOUS, "body.size", 1000.0 + 1e-9, False),
    (LISSAJOUS, "body.size", TINY, True),
    (LISSAJOUS, "body.size", 0.0, False),
    (LISSAJOUS, "body.size", -TINY, False),
    (LISSAJOUS, "body.dt", 1.0, True),
    (LISSAJOUS, "body.dt", 1.0 + 1e-9, False),
    (LISSAJOUS, "body.dt", TINY, True),
    (LISSAJOUS, "body.dt", 0.0, False),
    (LISSAJOUS, "body.k_init", [0.0, 0.0], True),
    (LISSAJOUS, "body.k_init", [-TINY, 1.0], False),
    (LISSAJOUS, "body.k_init", [1.0, 1.0], True),
    (LISSAJOUS, "body.k_init", [1.0, 1.0 - TINY], False),
    (LISSAJOUS, "body.d_init", [0.0, 0.0], True),
    (LISSAJOUS, "body.d_init", [-TINY, 0.0], False),
    (LISSAJOUS, "body.d_init", [2.0, 1.0], False),
    (LISSAJOUS, "brain.omega", TINY, True),
    (LISSAJOUS, "brain.omega", 0.0, False),
    (LISSAJOUS, "training.update_steps", 1, True),
    (LISSAJOUS, "training.update_steps", 0, False),
    (LISSAJOUS, "training.reject_factor", 0.0, True),
    (LISSAJOUS, "training.reject_factor", -TINY, False),
    (LISSAJOUS, "training.reject_patience", 1, True),
    (LISSAJOUS, "training.reject_patience", 0, False),
    (LISSAJOUS, "training.checkpoint_every", 0, True),
    (LISSAJOUS, "training.checkpoint_every", -1, False),
    (LISSAJOUS, "training.log_every", 1, True),
    (LISSAJOUS, "training.log_every", 0, False),
    (LISSAJOUS, "training.lr.k", 0.0, True),
    (LISSAJOUS, "training.lr.k", -TINY, False),
    (LISSAJOUS, "feedback.noise", 0.0, True),
    (LISSAJOUS, "feedback.noise", -TINY, False),
    (LISSAJOUS, "feedback.fit_time", TINY, True),
    (LISSAJOUS, "feedback.fit_time", 0.0, False),
    (LISSAJOUS, "lissajous.amplitude_fraction", TINY, True),
    (LISSAJOUS, "lissajous.amplitude_fraction", 0.0, False),
    (LISSAJOUS, "lissajous.eval_periods", 1, True),
    (LISSAJOUS, "lissajous.eval_periods", 0, False),
    (LISSAJOUS, "sim_time", TINY, True),
    (LISSAJOUS, "sim_time", 0.0, False),
    (LISSAJOUS, "epochs", 1, True),
    (LISSAJOUS, "epochs", 0, False),
    (LISSAJOUS, "sim_time", math.inf, False),
    (NARMA, "narma.n_inputs", 10, False),  # the field allows 10, but then train_end (120) < n_inputs fails
    (NARMA, "narma.order", 1, True),
    (NARMA, "narma.order", 0, False),
    (NARMA, "narma.tau", 1, True),
    (NARMA, "narma.tau", 0, False),
    (NARMA, "narma.delay", 0, True),
    (NARMA, "narma.delay", -1, False),
    (NARMA, "narma.input_scale", TINY, True),
    (NARMA, "narma.input_scale", 0.0, False),
    (NARMA, "brain.hidden", 1, True),
    (NARMA, "brain.hidden", 0, False),
    (LOCOMOTION, "locomotion.target_slope", 0.0, True),
    (LOCOMOTION, "locomotion.target_slope", -TINY, False),
    (LOCOMOTION, "locomotion.warmup_windows", 0, True),
    (LOCOMOTION, "locomotion.warmup_windows", -1, False),
    (LOCOMOTION, "locomotion.eval_time", TINY, True),
    (LOCOMOTION, "locomotion.eval_time", 0.0, False),
    (LOCOMOTION, "locomotion.wind_period", 0.0, True),
    (LOCOMOTION, "locomotion.wind_period", -TINY, False),
]


@pytest.mark.parametrize("base, key, value, accepted", CONFIG_EDGES,
                         ids=[f"{b['task']}-{k}={v}" for b, k, v, _ in CONFIG_EDGES])
def test_config_field_edges(base, key, value, accepted):
    data = _deep(base, key, value)
    if accepted:
        validate(data)
        return
    with pytest.raises(ConfigError, match=key.split(".")[-1]):
        validate(data)


NARMA_SPLIT = [  # (washout, train_end, n_inputs, accepted): washout < train_end < n_inputs
    (0, 1, 10, True),
    (9, 10, 11, True),
    (10, 10, 11, False),
    (9, 11, 11, False),
    (9, 12, 11, False),
    (11, 10, 12, False),
]


@pytest.mark.parametrize("washout, train_end, n_inputs, accepted", NARMA_SPLIT)
def test_config_narma_split_edges(washout, train_end, n_inputs, accepted):
    data = {**NARMA, "narma": {"washout": washout, "train_end": train_end, "n_inputs": n_inputs}}
    _verdict(accepted, ConfigError, lambda: validate(data), "washout < train_end < n_inputs")


@pytest.mark.parametrize("update_steps, speed_block, accepted", [
    (100, 100, True), (200, 100, True), (100, 50, True), (99, 100, False), (101, 100, False), (150, 100, False),
])
def test_config_update_steps_multiple_of_speed_block(update_steps, speed_block, accepted):
    data = {**LOCOMOTION, "training": {"update_steps": update_steps}, "locomotion": {"speed_block": speed_block}}
    _verdict(accepted, ConfigError, lambda: validate(data), "multiple of")


@pytest.mark.parametrize("task, rates, accepted", [
    (LISSAJOUS, {"k": 0, "d": 0, "l": 0, "amplitude": 0, "phase": 0}, False),
    (LISSAJOUS, {"k": 0, "d": 0, "l": 0, "amplitude": 0, "phase": TINY}, True),
    (LISSAJOUS, {"k": 0, "d": 0, "l": 0, "amplitude": TINY, "phase": 0}, True),
    (LISSAJOUS, {"k": TINY, "d": 0, "l": 0, "amplitude": 0, "phase": 0}, True),
    # the brain rate does not train an SWG agent; the SWG rates do not train an MLP
    (LISSAJOUS, {"k": 0, "d": 0, "l": 0, "amplitude": 0, "phase": 0, "brain": 1.0}, False),
    (NARMA, {"k": 0, "d": 0, "l": 0, "brain": 0, "amplitude": 1.0, "phase": 1.0}, False),
    (NARMA, {"k": 0, "d": 0, "l": 0, "brain": TINY}, True),
])
def test_config_all_zero_learning_rates(task, rates, accepted):
    data = {**task, "training": {"lr": rates}}
    _verdict(accepted, ConfigError, lambda: validate(data), "every learning rate is zero")


# -- analysis/ipc.py -------------------------------------------------------------------------------------------

def _ipc(u_edge: float | None = None, **kw):
    rng = np.random.default_rng(0)
    n = kw.pop("n", 40)
    u = rng.uniform(-0.5, 0.5, n)
    if u_edge is not None:
        u[5] = u_edge
    x = np.stack([u, np.roll(u, 1)], axis=1)
    args = {"max_degree": 1, "max_delay": 2, "washout": 0, "threshold": "none", "surrogates": 0}
    args.update(kw)
    return ipc_groups(u, [x], **args)


@pytest.mark.parametrize("value, accepted", [
    (-1.0, True), (1.0, True), (-1.0 - 1e-12, True), (1.0 + 1e-12, True),  # the documented rounding allowance
    (-1.0 - 1e-9, False), (1.0 + 1e-9, False), (-1.5, False), (1.5, False),
])
def test_ipc_input_range_both_signs(value, accepted):
    _verdict(accepted, IPCError, lambda: _ipc(value), r"must lie in \[-1, 1\]")


@pytest.mark.parametrize("threshold, surrogates, accepted", [
    ("tuple-max", 1, True), ("tuple-max", 0, False), ("tuple-max", -1, False),
    ("none", 0, True),  # raw capacities need no surrogate
])
def test_ipc_surrogates_edge(threshold, surrogates, accepted):
    _verdict(accepted, IPCError, lambda: _ipc(threshold=threshold, surrogates=surrogates), "needs surrogates >= 1")


@pytest.mark.parametrize("kw, accepted, match", [
    ({"max_degree": 1}, True, ""), ({"max_degree": 0}, False, "max_degree must be >= 1"),
    ({"threshold_scale": 0.0}, True, ""), ({"threshold_scale": -TINY}, False, "threshold_scale"),
    ({"threshold_scale": math.inf}, False, "threshold_scale"),
    ({"threshold_scale": math.nan}, False, "threshold_scale"),
    ({"washout": 0}, True, ""), ({"washout": -1}, False, ">= 0"),
    ({"max_delay": 0}, True, ""), ({"max_delay": -1}, False, ">= 0"),
    ({"min_delay": 0}, True, ""), ({"min_delay": -1}, False, ">= 0"),
    ({"min_delay": 2, "max_delay": 2}, True, ""), ({"min_delay": 3, "max_delay": 2}, False, "must not exceed"),
    # samples left after max(washout, max_delay): at least 10
    ({"n": 40, "washout": 30, "max_delay": 2}, True, ""), ({"n": 40, "washout": 31, "max_delay": 2}, False,
                                                          "only 9 samples remain"),
    ({"n": 40, "washout": 0, "max_delay": 30}, True, ""), ({"n": 40, "washout": 0, "max_delay": 31}, False,
                                                          "only 9 samples remain"),
    ({"threshold": "tuple-max", "surrogates": 1}, True, ""), ({"threshold": "max"}, False, "threshold must be"),
])
def test_ipc_settings_edges(kw, accepted, match):
    _verdict(accepted, IPCError, lambda: _ipc(**kw), match)


@pytest.mark.parametrize("n_labels, accepted", [(2, True), (1, False), (3, False), (0, False)])
def test_ipc_label_count(n_labels, accepted):
    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, 40)
    groups = [u[:, None], np.roll(u, 1)[:, None]]
    labels = [f"g{i}" for i in range(n_labels)]
    call = lambda: ipc_groups(u, groups, labels, max_degree=1, max_delay=2, washout=0, threshold="none")  # noqa: E731
    out = _verdict(accepted, IPCError, call, f"{n_labels} labels for 2 state sets")
    if accepted:
        assert [s["label"] for s in out.summary()] == labels


@pytest.mark.parametrize("rows, accepted", [(40, True), (39, False), (41, False)])
def test_ipc_state_length_must_match_input(rows, accepted):
    rng = np.random.default_rng(2)
    u = rng.uniform(-1, 1, 40)
    x = rng.normal(size=(rows, 2))
    _verdict(accepted, IPCError, lambda: ipc_groups(u, [x], max_degree=1, max_delay=2, washout=0, threshold="none"),
             "the input's length")


# -- sim/wind_schedule.py ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("timing, accepted", [
    ("random", True), ("fixed", True), ("0", True), ("99", True), ("100", False), ("-1", False), ("1.5", False),
    ("", False), ("٣", False),  # a non-ASCII digit is not an integer n
])
def test_wind_timing_edges(timing, accepted):
    call = lambda: WindSchedule("switching", period=1.0, timing=timing)  # noqa: E731
    _verdict(accepted, WindScheduleError, call, "timing must be random, fixed or an integer n in")


@pytest.mark.parametrize("hold, accepted", [
    ((1, 1), True), ((1, 8), True), ((3, 3), True), ((0, 3), False), ((0, 0), False), ((4, 3), False),
    ((-1, 2), False),
])
def test_wind_hold_periods_edges(hold, accepted):
    _verdict(accepted, WindScheduleError, lambda: WindSchedule("switching", period=1.0, hold_periods=hold),
             "hold_periods must satisfy 1 <= lo <= hi")


@pytest.mark.parametrize("kind, period, accepted", [
    ("switching", TINY, True), ("switching", 0.0, False), ("switching", -TINY, False),
    ("periodic", 0.0, True), ("periodic", -TINY, False), ("periodic", math.inf, False), ("constant", math.nan, False),
])
def test_wind_period_edges(kind, period, accepted):
    _verdict(accepted, WindScheduleError, lambda: WindSchedule(kind, period=period), "period")


@pytest.mark.parametrize("force, accepted", [
    ((0.0, 0.0), True), ((-1e300, 1e300), True), ((math.inf, 0.0), False), ((0.0, -math.inf), False),
    ((math.nan, 0.0), False),
])
def test_wind_force_finite(force, accepted):
    _verdict(accepted, WindScheduleError, lambda: WindSchedule("constant", force=force), "two finite numbers")


@pytest.mark.parametrize("period, steps", [(0.006, 1), (0.0051, 1), (0.005, None), (0.004, None), (0.015, 2)])
def test_wind_switching_period_rounds_to_whole_steps(period, steps):
    """The period is counted in whole steps of dt = 0.01 s (round half to even, Python's round): 0.6 and 0.51
    steps are one step, exactly half a step (0.5 → 0) is none and refused, 1.5 steps are two."""
    schedule = WindSchedule("switching", period=period, hold_periods=(1, 1), timing="fixed")
    if steps is None:
        with pytest.raises(WindScheduleError, match=r"is at most half a time step \(0.01 s\)"):
            schedule.blowing(5, 0.01)
        return
    # hold (1, 1), switch phase 0: segments of exactly one period, starting off
    expected = np.resize(np.repeat([0.0, 1.0], steps), 9)
    np.testing.assert_array_equal(schedule.blowing(8, 0.01), expected)


def _table(tmp_path, body: str, **kw):
    path = tmp_path / "wind.csv"
    path.write_text("t,fx,fy\n" + body)
    return read_table(path, **kw)


@pytest.mark.parametrize("body, accepted, match", [
    ("0,1,2\n", True, ""),
    ("-1e-9,1,2\n", False, "t must be >= 0"),
    ("-0.5,1,2\n0.5,1,2\n", False, "row 2: t must be >= 0"),
    ("0,1,2\n1,3,4\n", True, ""),
    ("0,1,2\n0,3,4\n", False, "row 3: t = 0 s is not after the previous row"),  # repeated t
    ("0,1,2\n1,3,4\n0.5,0,0\n", False, "row 4: t = 0.5 s is not after"),  # going back
    ("0,1,2\n1e-9,3,4\n", True, ""),  # just after
    ("", False, "no rows after the header"),
])
def test_wind_table_time_edges(tmp_path, body, accepted, match):
    out = _verdict(accepted, WindScheduleError, lambda: _table(tmp_path, body), match)
    if accepted:
        assert len(out) == body.count("\n")


@pytest.mark.parametrize("fx, fy, accepted", [
    (5.0, 0.0, True), (-5.0, 0.0, True), (0.0, 5.0, True), (0.0, -5.0, True),
    (5.0 + 1e-6, 0.0, False), (-5.0 - 1e-6, 0.0, False), (0.0, 5.0 + 1e-6, False), (0.0, -5.0 - 1e-6, False),
])
def test_wind_table_max_force_both_signs(tmp_path, fx, fy, accepted):
    _verdict(accepted, WindScheduleError, lambda: _table(tmp_path, f"0,{fx!r},{fy!r}\n", max_force=5.0),
             "beyond the body's max_wind of 5 N")


@pytest.mark.parametrize("rows, accepted", [(3, True), (4, False)])
def test_wind_table_row_limit(tmp_path, monkeypatch, rows, accepted):
    monkeypatch.setattr(ws, "MAX_TABLE_ROWS", 3)
    body = "".join(f"{t},0,0\n" for t in range(rows))
    _verdict(accepted, WindScheduleError, lambda: _table(tmp_path, body), "more than 3 rows")


@pytest.mark.parametrize("steps, accepted", [(0, True), (-1, False)])
def test_wind_forces_steps(steps, accepted):
    out = _verdict(accepted, ValueError, lambda: WindSchedule("constant", force=(1.0, 2.0)).forces(steps, 0.01),
                   "steps must be >= 0")
    if accepted:
        assert out.tolist() == [[1.0, 2.0]]


# -- live/safety.py: command limits, runaway, divergence policy ---------------------------------------------------

@pytest.mark.parametrize("kw, accepted, match", [
    ({"max_rest_length": TINY}, True, ""),
    ({"max_rest_length": 0.0}, False, "max_rest_length must be finite and > 0"),
    ({"max_rest_length": -TINY}, False, "max_rest_length must be finite and > 0"),
    ({"max_rest_length": math.inf}, False, "max_rest_length must be finite"),
    ({"max_rest_length": 1.0, "max_force": TINY}, True, ""),
    ({"max_rest_length": 1.0, "max_force": 0.0}, False, "max_force must be finite and > 0"),
    ({"max_rest_length": 1.0, "max_wind": TINY}, True, ""),
    ({"max_rest_length": 1.0, "max_wind": 0.0}, False, "max_wind must be finite and > 0"),
    ({"max_rest_length": 1.0, "min_rest_length": 1.0 - 1e-9}, True, ""),
    ({"max_rest_length": 1.0, "min_rest_length": 1.0}, False, "min_rest_length must be finite and below"),
    ({"max_rest_length": 1.0, "min_rest_length": 1.0 + 1e-9}, False, "min_rest_length must be finite and below"),
    ({"max_rest_length": 1.0, "min_rest_length": -5.0}, True, ""),  # the SWG's own floor may be negative
    ({"max_rest_length": 1.0, "min_rest_length": -math.inf}, False, "min_rest_length must be finite"),
])
def test_command_limits_construction(kw, accepted, match):
    _verdict(accepted, ValueError, lambda: CommandLimits(**kw), match)


LIMITS = CommandLimits(max_rest_length=2.0, max_force=3.0, max_wind=4.0, min_rest_length=0.5, max_displacement=1.0)


@pytest.mark.parametrize("source, value, accepted", [
    # rest lengths in (min, max]
    ("rest_length", 0.5, False), ("rest_length", 0.5 + 1e-9, True), ("rest_length", 2.0, True),
    ("rest_length", 2.0 + 1e-9, False), ("rest_length", 0.4, False),
    ("force", 3.0, True), ("force", -3.0, True), ("force", 3.0 + 1e-9, False), ("force", -3.0 - 1e-9, False),
    ("wind", 4.0, True), ("wind", -4.0, True), ("wind", 4.0 + 1e-9, False), ("wind", -4.0 - 1e-9, False),
    # perturbation components in [-max_displacement, max_displacement], negative ones too
    ("perturbation", 1.0, True), ("perturbation", -1.0, True), ("perturbation", 1.0 + 1e-9, False),
    ("perturbation", -1.0 - 1e-9, False),
])
def test_command_limits_check_both_sides(source, value, accepted):
    vals = np.full(4, 0.5 + 1e-3 if source == "rest_length" else 0.0)
    vals[2] = value
    problem = LIMITS.check(source, vals)
    if accepted:
        assert problem is None
    else:
        assert problem is not None and "at index 2" in problem and "(1 value(s) out of bounds)" in problem


@pytest.mark.parametrize("dx, dy, accepted", [
    (1.0, 0.0, True), (0.0, -1.0, True), (-0.6, -0.8, True),  # length exactly 1 (0.36 + 0.64)
    (1.0 + 1e-9, 0.0, False), (0.0, -1.0 - 1e-9, False), (-0.6, -0.8 - 1e-6, False),
    (0.9, 0.9, False),  # each component within 1, the length is not
])
def test_reset_displacement_length_edge(dx, dy, accepted):
    vals = np.array([0.0, 0.0, dx, dy])
    problem = LIMITS.check("reset", vals)
    if accepted:
        assert problem is None
    else:
        assert problem is not None and "movable mass 1" in problem


@pytest.mark.parametrize("v, a, accepted", [
    (10.0, 0.0, True), (10.0 * (1 + 1e-9), 0.0, False), (-10.0 * (1 + 1e-9), 0.0, False),  # |v|·dt vs the box
    (0.0, 100.0, True), (0.0, 100.0 * (1 + 1e-9), False), (0.0, -100.0 * (1 + 1e-9), False),  # |a|·dt² alone
    (0.0, 0.0, True),
])
def test_runaway_by_velocity_or_acceleration_alone(v, a, accepted):
    # dt = 0.1, limit 1 m: |v| = 10 m/s moves exactly 1 m in a step, |a| = 100 m/s² moves exactly 1 m in dt²
    vel = np.array([[0.0, 0.0], [0.0, v]])
    acc = np.array([[a, 0.0], [0.0, 0.0]])
    why = runaway(vel, acc, 0.1, limit=1.0)
    if accepted:
        assert why is None
    else:
        assert why is not None and "beyond 1 m within one step" in why


@pytest.mark.parametrize("policy, accepted", [("restore", True), ("stop", True), ("Stop", False), ("", False)])
def test_divergence_policy_names(policy, accepted):
    _verdict(accepted, ValueError, lambda: DivergenceRecovery(policy), "policy must be one of")


# -- live/channels.py: realtime age and the look-ahead ------------------------------------------------------------

def _channel(mode: str = "realtime", **kw) -> CommandChannel:
    return CommandChannel("rest_length", 2, ["a", "b"], mode, **kw)


@pytest.mark.parametrize("age, accepted", [(0, True), (9, True), (10, True), (11, False), (-1, True)])
def test_realtime_command_age_edge(age, accepted):
    ch = _channel(max_age_steps=10, max_ahead=1)
    rej = ch.offer(100 - age, [1.0, 1.0], next_step=100, now=0.0)
    if accepted:
        assert rej is None and ch.accepted == 1
    else:
        assert rej is not None and rej.reason == "stale" and "11 steps old (max 10)" in rej.message


@pytest.mark.parametrize("age, usable", [(10, True), (11, False), (0, True)])
def test_realtime_command_usable_until_max_age(age, usable):
    ch = _channel(max_age_steps=10)
    assert ch.offer(50, [1.0, 1.0], next_step=50, now=0.0) is None
    assert ch.has(50 + age) is usable
    assert (ch.take(50 + age) is not None) is usable


@pytest.mark.parametrize("mode", ["realtime", "lockstep"])
@pytest.mark.parametrize("ahead, accepted", [(0, True), (2, True), (3, False)])
def test_command_look_ahead_edge(mode, ahead, accepted):
    ch = _channel(mode, max_ahead=2)
    rej = ch.offer(10 + ahead, [1.0, 1.0], next_step=10, now=0.0)
    if accepted:
        assert rej is None
    else:
        assert rej is not None and rej.reason == "too_far_ahead"


@pytest.mark.parametrize("step, accepted", [(10, True), (9, False)])
def test_lockstep_stale_edge(step, accepted):
    ch = _channel("lockstep")
    rej = ch.offer(step, [1.0, 1.0], next_step=10, now=0.0)
    if accepted:
        assert rej is None and ch.has(10)
    else:
        assert rej is not None and rej.reason == "stale"


@pytest.mark.parametrize("latest, step, accepted", [(5, 6, True), (5, 5, False), (5, 4, False)])
def test_realtime_not_newer_than_latest(latest, step, accepted):
    ch = _channel(max_age_steps=10)
    assert ch.offer(latest, [1.0, 1.0], next_step=latest, now=0.0) is None
    rej = ch.offer(step, [1.0, 1.0], next_step=latest, now=0.0)
    if accepted:
        assert rej is None and ch.latest.step == step
    else:
        assert rej is not None and rej.reason == "stale" and "not newer than the latest (5)" in rej.message


@pytest.mark.parametrize("every, step, accepted", [(0, 0, False), (1, 7, True), (3, 6, True), (3, 7, False)])
def test_channel_schedule_every(every, step, accepted):
    ch = _channel("lockstep", every=every, max_ahead=100)
    rej = ch.offer(step, [1.0, 1.0], next_step=0, now=0.0)
    assert (rej is None) is accepted
    if not accepted:
        assert rej.reason == "off_schedule"


@pytest.mark.parametrize("kw, accepted, match", [
    ({"size": 1}, True, ""), ({"size": 0}, False, "size must be positive"),
    ({"every": 0}, True, ""), ({"every": -1}, False, "every must be >= 0"),
    ({"mode": "lockstep"}, True, ""), ({"mode": "real-time"}, False, "mode must be one of"),
])
def test_channel_construction(kw, accepted, match):
    args = {"name": "force", "size": 2, "names": [], "mode": "realtime", **kw}
    _verdict(accepted, ValueError, lambda: CommandChannel(**args), match)


# -- the scheduled perturbation -----------------------------------------------------------------------------------

@pytest.mark.parametrize("sigma, accepted", [(0.0, True), (TINY, True), (-TINY, False), (math.inf, False),
                                             (math.nan, False)])
def test_perturbation_sigma(sigma, accepted):
    _verdict(accepted, ValueError, lambda: perturbation(3, sigma, 0), "sigma must be finite and >= 0")


def test_perturbation_sigma_zero_is_no_displacement_and_tiny_is_some():
    assert perturbation(3, 0.0, 0).shape == (3, 2) and not perturbation(3, 0.0, 0).any()
    tiny = perturbation(3, TINY, 0)
    assert tiny.shape == (3, 2) and 0 < np.abs(tiny).max() < 10 * TINY


@pytest.mark.parametrize("at, sigma, accepted", [
    (-1.0, 0.0, True),  # none
    (0.0, 0.0, True), (0.0, 0.1, True), (-1.0, 0.1, False),  # σ > 0 needs a time
    (5.0, -TINY, False), (10.0, 0.1, True), (10.0 + 1e-9, 0.1, False),  # at most the run's length
])
def test_perturbation_problem_edges(at, sigma, accepted):
    problem = perturbation_problem(at, sigma, duration=10.0, rate_scale=1.0, mode="lockstep")
    assert (problem == "") is accepted


@pytest.mark.parametrize("at, accepted", [(20.0, True), (20.0 + 1e-9, False)])
def test_perturbation_problem_realtime_length(at, accepted):
    # realtime: the sim length is duration × rate_scale = 10 s × 2
    assert (perturbation_problem(at, 0.1, duration=10.0, rate_scale=2.0, mode="realtime") == "") is accepted


# -- data/mnist.py: MD5SUMS lines and labels ----------------------------------------------------------------------

def _idx(dims: tuple[int, ...], data: bytes) -> bytes:
    return struct.pack(f">BBBB{len(dims)}i", 0, 0, 8, len(dims), *dims) + data


def _mnist_dir(tmp_path, labels: list[int], sums_lines=None, n_images: int | None = None):
    n_images = len(labels) if n_images is None else n_images
    images = _idx((n_images, 28, 28), bytes(n_images * 784))
    lab = _idx((len(labels),), bytes(labels))
    (tmp_path / mnist.TEST_IMAGES).write_bytes(images)
    (tmp_path / mnist.TEST_LABELS).write_bytes(lab)
    md5 = {n: hashlib.md5(b).hexdigest() for n, b in ((mnist.TEST_IMAGES, images), (mnist.TEST_LABELS, lab))}
    lines = sums_lines(md5) if sums_lines else [f"{md5[n]}  {n}" for n in md5]
    (tmp_path / mnist.CHECKSUM_FILE).write_text("\n".join(lines) + "\n")
    return tmp_path


@pytest.mark.parametrize("label, accepted", [(9, True), (0, True), (10, False), (255, False)])
def test_mnist_label_digit_edge(tmp_path, label, accepted):
    d = _mnist_dir(tmp_path, [0, label, 3])
    out = _verdict(accepted, MnistError, lambda: read_pair(d, mnist.TEST_IMAGES, mnist.TEST_LABELS),
                   f"labels must be digits 0-9, found {label}")
    if accepted:
        assert out[1].tolist() == [0, label, 3] and out[2] is False


@pytest.mark.parametrize("n_images, accepted", [(3, True), (2, False), (4, False)])
def test_mnist_image_and_label_counts_match(tmp_path, n_images, accepted):
    d = _mnist_dir(tmp_path, [1, 2, 3], n_images=n_images)
    out = _verdict(accepted, MnistError, lambda: read_pair(d, mnist.TEST_IMAGES, mnist.TEST_LABELS),
                   f"holds {n_images} images but {mnist.TEST_LABELS} has shape \\(3,\\)")
    if accepted:
        assert out[0].shape == (3, 28, 28)


@pytest.mark.parametrize("form, accepted", [
    ("{h}  {n}", True),  # md5sum's text mode
    ("{h} *{n}", True),  # md5sum's binary mode marks the name with '*'
    ("{H}  {n}", True),  # upper-case hex
    ("{h}  {n}.gz", True),  # a sum over the name of the gzipped copy still names the uncompressed data
    ("{h31}  {n}", False), ("{h}0  {n}", False),  # 31 and 33 hex digits
    ("{h}", False), ("{h}  {n}  extra", False),
])
def test_mnist_md5sums_line_forms(tmp_path, form, accepted):
    def lines(md5):
        return [form.format(h=md5[n], H=md5[n].upper(), h31=md5[n][:31], n=n) for n in md5]

    d = _mnist_dir(tmp_path, [1, 2], lines)
    out = _verdict(accepted, MnistError, lambda: read_pair(d, mnist.TEST_IMAGES, mnist.TEST_LABELS),
                   r"MD5SUMS:1: expected 'MD5  NAME'")
    if accepted:
        assert out[1].tolist() == [1, 2]


def test_mnist_md5sums_star_name_is_still_checked(tmp_path):
    """A '*NAME' line is a checksum like any other: a wrong sum behind it is refused, not skipped."""
    d = _mnist_dir(tmp_path, [1, 2], lambda md5: [f"{'0' * 32} *{n}" for n in md5])
    with pytest.raises(MnistError, match="MD5 of the uncompressed data is"):
        read_pair(d, mnist.TEST_IMAGES, mnist.TEST_LABELS)


@pytest.mark.parametrize("dims, accepted", [
    ((1,), True), ((1, 1, 1, 1), True), ((1, 1, 1, 1, 1), False), ((), False),
])
def test_idx_dimension_count_edge(dims, accepted):
    _verdict(accepted, MnistError, lambda: mnist.parse_idx(_idx(dims, b"\x07"), "f"), "dimensions")


@pytest.mark.parametrize("dims, accepted", [((1, 1), True), ((0, 1), False), ((1, -1), False)])
def test_idx_size_at_least_one(dims, accepted):
    _verdict(accepted, MnistError, lambda: mnist.parse_idx(_idx(dims, b"\x07"), "f"), "every size must be >= 1")


# -- experiments/result.py: result rows and claims ----------------------------------------------------------------

def _result(**kw) -> dict:
    base = {"experiment": "x", "paper_ref": "", "scale": "smoke", "seed": 0, "wall_s": 0.0, "rows": [], "claims": [],
            "figures": []}
    base.update(kw)
    return base


def _row(**kw) -> dict:
    return {"system": "s", "metric": "m", "unit": "", "ours": 1.0, "paper": None, **kw}


RESULT_EDGES = [
    ("wall_s", 0.0, True), ("wall_s", 0, True), ("wall_s", -TINY, False), ("wall_s", math.inf, False),
    ("wall_s", True, False),
    ("seed", 0, True), ("seed", -3, True), ("seed", True, False), ("seed", 1.0, False),
    ("experiment", "a", True), ("experiment", "a" * MAX_SLUG_LEN, True),
    ("experiment", "a" * (MAX_SLUG_LEN + 1), False),
    ("experiment", "0-a_b", True), ("experiment", "-a", False), ("experiment", "A", False), ("experiment", "", False),
    ("scale", "paper", True), ("scale", "Paper", False),
    ("rows", [_row(ours=None)], True), ("rows", [_row(ours=0)], True), ("rows", [_row(ours=-1e300)], True),
    ("rows", [_row(ours=True)], False), ("rows", [_row(ours=False)], False), ("rows", [_row(ours=math.nan)], False),
    ("rows", [_row(ours=10**400)], False),  # an int no float can hold is not finite
    ("rows", [_row(paper="~0.1")], True), ("rows", [_row(paper=0.1)], True), ("rows", [_row(paper=True)], False),
    ("rows", [_row(paper=math.inf)], False), ("rows", [{k: v for k, v in _row().items() if k != "paper"}], False),
    ("rows", [_row(unit=None)], False),
    ("claims", [{"claim": "c", "holds": True, "evidence": ""}], True),
    ("claims", [{"claim": "c", "holds": False, "evidence": ""}], True),
    ("claims", [{"claim": "c", "holds": None, "evidence": "premise p failed"}], True),
    ("claims", [{"claim": "c", "holds": None, "evidence": " "}], False),
    ("claims", [{"claim": "c", "holds": 1, "evidence": "e"}], False),
    ("claims", [{"claim": "c", "holds": 0, "evidence": "e"}], False),
    ("claims", [{"claim": "c", "evidence": "e"}], False),
    ("figures", ["fig/a.png"], True), ("figures", ["../a.png"], False), ("figures", ["/a.png"], False),
    ("figures", [3], False),
]


@pytest.mark.parametrize("key, value, accepted", RESULT_EDGES,
                         ids=[f"{k}={str(v)[:30]}" for k, v, _ in RESULT_EDGES])
def test_result_schema_edges(key, value, accepted):
    data = _result(**{key: value})
    _verdict(accepted, ResultError, lambda: validate_result(data, "r.json"), f"r.json: {key}")


@pytest.mark.parametrize("holds, evidence, stored", [  # stored: the holds kept, or "refused"
    (True, "", True), (False, "", False), (np.bool_(True), "", True), (np.bool_(False), "", False),
    (None, "p failed", None), (None, "", "refused"), (None, "  ", "refused"), (1, "e", "refused"),
    (0, "e", "refused"), (np.float64(1.0), "e", "refused"),
])
def test_claim_holds_must_be_a_bool(holds, evidence, stored):
    out = _verdict(stored != "refused", ResultError, lambda: Claim("c", holds, evidence), "claim 'c'")
    if stored != "refused":
        assert out.holds is stored  # the plain Python True/False/None (a numpy bool converted)


# -- body/msdn.py and training/guard.py ------------------------------------------------------------------------------

@pytest.mark.parametrize("dt, accepted", [(TINY, True), (1.0, True), (0.0, False), (-TINY, False), (math.nan, False),
                                          (math.inf, False)])
def test_msdn_dt_edges(dt, accepted):
    """dt must be a positive number of seconds: NaN (which compares False with everything) and inf are not."""
    _verdict(accepted, ValueError, lambda: MSDN(double_circle(7), dt=dt), "dt must be")


@pytest.mark.parametrize("dt, ns", [(1e-9, 1), (0.01, 10_000_000), (2.0, 2_000_000_000), (0.0, None), (-1e-9, None),
                                    (1.5e-9, None), (math.nan, None), (math.inf, None), (1e300, None)])
def test_dt_to_ns_edges(dt, ns):
    """A ROS time step is a whole, positive, finite number of nanoseconds; anything else is one ValueError."""
    from bptsb_ros.interface.topics import dt_to_ns

    if ns is not None:
        assert dt_to_ns(dt) == ns
    else:
        with pytest.raises(ValueError, match="dt must be"):
            dt_to_ns(dt)


def _optimizer():
    return torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0)


@pytest.mark.parametrize("factor, patience, accepted, match", [
    (0.0, 1, True, ""), (-TINY, 5, False, "factor must be finite and >= 0"),
    (math.inf, 5, False, "factor must be finite"), (math.nan, 5, False, "factor must be finite"),
    (2.0, 0, False, "patience must be >= 1"), (2.0, -1, False, "patience must be >= 1"),
])
def test_guard_settings_edges(factor, patience, accepted, match):
    out = _verdict(accepted, ValueError, lambda: UpdateGuard(_optimizer(), factor=factor, patience=patience), match)
    if accepted:
        assert out.factor == factor and out.patience == patience


# -- cli: argument types and the checks before any work -----------------------------------------------------------

@pytest.mark.parametrize("text, accepted", [("0", True), ("-1e308", True), ("1e308", True), ("nan", False),
                                            ("inf", False), ("-inf", False), ("1e309", False), ("x", False)])
def test_finite_float(text, accepted):
    _verdict(accepted, argparse.ArgumentTypeError, lambda: finite_float(text), "not a number|must be a finite number")


@pytest.mark.parametrize("text, accepted", [("3600", True), ("1e-9", True), ("3600.000001", False), ("0", False),
                                            ("-1", False)])
def test_sweep_connect_timeout_range(text, accepted):
    from bptsb_ros.cli.sweep_cmd import _timeout

    out = _verdict(accepted, argparse.ArgumentTypeError, lambda: _timeout(text), r"must be in \(0, 3600\] seconds")
    if accepted:
        assert out == float(text)


@pytest.mark.parametrize("flag, value, accepted", [
    ("--steps", "1", True), ("--steps", "0", False),
    ("--perturb", "0", True), ("--perturb", "-1e-9", False),
    ("--dt", "1e-9", True), ("--dt", "0", False), ("--dt", "-1e-9", False),
])
def test_simulate_checks_before_work(capsys, flag, value, accepted):
    # --out is wrong on purpose: an accepted value gets as far as the --out check (and no further work is done)
    argv = ["simulate", "--shape", "double_circle", "--steps", "5", "--out", "x.txt", f"{flag}={value}"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    if accepted:
        assert err == "bptsb simulate: --out must end in .npz, got x.txt"
    else:
        assert err.startswith(f"bptsb simulate: {flag} must be")


@pytest.mark.parametrize("value, accepted", [("1e-9", True), ("0", False), ("-1", False), ("inf", False),
                                             ("nan", False)])
def test_launch_max_wind_param(value, accepted):
    from bptsb_ros.cli.launch_cmd import _wind_limit

    out = _verdict(accepted, ValueError, lambda: _wind_limit({"body_sim": [f"max_wind:={value}"]}),
                   "must be finite and > 0")
    if accepted:
        assert out == float(value)


@pytest.mark.parametrize("flag, value, accepted", [
    ("--duration", "0", True), ("--duration", "-1e-9", False),
    ("--rate-scale", "1e-9", True), ("--rate-scale", "0", False), ("--rate-scale", "-1", False),
    ("--grace", "1e-9", True), ("--grace", "0", False),
])
def test_launch_run_settings_before_any_node(capsys, flag, value, accepted):
    # --perturb-at -1 is refused on purpose: an accepted value gets as far as that check, and no node starts
    assert cli_main(["launch", "lissajous_open", f"{flag}={value}", "--perturb-at=-1"]) == 2
    err = capsys.readouterr().err.strip()
    if accepted:
        assert err == "bptsb launch: --perturb-at -1: must be >= 0 (sim seconds)"
    else:
        assert err == "bptsb launch: --duration must be >= 0, --rate-scale and --grace > 0"


@pytest.mark.parametrize("functions, max_bytes, accepted, match", [
    # basis of max_degree 2, max_delay 2, by hand: degree 1: u(t−0..2), 3 functions; degree 2: P2 of each of the
    # 3 delays and the 3 products of two delays, 6. Total 9; the largest degree, 6 functions × 10 samples × 8 B.
    (9, 480, True, ""), (8, 480, False, "is a basis of 9 functions, more than the maximum of 8"),
    (9, 479, False, r"the degree-2 basis \(6 functions × 10 samples\) needs"),
])
def test_ipc_cli_basis_bounds(monkeypatch, functions, max_bytes, accepted, match):
    from bptsb_ros.cli import ipc_cmd

    assert ipc_cmd.basis_size(2, 2) == [3, 6]
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_FUNCTIONS", functions)
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_BYTES", max_bytes)
    _verdict(accepted, IPCError, lambda: ipc_cmd._check_basis(2, 2, samples=10), match)


# -- interface/params.py: the node parameters' bounds ------------------------------------------------------------------

@pytest.mark.parametrize("spec, value, accepted, match", [
    ({"kind": "float", "positive": True}, 1e-9, True, ""),
    ({"kind": "float", "positive": True}, 0.0, False, "must be > 0"),
    ({"kind": "float", "positive": True}, -1e-9, False, "must be > 0"),
    ({"kind": "float", "minimum": 0.0}, 0.0, True, ""),
    ({"kind": "float", "minimum": 0.0}, -1e-9, False, "must be >= 0"),
    ({"kind": "float", "maximum": 2.0}, 2.0, True, ""),
    ({"kind": "float", "maximum": 2.0}, 2.0 + 1e-9, False, "must be <= 2"),
    ({"kind": "float", "minimum": -1.0, "maximum": 1.0}, -1.0, True, ""),
    ({"kind": "float", "minimum": -1.0, "maximum": 1.0}, -1.0 - 1e-9, False, "must be >= -1"),
    ({"kind": "int", "minimum": 1}, 1, True, ""), ({"kind": "int", "minimum": 1}, 0, False, "must be >= 1"),
    ({"kind": "float"}, math.inf, False, "must be finite"), ({"kind": "float"}, -math.inf, False, "must be finite"),
    ({"kind": "float_list", "size": 2}, [1.0, 2.0], True, ""),
    ({"kind": "float_list", "size": 2}, [1.0], False, "must have 2 values, got 1"),
    ({"kind": "float_list", "size": 2}, [1.0, 2.0, 3.0], False, "must have 2 values, got 3"),
    ({"kind": "float_list", "size": 2}, [1.0, math.nan], False, "must be finite"),
])
def test_node_parameter_bounds(spec, value, accepted, match):
    from bptsb_ros.interface.params import Param, ParameterError

    default = [0.0, 0.0] if spec["kind"] == "float_list" else (1 if spec["kind"] == "int" else 1.0)
    p = Param("x", default, "x [unit]", **spec)
    out = _verdict(accepted, ParameterError, lambda: p.validate(value), re.escape(f"parameter 'x' {match}"))
    if accepted:
        assert out == value


@pytest.mark.parametrize("bag, accepted", [(False, False), (True, True)])
def test_launch_recorder_in_body_needs_a_bag(capsys, tmp_path, bag, accepted):
    # --perturb-at -1 is refused on purpose: an accepted flag gets as far as that check, and no node starts
    argv = ["launch", "lissajous_open", "--recorder-in-body", "--perturb-at=-1"]
    assert cli_main(argv + (["--bag", str(tmp_path / "bag")] if bag else [])) == 2
    err = capsys.readouterr().err.strip()
    if accepted:
        assert err == "bptsb launch: --perturb-at -1: must be >= 0 (sim seconds)"
    else:
        assert err == "bptsb launch: --recorder-in-body needs --bag DIR (there is no recorder without a bag)"
    assert not (tmp_path / "bag").exists()


@pytest.mark.parametrize("values, accepted", [({"recorder_in_body": "true"}, False),
                                              ({"recorder_in_body": "true", "bag": "B"}, True),
                                              ({"recorder_in_body": "yes", "bag": "B"}, False)])
def test_launch_file_recorder_in_body_needs_a_bag(tmp_path, values, accepted):
    from bptsb_ros.live.loops import LOOPS, LaunchArgumentError, resolve_arguments

    values = {k: str(tmp_path / v) if k == "bag" else v for k, v in values.items()}
    _verdict(accepted, LaunchArgumentError, lambda: resolve_arguments(LOOPS["lissajous_open"], values),
             "recorder_in_body:=")
