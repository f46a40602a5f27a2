"""lissajous-perturbation's numbers from planted errors, every expected value written here by hand: the paper's trial
(a kick of the running cycle) with its two readings of E_orig — the same loop unperturbed (primary) and the open
loop's error for both loops (the paper's literal "E_orig was the error in the open loop") —, and the windows its
errors are read over (the kick trial's last ``eval_periods`` periods, the restart trial's last windows)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bptsb_ros.experiments import lissajous_perturbation as lpert
from bptsb_ros.experiments.registry import Context
from bptsb_ros.experiments.result import ExperimentResult

SEEDS = 4
NAN = float("nan")
#: σ = 0: every row is the unperturbed run. E_orig: SWG 1e-4, FL 3e-4 (3× the SWG's, so with the literal E_orig the
#: unperturbed FL already "fails": 3e-4 ≥ 2 × 1e-4)
OPEN_0, CLOSED_0 = 1e-4, 3e-4
#: σ = 0.1 … 0.9 (the same four seeds each) and σ = 1.0
OPEN_ROW = [1e-4, 1.5e-4, 3e-4, NAN]  # < 2e-4: 2 of 4 (a NaN, a blown-up row, never returns)
CLOSED_ROW = [1.5e-4, 2.5e-4, 5e-4, 7e-4]  # < 6e-4 (primary): 3 of 4; < 2e-4 (literal): 1 of 4
CLOSED_LAST = [1.5e-4, NAN, 6e-4, 1e-3]  # σ = 1.0: primary 1 of 4 (6e-4 is not < 6e-4); literal 1 of 4
RATE_OPEN = [1.0] + [0.5] * 10
RATE_CLOSED = [1.0] + [0.75] * 9 + [0.25]
RATE_LITERAL = [0.0] + [0.25] * 10
TARGET_MS = 0.02


def planted_errors() -> tuple[np.ndarray, np.ndarray]:
    e_open = np.array([[OPEN_0] * SEEDS] + [OPEN_ROW] * 10)
    e_closed = np.array([[CLOSED_0] * SEEDS] + [CLOSED_ROW] * 9 + [CLOSED_LAST])
    return e_open, e_closed


def run_kick_variant(monkeypatch, tmp_path) -> tuple[ExperimentResult, dict]:
    """``_kick_variant`` with ``perturbation_errors`` answering the planted errors (rows σ_j·seeds + i) and the
    figure recorded instead of drawn."""
    e_open, e_closed = planted_errors()
    batch = e_open.size

    def errors(trained, seeds, *, settle, run, eval_periods, sigmas=lpert.SIGMAS):
        assert (seeds, settle, run, eval_periods) == (SEEDS, 3, 20, 5)
        # the errors over the periods before the last ones: as the last (every run settled; not what is tested here)
        return {"batch": batch, "steps": run * 100, "open": e_open.reshape(-1), "closed": e_closed.reshape(-1),
                "open_before": e_open.reshape(-1), "closed_before": e_closed.reshape(-1),
                "open_wall_s": 2.0, "closed_wall_s": 4.0, "open_traj": np.zeros((3, batch, 2)),
                "closed_traj": np.zeros((3, batch, 2)), "open_diverged": np.isnan(e_open.reshape(-1)),
                "closed_diverged": np.isnan(e_closed.reshape(-1)), "t0_open": 10.0, "t0_closed": 13.0}

    figure: dict = {}

    def plot(path, sigmas, rates, **kw):
        figure.update(rates)
        path.write_bytes(b"")
        return path

    monkeypatch.setattr(lpert, "perturbation_errors", errors)
    monkeypatch.setattr("bptsb_ros.analysis.autonomy_plots.plot_perturbation", plot)
    result = ExperimentResult("lissajous-perturbation", "Fig. 4", "smoke", 0)
    ctx = Context("smoke", 0, tmp_path, result, progress=False, log=lambda msg: None)
    trained = SimpleNamespace(agent=SimpleNamespace(dt=0.01), amplitude=0.2, omega=2 * math.pi, period=100,
                              metrics={"loss": [0.5]})
    values = {"sim_time": 5, "n_seeds": SEEDS, "run_periods": 20, "eval_periods": 5, "settle_periods": 3}
    lpert._kick_variant(ctx, trained, "paper", lpert.TRIAL_TEXT[False], values, TARGET_MS, first=True)
    return result, figure


def test_the_literal_rows_compare_the_closed_loop_with_the_open_loops_error(monkeypatch, tmp_path):
    result, figure = run_kick_variant(monkeypatch, tmp_path)
    rows = {(r.system, r.metric): r.ours for r in result.rows}
    for j, sigma in enumerate(np.round(np.arange(11) / 10, 1)):
        assert rows[(f"SWG (open loop), σ = {sigma:.1f}", "return rate")] == pytest.approx(RATE_OPEN[j])
        assert rows[(f"FL (closed loop), σ = {sigma:.1f}", "return rate")] == pytest.approx(RATE_CLOSED[j])
        assert rows[(f"FL, E_orig = SWG error (literal), σ = {sigma:.1f}", "return rate")] == pytest.approx(
            RATE_LITERAL[j])
    assert rows[("SWG (open loop)", "unperturbed error E_orig")] == pytest.approx(OPEN_0)
    assert rows[("FL (closed loop)", "unperturbed error E_orig")] == pytest.approx(CLOSED_0)
    assert rows[("SWG (open loop)", "unperturbed error / target mean square")] == pytest.approx(0.005)
    assert rows[("FL (closed loop)", "unperturbed error / target mean square")] == pytest.approx(0.015)
    assert rows[("SWG batched sweep", "rollouts per second")] == pytest.approx(44 / 2.0)
    assert rows[("FL batched sweep", "rollouts per second")] == pytest.approx(44 / 4.0)
    # the figure draws the same three curves
    assert list(figure) == ["SWG (open loop)", "FL (closed loop)", "FL, E_orig = SWG error (literal)"]
    for rates, expected in zip(figure.values(), (RATE_OPEN, RATE_CLOSED, RATE_LITERAL), strict=True):
        assert np.asarray(rates) == pytest.approx(expected)
    # the claim "almost the same" (both draw, some rate below 1): max |0.5 − 0.75| = |0.5 − 0.25| = 0.25 > 0.2,
    # first reached at σ = 0.1; its evidence names the literal reading's rate at σ = 0
    same = result.claims[2]
    assert same.holds is False
    assert same.evidence == ("max |rate_SWG − rate_FL| = 0.25 (at σ = 0.1); with the literal E_orig (SWG error) "
                             "the FL rate at σ = 0.0 is 0.00")
    notes = result.details["notes"]
    assert "the unperturbed closed loop already fails (its error is 3.00× the SWG's, ≥ 2)" in notes
    assert result.details["diverged_open"] == 10 and result.details["diverged_closed"] == 1


# -- the windows the errors are read over --------------------------------------------------------------------------
def _curve(t: np.ndarray) -> np.ndarray:
    """(1, 2, 0), amplitude 0.2 m, ω = 2π rad/s: the single-curve target, written out."""
    return np.stack([0.2 * np.cos(2 * np.pi * t), 0.2 * np.sin(4 * np.pi * t)], -1)


def test_the_kick_trials_error_is_read_over_its_last_periods_and_their_closing_step():
    """Steps k0 … k0 + 500 (5 periods of 100) of two rows: 0.5 m off until the last 3 periods, then offset c1 over
    the first of them and c2 from there to the last step. The error is the mean over the 3 periods of each period's
    MSE (period + 1 rows, the next period's first row closing it; no time shift does better than none here)."""
    k0, period, dt, periods = 37, 100, 0.01, 3
    steps = np.arange(k0, k0 + 5 * period + 1)
    traj = np.repeat(_curve(steps * dt)[:, None, :], 2, axis=1)
    first_row = len(steps) - periods * period - 1  # the window's first row
    c1, c2 = np.array([[0.01, 0.02], [0.03, 0.0]]), np.array([[0.02, 0.0], [0.0, 0.01]])  # per row b: (x, y) [m]
    traj[:first_row] += 0.5
    traj[first_row:first_row + period] += c1
    traj[first_row + period:] += c2
    trained = SimpleNamespace(amplitude=0.2, omega=2 * np.pi)
    out = lpert._errors(traj, k0, period, periods, dt, trained, lambda t, a, w: _curve(t))
    sq1, sq2 = (c1 ** 2).sum(1) / 2, (c2 ** 2).sum(1) / 2  # mean over x, y of the squared offset
    first = (period * sq1 + sq2) / (period + 1)
    assert out == pytest.approx((first + 2 * sq2) / 3, rel=1e-9)


def test_the_restart_trials_windows_may_fill_the_whole_run():
    traj = np.zeros((7, 1, 2))  # steps 0..6; windows of 2 steps: (1, 2), (3, 4), (5, 6)
    traj[1:, 0, 0] = [9.0, 9.0, 1.0, 3.0, 2.0, 0.0]  # windows' MSE (mean of x², y² = 0): 40.5, 2.5, 1
    out = lpert.window_errors(traj, np.zeros((7, 2)), 2, 3)  # exactly the 6 steps the run has
    assert out[0] == pytest.approx((40.5 + 2.5 + 1.0) / 3)
    with pytest.raises(ValueError, match="the run has 6 steps, fewer than 4 windows of 2"):
        lpert.window_errors(traj, np.zeros((7, 2)), 2, 4)
    with pytest.raises(ValueError, match="the run has 6 steps, fewer than 1 windows of 7"):
        lpert.window_errors(traj, np.zeros((7, 2)), 7, 1)
