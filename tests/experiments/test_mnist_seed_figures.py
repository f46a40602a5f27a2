"""The MNIST experiments' figures over seeds draw exactly the numbers their claims read, as each seed stored them.

Each seed's result holds the claim function's arguments in ``measured`` (recorded here from planted numbers with
the same ``measured.record`` a run uses); the figure hooks decode them (``mnist_claims.over_seeds``) and hand them
to the plotting functions, which a spy replaces to compare what arrives with the planted numbers. A seed whose
result stored no such call is a row of NaN, not a shifted row. At the end every hook draws for real, through the
seeds runner's own figure step.
"""

from __future__ import annotations

import numpy as np
import pytest

from bptsb_ros.analysis import seed_plots
from bptsb_ros.experiments import measured
from bptsb_ros.experiments import mnist_drawing as draw
from bptsb_ros.experiments import mnist_labelmap as lm
from bptsb_ros.experiments import mnist_pca as pca
from bptsb_ros.experiments import mnist_readout as ro
from bptsb_ros.experiments import mnist_specific100 as sp
from bptsb_ros.experiments.mnist_claims import Separation, Skill, over_seeds

SEEDS = [0, 1, 2]


def result(experiment: str, fn=None, numbers=None) -> dict:
    """A seed's result.json as the hooks read it: the experiment's name and the stored judge call (none: a run made
    before numbers were stored)."""
    calls = [] if fn is None else [measured.record(fn, [numbers], {})]
    claims = [] if fn is None else [{"claim": c.claim, "holds": c.holds, "evidence": c.evidence} for c in fn(numbers)]
    return {"experiment": experiment, "measured": calls, "claims": claims, "rows": [], "figures": []}


@pytest.fixture
def spy(monkeypatch, tmp_path):
    """Replace the two plotting functions; record what each call got; return a path as they do."""
    got: list[tuple[str, tuple, dict]] = []

    def fake(name):
        def plot(path, *args, **kwargs):
            got.append((name, (path, *args), kwargs))
            return path
        return plot

    monkeypatch.setattr(seed_plots, "plot_bars_over_seeds", fake("bars"))
    monkeypatch.setattr(seed_plots, "plot_band", fake("band"))
    return got


def skill(acc: float) -> Skill:
    return Skill(acc, 1000, 0.1)


def test_over_seeds_decodes_each_seeds_stored_numbers_and_leaves_a_seed_without_them_empty():
    keys = [(s, n) for s, n, _ in ro.SYSTEMS]
    per = [result("mnist-readout", ro.claims, ro.ReadoutNumbers({k: skill(0.9 + 0.01 * i + 0.001 * s)
                                                                 for i, k in enumerate(keys)})) for s in (0, 2)]
    per.insert(1, result("mnist-readout"))
    got = over_seeds(per, ro.claims, lambda n: [n.skill[k].accuracy for k in keys])
    expected = np.array([[0.9 + 0.01 * i + 0.001 * s for i in range(5)] for s in (0, 2)])
    np.testing.assert_array_equal(got[[0, 2]], expected)
    assert got.shape == (3, 5) and np.isnan(got[1]).all()
    assert over_seeds([result("mnist-readout")], ro.claims, lambda n: [1.0]).shape == (1, 0)


def test_readout_figure_draws_each_seeds_accuracy_beside_the_papers(spy, tmp_path):
    keys = [(s, n) for s, n, _ in ro.SYSTEMS]
    acc = np.array([[0.91, 0.95, 0.96, 0.955, 0.97], [0.92, 0.951, 0.962, 0.949, 0.965], [0.90, 0.96, 0.97, 0.95,
                                                                                          0.96]])
    per = [result("mnist-readout", ro.claims, ro.ReadoutNumbers({k: skill(a) for k, a in zip(keys, row)}))
           for row in acc]
    assert ro.seed_figures(tmp_path, per, SEEDS) == [tmp_path / "accuracy_over_seeds.png"]
    (name, (_, panels, title), _), = spy
    bars = panels[0]
    assert name == "bars" and "3 seeds" in title
    np.testing.assert_allclose(bars.values, 100 * acc)
    assert list(bars.paper) == [91.18, 95.69, 96.77, 95.36, 96.22] and bars.hline[0] == pytest.approx(95.0)
    assert list(bars.names) == ["only brain", "DC 17", "DC 65", "MC 17", "MC 65"]


def test_drawing_figure_draws_the_errors_and_the_learned_share(spy, tmp_path):
    keys = [(b, n) for n in (17, 65) for b in ("lil", "mlp")]
    mse = np.array([[0.02, 0.01, 0.015, 0.008], [0.021, 0.011, 0.014, 0.007], [0.019, 0.012, 0.016, 0.009]])
    per = [result("mnist-drawing", draw.claims, draw.DrawingNumbers(dict(zip(keys, row)),
                                                                    {k: skill(0.5 + 0.1 * i) for i, k in
                                                                     enumerate(keys)})) for row in mse]
    draw.seed_figures(tmp_path, per, SEEDS)
    (_, (_, panels, _), _), = spy
    np.testing.assert_array_equal(panels[0].values, mse)
    np.testing.assert_allclose(panels[1].values, np.tile([50, 60, 70, 80], (3, 1)))
    assert list(panels[0].names) == ["LIL 17", "MLP 17", "LIL 65", "MLP 65"]


