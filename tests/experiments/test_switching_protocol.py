"""The authors' published switching protocol as a settings variant: the window schedule (50 calm, 50 windy windows
of 100 steps, the switch at a random step inside the window), the displaced target, the wind values and the ÷10
learning-rate schedule (hand values from published-code-facts.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bptsb_ros.agent import build_agent
from bptsb_ros.experiments.common import packaged_config
from bptsb_ros.experiments.experiment_settings import resolve_settings
from bptsb_ros.experiments.lissajous_switching import variant_curve, variant_lr
from bptsb_ros.sim.inputs import wind_schedule
from bptsb_ros.tasks.lissajous import LissajousTask
from bptsb_ros.tasks.switching import CURVE_1, switch_targets, train_switching, wind_vector
from bptsb_ros.training.optim import step_decay_updates

AUTHORS = resolve_settings("lissajous-switching", "smoke").variants["authors"]


def test_authors_schedule_is_50_calm_then_50_windy_windows_with_the_switch_at_a_random_step_inside():
    window = 100  # the SWG period at ω = 2π, dt = 0.01: one 100-step window
    steps = 40 * 50 * window
    calm_on = wind_schedule(steps, window, np.random.default_rng(11), hold_periods=tuple(AUTHORS["hold"]))
    switches = np.flatnonzero(np.diff(calm_on)) + 1
    assert len(switches) == 39 and calm_on[0] == 0.0  # starts calm
    # the i-th switch lies inside window 50·i (steps 5000·i … 5000·i + 99)
    assert (switches // window).tolist() == [50 * (i + 1) for i in range(39)]
    offsets = switches % window
    assert len(set(offsets.tolist())) > 20  # a fresh uniform step each time, not a fixed phase
    # segments alternate calm / windy, each holding the wind for about 50 windows
    assert np.all(calm_on[switches] == np.resize([1.0, 0.0], 39))
    assert np.all(np.abs(np.diff(np.concatenate([[0], switches])) - 50 * window) < window)
    fixed = wind_schedule(steps, window, np.random.default_rng(11), hold_periods=(50, 50), timing="fixed")
    assert (np.flatnonzero(np.diff(fixed)) + 1).tolist()[:3] == [5000, 10000, 15000]  # n = 0: at the window edge


def test_authors_target_is_the_figure_eight_displaced_by_a_twentieth_of_the_body_and_the_wind_15_up_1():
    curve = variant_curve(AUTHORS)
    assert (curve.alpha, curve.beta, curve.delta) == (2.0, 1.0, math.pi / 4)  # lissajous2: [2, 1, 1, 4]
    size = 4.0
    shift = AUTHORS["shift_of_size"] * size
    assert shift == pytest.approx(0.2)
    t = np.array([0.0, 0.1, 0.3])
    wind = np.array([0.0, 1.0, 1.0])
    xy = switch_targets(CURVE_1, curve, 1.0, 2 * math.pi, shift)(t, wind)
    expect = np.array([[1.0, 0.0],  # (1,2,0) at t = 0, calm: not displaced
                       [math.cos(0.4 * math.pi) + 0.2, math.sin(0.2 * math.pi + math.pi / 4)],
                       [math.cos(1.2 * math.pi) + 0.2, math.sin(0.6 * math.pi + math.pi / 4)]])
    np.testing.assert_allclose(xy, expect, atol=1e-12)
    f = wind_vector(torch.tensor([0.0, 1.0]), published=AUTHORS["published_wind"])
    assert f.tolist() == [[0.0, 1.0], [15.0, 1.0]]  # calm: +1 up only; windy: 15 in x and +1 up
    lr = variant_lr(AUTHORS)
    assert (lr.k, lr.d, lr.l, lr.amplitude, lr.phase) == (1000.0, 100.0, 1.0, 1.0, 10.0)


def test_rates_are_divided_at_80_and_90_percent_only_beyond_1000_windows():
    assert step_decay_updates(2000) == [1600, 1800]
    assert step_decay_updates(1000) == []  # "more than 1,000 windows"
    assert step_decay_updates(1001) == [800, 900]
    with pytest.raises(ValueError, match="milestones must lie in"):
        step_decay_updates(2000, milestones=(0.8, 1.0))


def test_switching_trainer_applies_the_decay_before_the_update_at_80_and_90_percent():
    cfg = packaged_config("lissajous_single", ["dtype=float64", "body.integrator=published"], seed=3)
    agent = build_agent(cfg)
    assert agent.body.integrator == "published"
    state = LissajousTask(agent, cfg).state
    schedule = wind_schedule(400, 100, np.random.default_rng(3), hold_periods=(1, 1))
    target = switch_targets(CURVE_1, variant_curve(AUTHORS), 0.2, 2 * math.pi, 0.2)
    res = train_switching(agent, state, schedule, target, lr=variant_lr(AUTHORS), window=40,
                          published_wind=True, lr_decay=True, lr_decay_min_updates=2, backend="numba")
    # 10 windows: window 0 … 7 at 1000, window 8 (80 %) at 100, window 9 (90 %) at 10
    assert res.lr_k == pytest.approx([1000.0] * 8 + [100.0, 10.0])
    assert not res.guard.get("events")  # no guard cut mixed into these values
    plain = train_switching(build_agent(cfg), LissajousTask(build_agent(cfg), cfg).state, schedule, target,
                            lr=variant_lr(AUTHORS), window=40, published_wind=True, backend="numba")
    assert plain.lr_k == [1000.0] * 10


def test_loss_by_condition_splits_the_first_and_last_tenth_into_calm_and_windy_updates():
    from bptsb_ros.experiments.lissajous_switching import loss_by_condition

    window = 4
    on = np.array([0, 1, 0, 1, 1, 0, 0, 1, 1, 0] * 2, float)  # 20 updates, windy as planted
    schedule = np.concatenate([[0.0], np.repeat(on, window)])
    schedule[1 + 1 * window] = 0.0  # update 1: 3 of 4 steps windy, still windy
    losses = np.arange(20, dtype=float)
    out = loss_by_condition(losses, schedule, window, share=0.1)  # 2 updates at each end
    assert out == {"loss_calm_first_share": 0.0, "loss_windy_first_share": 1.0,
                   "loss_calm_last_share": 19.0, "loss_windy_last_share": 18.0}
    out = loss_by_condition(losses, schedule, window, share=0.25)  # 5 at each end: updates 0-4 and 15-19
    assert out["loss_windy_first_share"] == (1 + 3 + 4) / 3 and out["loss_calm_last_share"] == (15 + 16 + 19) / 3
