"""The across-seed figures of the SWG experiments (``@seed_figure`` hooks): each draws exactly the numbers its claims
read in every seed (``result.json`` ``measured``), leaves out a seed whose system diverged, and writes its PNG.

The per-seed results are planted: each holds only the ``measured`` record of planted claim numbers, as
:meth:`Context.judge <bptsb_ros.experiments.registry.Context.judge>` writes it. The plot function is replaced by one
that keeps what it was given, so the test compares the drawn arrays with the planted ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bptsb_ros.analysis import seed_plots
from bptsb_ros.experiments import lissajous_perturbation as lpert
from bptsb_ros.experiments import lissajous_switching as lsw
from bptsb_ros.experiments import locomotion_closed_loop as locl
from bptsb_ros.experiments import locomotion_headwind as hw
from bptsb_ros.experiments import locomotion_perturbation as lopert
from bptsb_ros.experiments.measured import record
from bptsb_ros.experiments.seeds import _SEED_FIGURES

SIG = np.round(np.arange(11) / 10, 1)
WINDS = np.round(np.arange(-1.0, 2.0001, 0.05), 10)


def result(experiment: str, *calls) -> dict:
    """A seed's result.json as far as the hooks read it: the experiment and its judge calls (fn, args, label)."""
    return {"experiment": experiment, "measured": [record(fn, args, {}, label) for fn, args, label in calls]}


@pytest.fixture
def drawn(monkeypatch):
    """Replace every seed_plots function by one that records (name, path, args, kwargs) and writes a stub PNG."""
    calls = []

    def fake(name):
        def plot(path, *args, **kwargs):
            calls.append((name, Path(path), args, kwargs))
            Path(path).write_bytes(b"png")
            return Path(path)
        return plot

    for name in ("plot_band_panels", "plot_share_panels", "plot_period_map", "plot_count_histogram"):
        monkeypatch.setattr(seed_plots, name, fake(name))
    return calls


def test_lissajous_perturbation_bands_are_the_rates_the_claims_read(tmp_path, drawn):
    def seed(k: float, diverged: str = ""):
        paper = lpert.PerturbationNumbers(SIG, 1 - k * SIG, 1 - 2 * k * SIG, 0.01, 0.02, variant="paper",
                                          diverged=diverged)
        authors = lpert.PerturbationNumbers(SIG, 1 - k * SIG / 2, 1 - k * SIG, 0.01, 0.02, variant="authors")
        return result("lissajous-perturbation", (lpert.claims, (paper,), ""),
                      (lpert.claims, (authors,), "[authors: restarts from the displaced layout at rest, t = 0] "))

    per_seed = [seed(0.3), seed(0.5), seed(0.9, diverged="the training diverged (planted)")]
    paths = _SEED_FIGURES["lissajous-perturbation"](tmp_path, per_seed, [0, 1, 2])
    assert paths == [tmp_path / "perturbation_seeds.png"] and paths[0].is_file()
    (name, _, _, kwargs), = drawn
    panels = drawn[0][2][0]
    assert name == "plot_band_panels" and list(panels) == [
        "paper: a kick of the running cycle", "authors: restarts from the displaced layout at rest, t = 0"]
    paper = panels["paper: a kick of the running cycle"]
    np.testing.assert_array_equal(paper["x"], SIG)
    # the diverged seed is left out of its panel only; the other trial keeps all three seeds
    np.testing.assert_allclose(paper["curves"]["FL (closed loop)"], [1 - 0.6 * SIG, 1 - 1.0 * SIG])
    assert len(panels["authors: restarts from the displaced layout at rest, t = 0"]["curves"]["SWG (open loop)"]) == 3
    assert "[m]" in kwargs["xlabel"] and "[-]" in kwargs["ylabel"]


def test_locomotion_perturbation_bands_per_draw(tmp_path, drawn):
    s = np.array(lopert.SIGMAS)
    per_seed = [result("locomotion-perturbation",
                       (lopert.claims, (lopert.PerturbationRates(s, 1 - k * s, 1 - k * s / 2, True, True, "paper"),),
                        ""),
                       (lopert.claims, (lopert.PerturbationRates(s, 1 - k * s, 1 - k * s, True, True, "authors"),),
                        "[authors: ...] ")) for k in (0.2, 0.4)]
    per_seed.append(result("locomotion-perturbation", (lopert.claims, (lopert.PerturbationRates(
        s, np.full(11, np.nan), np.full(11, np.nan), False, False, "paper", "no agent (planted)"),), "")))
    assert _SEED_FIGURES["locomotion-perturbation"](tmp_path, per_seed, [0, 1, 2]) == [
        tmp_path / "return_rate_seeds.png"]
    panels = drawn[0][2][0]
    assert list(panels) == ["paper", "authors"] and "[m]" in panels["paper"]["xlabel"]
    assert "[-]" in panels["authors"]["xlabel"]  # the authors' σ is relative to the body's extent
    np.testing.assert_allclose(panels["paper"]["curves"]["FL (closed loop)"], [1 - 0.1 * s, 1 - 0.2 * s])