def test_pca_figures_draw_the_per_digit_silhouettes_and_the_bodys_gain(spy, tmp_path):
    rng = np.random.default_rng(0)
    brain, body = rng.uniform(-0.2, 0.4, (3, 10)), rng.uniform(0.2, 0.8, (3, 10))

    def sepn(per: np.ndarray) -> Separation:
        return Separation(float(per.mean()), tuple(per), skill(0.5))

    per = [result("mnist-pca", pca.claims, pca.PcaNumbers(skill(0.6), sepn(b), sepn(y))) for b, y in zip(brain, body)]
    per[1] = result("mnist-pca")  # a seed that stored no numbers
    brain[1] = body[1] = np.nan
    pca.seed_figures(tmp_path, per, SEEDS)
    (n1, (_, x1, curves), kw1), (n2, (_, x2, gain), kw2) = spy
    assert n1 == n2 == "band" and x1.tolist() == x2.tolist() == list(range(10))
    b, y = curves.values()
    np.testing.assert_array_equal(b, brain)
    np.testing.assert_array_equal(y, body)
    np.testing.assert_array_equal(gain["body − brain"], body - brain)
    assert kw1["highlight"] == kw2["highlight"] == (5, 7, 8) and kw2["hline"] == 0.0


def test_labelmap_figure_draws_each_masss_size_in_its_group(spy, tmp_path):
    joined = np.array([False] * 12 + [True] * 4)
    sizes = np.array([np.linspace(0.5, 0.9, 16), np.linspace(0.6, 1.0, 16)])
    per = [result("mnist-labelmap", lm.claims, lm.LabelMapNumbers(s, joined, np.arange(20, 36), np.arange(10)))
           for s in sizes]
    lm.seed_figures(tmp_path, per, SEEDS[:2])
    (_, (_, panels, _), _), = spy
    np.testing.assert_array_equal(panels[0].values, sizes)
    assert list(panels[0].names) == [str(m) for m in range(20, 36)]
    assert list(panels[0].groups) == ["not joined to the CMP"] * 12 + ["joined to the CMP"] * 4
    assert panels[0].hline[0] == 0.5
    assert lm.seed_figures(tmp_path, [result("mnist-labelmap")], [0]) == []  # nothing stored: nothing drawn


def _specific(scale: float, spread=True, full=True) -> sp.Specific100Numbers:
    keys = [(b, s, m) for b, s, m, _ in sp.systems()]
    sep = lambda s: Separation(s, (s,) * 10, skill(0.5))  # noqa: E731
    maps = lambda b, r: lm.LabelMapNumbers(np.full(16, 0.8), np.array([False] * 12 + [True] * 4),  # noqa: E731
                                           np.arange(20, 36), np.arange(10), np.full(16, b), np.full(16, r))
    extra = {}
    if full:
        extra |= dict(full_skill=skill(0.5), full_brain=sep(0.2), full_body=sep(0.3 * scale), full_maps=maps(0.1, 2))
    if spread:
        extra["brain_spread"] = sp.LabelSpread(np.arange(10) * 0.01 * scale, np.full(10, 0.1))
    return sp.Specific100Numbers({k: 0.01 * scale for k in keys}, {k: skill(0.95) for k in keys}, sep(0.05),
                                 sep(0.2 * scale), maps(0.3 * scale, 4 * scale), **extra)


def test_specific100_figures_draw_errors_comparison_and_spread(spy, tmp_path):
    per = [result("mnist-specific100", sp.claims, _specific(s)) for s in (1.0, 1.5)]
    paths = sp.seed_figures(tmp_path, per, SEEDS[:2])
    assert [p.name for p in paths] == ["errors_over_seeds.png", "comparison_over_seeds.png",
                                       "brain_spread_over_seeds.png"]
    (_, (_, errors, _), _), (_, (_, compare, _), _), (_, (_, x, curves), kw) = spy
    np.testing.assert_allclose(errors[0].values, [[0.01] * 8, [0.015] * 8])
    np.testing.assert_allclose(errors[1].values, np.full((2, 8), 95.0))
    gain, boundary, regions = (c.values for c in compare)
    np.testing.assert_allclose(gain, [[0.2 - 0.05, 0.3 - 0.2], [0.3 - 0.05, 0.45 - 0.2]])
    np.testing.assert_allclose(boundary, [[0.3, 0.1], [0.45, 0.1]])
    np.testing.assert_allclose(regions, [[4, 2], [6, 2]])
    np.testing.assert_allclose(curves["brain output"], [np.arange(10) * 0.1,
                                                                             np.arange(10) * 0.15])
    assert kw["hline"] == sp.ONE_POINT and x.tolist() == list(range(10))


def test_specific100_figures_leave_out_what_no_seed_measured(spy, tmp_path):
    per = [result("mnist-specific100", sp.claims, _specific(1.0, spread=False, full=False))]
    assert [p.name for p in sp.seed_figures(tmp_path, per, [0])] == ["errors_over_seeds.png"]


def test_the_seeds_runner_draws_every_mnist_figure(tmp_path):
    """Through the multi-seed run's figure step (the hooks as registered), for real: files beside the strip."""
    from bptsb_ros.experiments.seeds import _figures

    keys = [(s, n) for s, n, _ in ro.SYSTEMS]
    cases = {"mnist-readout": (ro.claims, lambda s: ro.ReadoutNumbers({k: skill(0.95 + 0.001 * s) for k in keys})),
             "mnist-specific100": (sp.claims, lambda s: _specific(1 + s))}
    for name, (fn, numbers) in cases.items():
        per = [result(name, fn, numbers(s)) for s in (0, 1)]
        out = tmp_path / name
        figs = _figures(out, [0, 1], per, lambda msg: pytest.fail(msg))
        assert figs[0] == "seeds.png" and len(figs) > 1
        for f in figs:
            assert (out / f).is_file() and (out / f).stat().st_size > 0, f
