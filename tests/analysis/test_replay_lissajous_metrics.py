"""The replay's Lissajous metrics (``analysis/replay_lissajous.py``) on planted runs whose answers are written here
by hand: the switching run's per-segment NMSE (centred: a wind segment's figure is displaced), which segments count
(a transient plus one whole period, exactly, is enough), "both curves drawn" (drawn in every segment AND both wind
conditions seen), which rows blow (the x component: the published calm wind is (0, 1)), and the return criterion's
window (at least 2 periods after the kick, at most the last 10 periods).

The targets are written out below (x = A cos(α ω t) + dx, y = A sin(β ω t + δ)); over any whole period of 100
samples each coordinate's variance is A²/2, so a segment's centred mean square is A²/2 = 0.02 m², calm or windy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bptsb_ros.analysis.replay_lissajous import blowing, return_metrics, switching_metrics

DT, A, OMEGA, PERIOD = 0.01, 0.2, 2 * math.pi, 100
SHIFT = 0.3  # the wind curve's displacement in x [m]
VARIANCE = A * A / 2  # the centred mean square of either curve over whole periods [m²]
CONFIG = {"task": "lissajous", "brain": {"omega": OMEGA}, "body": {"size": 4.0, "dt": DT},
          "lissajous": {"amplitude_fraction": 0.05, "alpha": 1, "beta": 2, "delta": 0.0}}
EXTRA = {"curve_on": [2, 1, math.pi / 2], "wind_shift_x": SHIFT}


def calm_curve(t: np.ndarray) -> np.ndarray:
    """(1, 2, 0): the curve without wind."""
    return np.stack([A * np.cos(OMEGA * t), A * np.sin(2 * OMEGA * t)], 1)


def wind_curve(t: np.ndarray) -> np.ndarray:
    """(2, 1, π/2) displaced by SHIFT in x: the curve with wind."""
    return np.stack([A * np.cos(2 * OMEGA * t) + SHIFT, A * np.sin(OMEGA * t + math.pi / 2)], 1)


def planted(lengths: list[int], *, published: bool = False, offsets=None, transient_offset: float = 0.0):
    """A run of alternating calm / windy segments of ``lengths`` rows (calm first) → (wind (T, 2), trajectory (T, 2)):
    the trajectory is the segment's curve plus ``offsets[i]`` (2,) in segment i, and ``transient_offset`` in both
    coordinates over each segment's first two periods (which the metric skips)."""
    n = sum(lengths)
    t = np.arange(n) * DT
    windy = np.zeros(n, bool)
    traj = np.empty((n, 2))
    start = 0
    for i, length in enumerate(lengths):
        rows = slice(start, start + length)
        windy[rows] = i % 2 == 1
        traj[rows] = (wind_curve if i % 2 else calm_curve)(t[rows]) + (0.0 if offsets is None else offsets[i])
        traj[start:start + min(2 * PERIOD, length)] += transient_offset
        start += length
    if published:  # the published wind (15·F, 1): calm is (0, 1), blowing (15, 1)
        wind = np.stack([15.0 * windy, np.ones(n)], 1)
    else:
        wind = np.stack([1.0 * windy, np.zeros(n)], 1)
    return wind, traj


def metrics(wind: np.ndarray, **trajs: np.ndarray) -> dict:
    return switching_metrics(trajs, wind, DT, CONFIG, EXTRA)


# -- the per-segment NMSE ------------------------------------------------------------------------------------------
def test_segment_nmse_is_the_mse_over_the_centred_mean_square_of_that_segments_figure():
    # calm: offset (0.01, 0) → MSE (1e-4 + 0)/2 = 5e-5 → NMSE 5e-5 / 0.02 = 0.0025
    # windy (figure centred 0.3 m off the origin): offset (0, 0.04) → MSE 8e-4 → NMSE 0.04 (not 8e-4 / 0.065, the
    # uncentred mean square (0.02 + 0.3² + 0.02) / 2 of the displaced figure)
    # calm again: offset (0.03, 0.04) → MSE (9e-4 + 1.6e-3)/2 = 1.25e-3 → NMSE 0.0625
    offsets = [(0.01, 0.0), (0.0, 0.04), (0.03, 0.04)]
    wind, traj = planted([400, 300, 300], offsets=offsets, transient_offset=5.0)
    out = metrics(wind, live=traj)
    seg = out["segments"]
    assert [(s["steps"], s["wind"]) for s in seg] == [([200, 399], False), ([600, 699], True), ([900, 999], False)]
    assert [s["curve"] for s in seg] == ["(1,2,0)", "(2,1,0.5π)", "(1,2,0)"]
    assert [s["nmse_live"] for s in seg] == pytest.approx([0.0025, 0.04, 0.0625], rel=1e-9)
    assert out["both_curves_drawn_live"]  # every NMSE < 0.1, calm and windy both seen


def test_a_segment_just_above_the_draws_threshold_is_not_drawn_and_just_below_is():
    # windy offset (0, 0.0633) → NMSE 0.0633² / 2 / 0.02 = 0.10017 ≥ 0.1: that segment is not drawn
    wind, traj = planted([300, 300], offsets=[(0.0, 0.0), (0.0, 0.0633)])
    out = metrics(wind, live=traj)
    assert [s["nmse_live"] for s in out["segments"]] == pytest.approx([0.0, 0.0633 ** 2 / 2 / VARIANCE], rel=1e-9,
                                                                      abs=1e-20)
    assert not out["both_curves_drawn_live"]
    # 0.0632 → NMSE 0.09986 < 0.1: drawn
    wind, traj = planted([300, 300], offsets=[(0.0, 0.0), (0.0, 0.0632)])
    assert metrics(wind, live=traj)["both_curves_drawn_live"]