def test_bifurcation_map_rows_are_the_periods_of_the_seeds_that_trained(tmp_path, drawn):
    per = [np.where(WINDS > 0.2, 0, 1), np.where(WINDS > 0.5, 2, 1)]
    per_seed = [result("lissajous-bifurcation",
                       (lsw.bifurcation_claims, (lsw.BifurcationNumbers(WINDS, p, {0.0: 0.05, 1.0: 0.05},
                                                                        "paper wind (F, 0)"), ""), ""),
                       (lsw.bifurcation_claims, (lsw.BifurcationNumbers(WINDS, np.full(61, -1), {},
                                                                        "authors' protocol", "diverged (planted)"),
                                                 " [authors' protocol]"), "")) for p in per]
    assert _SEED_FIGURES["lissajous-bifurcation"](tmp_path, per_seed, [3, 7]) == [tmp_path / "bifurcation_seeds.png"]
    (_, _, args, kwargs), = drawn
    x, panels = args
    np.testing.assert_array_equal(x, WINDS)
    assert list(panels) == ["paper wind (F, 0)"]  # the diverged variant has no row in any seed
    seeds, rows = panels["paper wind (F, 0)"]
    assert seeds == [3, 7]
    np.testing.assert_array_equal(rows, np.stack(per))
    assert [(lo, hi) for lo, hi, _ in kwargs["spans"]] == [(-1.0, 0.2), (0.2, 0.6), (1.2, 2.0)]


def test_timing_shares_are_the_converging_runs_per_n(tmp_path, drawn):
    band = np.where((np.arange(100) >= 22) & (np.arange(100) <= 69), 0.5, 0.05)
    per_seed = [
        result("lissajous-timing", (lsw.timing_claims, (lsw.TimingNumbers(band, np.full(100, 0.05), 5, "(1,3,0)",
                                                                           "paper wind (F, 0)"), ""), "")),
        result("lissajous-timing", (lsw.timing_claims, (lsw.TimingNumbers(
            np.full(100, 0.0999), np.full(100, np.inf), 5, "(1,3,0)", "paper wind (F, 0)",
            random_diverged="diverged (planted)"), ""), "")),
    ]
    assert _SEED_FIGURES["lissajous-timing"](tmp_path, per_seed, [0, 1]) == [tmp_path / "timing_seeds.png"]
    panel = drawn[0][2][0]["paper wind (F, 0)"]
    fixed = np.array(panel["shares"]["fixed timing (n = 0)"])
    assert fixed.shape == (2, 100) and fixed[0, 30] == 0 and fixed[0, 10] == 1 and fixed[1].all()
    assert len(panel["shares"]["random timing"]) == 1  # the seed whose random-timing system diverged is left out
    assert panel["spans"][0][:2] == (21.5, 69.5)


def test_headwind_band_is_the_speed_relative_to_each_seeds_target(tmp_path, drawn):
    winds = np.round(np.arange(-2.0, 1.0 + 1e-9, 0.05), 2)
    phases = {"calm": 1.0, "windy_early": 0.8, "windy_late": 1.0}
    blocks = dict.fromkeys(hw.PHASES, 5)
    per_seed = [result("locomotion-headwind",
                       (hw.claims, (hw.HeadwindNumbers(t, phases, blocks, winds, t * (1 + 0.1 * winds), -1.0,
                                                       "paper"),), "")) for t in (0.2, 0.5)]
    per_seed.append(result("locomotion-headwind", (hw.claims, (hw.HeadwindNumbers(
        np.nan, phases, blocks, winds, np.full(61, np.nan), -1.0, "paper", "diverged (planted)"),), "")))
    assert _SEED_FIGURES["locomotion-headwind"](tmp_path, per_seed, [0, 1, 2]) == [
        tmp_path / "speed_vs_wind_seeds.png"]
    (_, _, args, kwargs), = drawn
    panel = args[0]["paper"]
    np.testing.assert_allclose(panel["curves"]["after switching training"], [1 + 0.1 * winds] * 2)
    assert kwargs["hline"] == 1.0 and "[N]" in kwargs["xlabel"] and "[-]" in kwargs["ylabel"]


def test_closed_loop_success_counts_per_seed_with_the_papers_eight(tmp_path, drawn):
    def seed(successes: int, forward: int = 20):
        speed = np.array([0.5] * forward + [0.0] * (20 - forward))
        ok = np.arange(20) < successes
        return result("locomotion-closed-loop-20", (locl.claims, (locl.ClosedLoopCounts(speed, ok),), ""))

    per_seed = [seed(4), seed(1, forward=19), seed(8)]
    assert _SEED_FIGURES["locomotion-closed-loop-20"](tmp_path, per_seed, [0, 1, 2]) == [
        tmp_path / "success_count_seeds.png"]
    (_, _, args, kwargs), = drawn
    assert list(args[0]) == [4, 1, 8] and kwargs["paper"] == 8 and kwargs["total"] == 20
    assert "19–20 moving forward" in kwargs["xlabel"]


def test_hooks_draw_nothing_without_numbers(tmp_path, drawn):
    for name in ("lissajous-perturbation", "lissajous-bifurcation", "lissajous-timing", "locomotion-perturbation",
                 "locomotion-headwind", "locomotion-closed-loop-20"):
        assert _SEED_FIGURES[name](tmp_path, [{"experiment": name, "measured": []}], [0]) == []
    assert drawn == []


def test_a_hook_draws_a_real_figure(tmp_path):
    per_seed = [result("lissajous-bifurcation", (lsw.bifurcation_claims, (lsw.BifurcationNumbers(
        WINDS, np.where(WINDS > 0.2, 0, 1), {0.0: 0.05, 1.0: 0.05}, "paper wind (F, 0)"), ""), ""))] * 2
    path, = _SEED_FIGURES["lissajous-bifurcation"](tmp_path, per_seed, [0, 1])
    assert path.read_bytes()[:4] == b"\x89PNG"