# -- which segments count: a transient of 2 periods plus at least one whole period ---------------------------------
def test_a_segment_of_exactly_a_transient_plus_one_period_counts_and_one_step_less_does_not():
    wind, traj = planted([300, 300, 300])  # every segment exactly 2 + 1 periods
    out = metrics(wind, live=traj)
    assert [s["steps"] for s in out["segments"]] == [[200, 299], [500, 599], [800, 899]]
    assert out["both_curves_drawn_live"]
    wind, traj = planted([300, 299, 300])  # the windy segment one step short: left out
    out = metrics(wind, live=traj)
    assert [(s["steps"], s["wind"]) for s in out["segments"]] == [([200, 299], False), ([799, 898], False)]
    assert not out["both_curves_drawn_live"]  # no windy segment counted: the switch was never shown
    wind, traj = planted([299, 301])  # the first segment one step short, the second one step over
    out = metrics(wind, live=traj)
    assert [(s["steps"], s["wind"]) for s in out["segments"]] == [([499, 599], True)]


def test_a_run_too_short_for_any_segment_draws_nothing():
    wind, traj = planted([250, 250])
    out = metrics(wind, live=traj)
    assert out["segments"] == [] and out["both_curves_drawn_live"] is False


# -- "both curves drawn" needs both wind conditions ----------------------------------------------------------------
@pytest.mark.parametrize("lengths, windy", [([1000], False), ([0, 1000], True)])
def test_a_run_with_only_one_wind_condition_does_not_draw_both_curves(lengths, windy):
    wind, traj = planted(lengths)
    out = metrics(wind, live=traj)
    assert [(s["steps"], s["wind"]) for s in out["segments"]] == [([200, 999], windy)]
    assert out["segments"][0]["nmse_live"] < 1e-20  # drawn perfectly, and still not both curves
    assert out["both_curves_drawn_live"] is False


def test_both_curves_drawn_is_per_trajectory():
    wind, traj = planted([300, 300])
    stuck = calm_curve(np.arange(600) * DT)  # keeps drawing (1, 2, 0) through the wind
    out = metrics(wind, live=traj, stuck=stuck)
    assert out["both_curves_drawn_live"] and not out["both_curves_drawn_stuck"]
    # in the windy segment the stuck CMP's error against the displaced (2, 1, π/2), by hand: both curves have
    # mean square A²/2 per coordinate, the cross terms average to 0 over a whole period, and the x offset is −0.3:
    # MSE = (A² + 0.3² + A²)/2 = 0.085 → NMSE 4.25
    assert out["segments"][1]["nmse_stuck"] == pytest.approx((2 * A * A + SHIFT ** 2) / 2 / VARIANCE, rel=1e-9)


# -- which rows blow -----------------------------------------------------------------------------------------------
def test_the_published_wind_blows_by_its_x_component_only():
    wind, traj = planted([300, 300, 300], published=True)  # calm (0, 1): a y component but no wind
    assert blowing(wind).tolist() == [False] * 300 + [True] * 300 + [False] * 300
    out = metrics(wind, live=traj)
    assert [(s["steps"], s["wind"]) for s in out["segments"]] == [([200, 299], False), ([500, 599], True),
                                                                  ([800, 899], False)]
    assert all(s["nmse_live"] < 1e-20 for s in out["segments"]) and out["both_curves_drawn_live"]
    assert blowing(np.array([[-0.5, 0.0], [0.0, -2.0], [1e-9, 1.0]])).tolist() == [True, False, True]


# -- the return criterion's window ---------------------------------------------------------------------------------
def _return_run(rows: int, inside: float, before: float) -> dict[str, np.ndarray]:
    """Three trajectories over steps 0..rows−1: the (1, 2, 0) target plus ``before`` in both coordinates until step
    rows − 1 − 10 periods (exclusive) and ``inside`` from there; the unperturbed one a constant 0.01 off."""
    t = np.arange(rows) * DT
    tgt = calm_curve(t)
    live = tgt + np.where(np.arange(rows)[:, None] < rows - 1 - 10 * PERIOD, before, inside)
    return {"unperturbed": tgt + 0.01, "live": live, "offline": live.copy()}


def test_the_return_window_is_at_most_the_last_10_periods():
    # kicked at step 0 of a 25-period run: half the periods after the kick would be 12; the window is the last 10
    planted_run = _return_run(2501, inside=0.015, before=0.2)
    out = return_metrics(planted_run, 0, 0, DT, CONFIG)
    assert out["eval_periods"] == 10 and out["eval_steps"] == [1500, 2500]
    # E = (0.015² + 0.015²)/2 = 2.25e-4 from the window alone (0.2 m off before it); E_orig = 1e-4
    assert out["E_live"] == pytest.approx(2.25e-4, rel=1e-9) and out["E_orig"] == pytest.approx(1e-4, rel=1e-9)
    assert out["returned_live"] is False  # 2.25 ≥ 2


def test_the_return_criterion_needs_two_whole_periods_after_the_kick():
    planted_run = _return_run(1001, inside=0.014, before=0.014)  # steps 0..1000
    out = return_metrics(planted_run, 0, 800, DT, CONFIG)  # 200 steps after the kick: 2 periods, the last one counts
    assert out["eval_periods"] == 1 and out["eval_steps"] == [900, 1000]
    assert out["E_live"] == pytest.approx(1.96e-4, rel=1e-9) and out["returned_live"] is True  # 1.96 < 2
    short = return_metrics(planted_run, 0, 801, DT, CONFIG)  # 199 steps: one step short
    assert "returned_live" not in short
    assert short["problem"] == ("the run ends 199 steps after the perturbation; the return criterion needs at least "
                                "2 periods (200 steps)")
