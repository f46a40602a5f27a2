"""Every figure function of the package called on small planted data (no training, no simulation).

``CASES``: name → function(out_dir) returning the PNG it wrote. Used by tests/analysis/test_figures.py; run as a script
(``python tests/figure_cases.py DIR``) to write every figure into DIR for a look.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bptsb_ros.analysis import autonomy_plots as A
from bptsb_ros.analysis import locomotion_plots as L
from bptsb_ros.analysis import mnist_plots as M
from bptsb_ros.analysis import plots as P
from bptsb_ros.analysis import seed_plots as S
from bptsb_ros.analysis import timeseries_plots as T

RNG_SEED = 3
DT = 0.01
#: fewer panels in the many-panel figures (the tests set it: same code paths, a third of the time)
SMALL = False


def _rng() -> np.random.Generator:
    return np.random.default_rng(RNG_SEED)


def _lissajous(t: np.ndarray, a: float = 1, b: float = 2, r: float = 0.3) -> np.ndarray:
    return np.stack([r * np.sin(a * t), r * np.sin(b * t)], axis=1)


def _targets() -> list[np.ndarray]:
    """Ten planted digit strokes (T_d + 1, 2) [m]: circles and spirals of different lengths."""
    out = []
    for d in range(10):
        s = np.linspace(0, (1 + d / 5) * np.pi, 30 + 3 * d)
        out.append(np.stack([0.1 * np.sin(s) * (1 + d / 20), 0.12 * (1 - np.cos(s))], axis=1))
    return out


def _fake_ipc(labels: list[str], n_f: int = 24) -> SimpleNamespace:
    rng = _rng()
    degrees = np.repeat([1, 2, 3], n_f // 3)
    delays = np.tile(np.arange(n_f // 3), 3)
    cap = rng.uniform(0, 0.08, (len(labels), n_f))
    return SimpleNamespace(labels=labels, group=labels.index, capacity=cap, degrees=degrees,
                           max_delays=lambda: delays, rank=np.full(len(labels), 1.0))


def loss(out: Path) -> Path:
    y = np.exp(-np.arange(400) / 80) + 0.05 * _rng().random(400) + 0.01
    return P.plot_loss(out / "loss.png", y, "trajectory MSE [m²]", "lissajous")


def lissajous(out: Path) -> Path:
    t = np.arange(0, 2 * np.pi, DT)
    tgt = _lissajous(t)
    return P.plot_lissajous(out / "lissajous.png", t, {"open loop (SWG)": tgt * 1.05 + 0.01,
                                                       "closed loop (FL)": tgt * 0.95}, tgt)


def speed(out: Path) -> Path:
    t = np.arange(0, 20, DT)
    v = 0.3 + 0.1 * np.sin(t) + 0.05 * _rng().standard_normal(len(t))
    return P.plot_speed(out / "speed.png", t, {"live": v, "offline": v * 0.97}, target=0.3, window=100,
                        shade=[(5, 8), (12, 15)], shade_label="wind blowing")


def series(out: Path) -> Path:
    rng = _rng()
    u = rng.random(120)
    return P.plot_series(out / "narma.png", {"input u": u, "target y": np.convolve(u, [0.5, 0.3], "same"),
                                             "output (CMP y)": np.convolve(u, [0.45, 0.3], "same")},
                         "sample [τ steps]", "u [-]; target y, output (CMP y) [m]", "expanded NARMA2", (60, 120))


def spring_lengths(out: Path) -> Path:
    t = np.arange(0, 5, DT)
    e = np.arange(48)
    lengths = 0.5 + 0.05 * e / 48 + 0.02 * np.sin(np.outer(t, 1 + e / 10))
    return P.plot_spring_lengths(out / "spring_lengths.png", t, lengths)


def ipc_bars(out: Path) -> Path:
    return P.plot_ipc_bars(out / "ipc.png", _fake_ipc([f"mass {i} {a}" for i in range(6) for a in "xy"]),
                           title="IPC of a planted result")


def ipc_panels(out: Path) -> Path:
    res = _fake_ipc(["output, epoch 0", "output, epoch 1", "target"] + [f"mass {i} {a}" for i in range(10)
                                                                       for a in "xy"])
    left = T.IpcPanel.of(res, res.labels[:3], "output by epoch", legend=False)
    right = T.IpcPanel.of(res, res.labels[3:], "each movable mass", highlight=2)
    return T.plot_ipc_panels(out / "ipc_panels.png", [[left, right]] * (1 if SMALL else 2), width_ratios=[5, 20])


def memory_error(out: Path) -> Path:
    rng = _rng()
    delays = [1, 4, 8, 12, 17]
    errors = {b: 0.05 * np.arange(1, 6)[:, None] + 0.02 * rng.random((5, 3)) for b in ("double-circle",
                                                                                      "multiple-circle")}
    u = rng.random(200)
    t = np.arange(100, 160)
    target = np.roll(u, 8)
    return T.plot_memory_error(out / "memory_error.png", delays, errors, t, u, target,
                               {b: target[t] + 0.05 * rng.standard_normal(len(t)) for b in errors}, 8)


def narma_emulation(out: Path) -> Path:
    rng = _rng()
    u = rng.random(250)
    target = np.convolve(u, [0.4, 0.3, 0.1], "same")
    t = np.arange(100, 200)
    names = ["LIL + double circle", "MLP + double circle", "LIL + chain", "MLP + chain"]
    outs = {n: target + 0.03 * (i + 1) * rng.standard_normal(len(u)) for i, n in enumerate(names)}
    return T.plot_narma_emulation(out / "narma_emulation.png", t, u, target, outs,
                                  {n: 0.1 * (i + 1) for i, n in enumerate(names)}, "expanded NARMA2 (planted)")


def targets(out: Path) -> Path:
    return M.plot_targets(out / "targets.png", _targets(), DT)


def best_drawings(out: Path) -> Path:
    rng = _rng()
    tg = _targets()
    t_max = max(len(x) for x in tg)
    labels = np.arange(30) % 10
    drawings = np.zeros((30, t_max, 2))
    for i, d in enumerate(labels):
        drawings[i, : len(tg[d])] = tg[d] + 0.01 * rng.standard_normal(tg[d].shape)
        drawings[i, len(tg[d]):] = drawings[i, len(tg[d]) - 1]
    systems = {name: {"drawings": drawings, "errors": rng.uniform(1e-4, 1e-3, 30), "labels": labels}
               for name in ("LIL + multiple circle", "MLP + double circle")[: 1 if SMALL else 2]}
    return M.plot_best_drawings(out / "drawings.png", systems, tg, DT)


def error_bars(out: Path) -> Path:
    return M.plot_error_bars(out / "errors.png", ["only brain", "LIL + double", "MLP + multiple"],
                             [3e-3, 1.5e-3, 1e-3], [2e-4, 1e-4, 1e-4], "MNIST drawing: mean test MSE")


def pca(out: Path) -> Path:
    rng = _rng()
    labels = np.repeat(np.arange(10), 30)
    centres = rng.standard_normal((10, 2))
    pts = centres[labels] + 0.2 * rng.standard_normal((300, 2))
    scores = {p: {"silhouette_2d": 0.4, "probe_2d": 0.8} for p in ("brain", "body")}
    return M.plot_pca(out / "pca.png", pts, pts * 0.5, labels, scores, "PCA of planted clusters")


def label_maps(out: Path) -> Path:
    rng = _rng()
    maps = rng.integers(0, 10, (10, 3, 9, 9))
    return M.plot_label_maps(out / "label_maps.png", maps, np.linspace(-0.2, 0.2, 9),
                             {"mass 4 (largest)": 0, "mass 7 (smallest)": 2} if not SMALL else {"mass 4": 0},
                             rng.random((10, 3)),
                             "planted label maps")


def label_map_sizes(out: Path) -> Path:
    rng = _rng()
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pos = np.concatenate([np.stack([np.cos(ang), np.sin(ang)], 1), 0.5 * np.stack([np.cos(ang), np.sin(ang)], 1),
                          [[0.0, 0.0]]])
    springs = np.array([(i, (i + 1) % 12) for i in range(12)] + [(i, 12 + i) for i in range(12)]
                       + [(12 + i, 24) for i in range(12)])
    fixed = np.zeros(25, bool)
    fixed[:12] = True
    idx = np.arange(12, 24)
    return M.plot_label_map_sizes(out / "label_map_sizes.png", pos, springs, fixed, 24, idx, rng.random(12),
                                  idx % 3 == 0, "label-map size per mass")


def curves(out: Path) -> Path:
    x = np.arange(1, 300)
    return M.plot_curves(out / "training.png", {"LIL + double": 1 / x, "MLP + multiple": 0.5 / x + 1e-3},
                         "batch drawing MSE [m²]", "BPTSB training")


def live_drawings(out: Path) -> Path:
    rng = _rng()
    tg = _targets()
    labels = np.arange(7) % 10
    e = max(len(x) for x in tg)
    live = np.stack([np.pad(tg[d], ((0, e - len(tg[d])), (0, 0)), mode="edge") for d in labels])
    live = live + 0.005 * rng.standard_normal(live.shape)
    return M.plot_live_drawings(out / "live_drawings.png", live, live * 0.98, tg, labels, rng.random(7) * 1e-3,
                                DT, list(range(0, 700, 100)))


def perturbation(out: Path) -> Path:
    seeds, period = 2, 100
    sigmas = np.arange(0, 1.01, 0.1)
    t0 = 0.0
    t = t0 + DT * np.arange(4 * period + 1)
    base = _lissajous(t * 2 * np.pi / (period * DT))
    traj = np.repeat(base[:, None], seeds * len(sigmas), axis=1)
    ok = np.ones(seeds * len(sigmas), bool)
    ok[-3:] = False
    traj[:, -3:] *= 1.6
    return A.plot_perturbation(out / "perturbation.png", sigmas, {"FL (closed loop)": np.linspace(1, 0.2, 11),
                                                                  "SWG (open loop)": np.linspace(1, 0.6, 11)},
                               closed_traj=traj, closed_ok=ok, dt=DT, t0=t0,
                               target=lambda tt: _lissajous(tt * 2 * np.pi / (period * DT)), seeds=seeds,
                               period=period)


def _wind_run() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(0, 8, DT)
    wind = (t >= 4).astype(float)
    cmp = np.where(wind[:, None] > 0.5, _lissajous(t, 1, 3), _lissajous(t, 1, 2))
    return t, wind, cmp


def switching_curves(out: Path) -> Path:
    t, wind, cmp = _wind_run()
    return A.plot_switching_curves(out / "switching_curves.png", cmp * 1.02, cmp, wind,
                                   {"no wind (steps 100-399)": (100, 400), "wind (steps 500-799)": (500, 800)},
                                   title="planted")


def switching_dynamics(out: Path) -> Path:
    t, wind, cmp = _wind_run()
    r = cmp[:, None, :] * np.linspace(0.2, 1.0, 6)[None, :, None]
    return A.plot_switching_dynamics(out / "switching_dynamics.png", t, r, wind, 5)


def bifurcation(out: Path) -> Path:
    rng = _rng()
    winds = np.round(np.arange(-0.5, 1.51, 0.1), 2)
    t = np.arange(0, 6, DT)
    cmp = np.stack([_lissajous(t, 1, 2 + w) for w in winds], axis=1)
    maxima = [0.3 + 0.01 * rng.standard_normal(1 + i % 4) for i in range(len(winds))]
    return A.plot_bifurcation(out / "bifurcation.png", winds, maxima, maxima, cmp, [0.0, 0.5, 1.0],
                              np.array([1 + i % 3 for i in range(len(winds))]))


def timing(out: Path) -> Path:
    period = 100
    t = np.arange(0, 6 * period) * DT
    cmp = np.repeat(_lissajous(t * 2 * np.pi / (period * DT), 1, 3)[:, None], 100, axis=1)
    conv = np.arange(100) % 7 != 3
    runs = {name: {"n": np.arange(100), "converged": conv, "t": t, "cmp": cmp} for name in ("fixed", "random")}
    return A.plot_timing(out / "timing.png", runs, period=period,
                         target=lambda tt, s: _lissajous((tt + s) * 2 * np.pi / (period * DT), 1, 3),
                         shifts={"fixed": 0.0, "random": 0.0})


def scheme_ratios(out: Path) -> Path:
    rng = _rng()
    return A.plot_scheme_ratios(out / "schemes.png", ["(1, 2, 0)", "(1, 3, 0)", "(2, 3, 0)"], [0, 1, 2, 3, 4],
                                rng.uniform(0.5, 1.5, (3, 5)), rng.uniform(0.5, 1.5, (3, 5)),
                                rng.uniform(0.5, 1.5, (3, 5)), np.where(np.eye(3, 5) > 0, np.inf, 0.8))


def perturbed_run(out: Path) -> Path:
    t = np.arange(0, 6, DT)
    tgt = _lissajous(t)
    live = tgt.copy()
    live[200:] += 0.1 * np.exp(-(t[200:, None] - 2))
    return A.plot_perturbed_run(out / "perturbed_run.png", t, {"live": live, "offline": live * 1.01,
                                                               "unperturbed": tgt}, tgt, 2.0, 4.0,
                                "returned (E / E_orig = 1.2, criterion < 2)")


def gaits(out: Path) -> Path:
    from bptsb_ros.body.shapes import build_shape

    rng = _rng()
    topo = build_shape("caterpillar", 10)
    rest, springs = np.asarray(topo.positions), np.asarray(topo.springs)
    steps = np.arange(0, 101)[:, None, None]
    gaits_, results = {}, {}
    for seed in range(6 if SMALL else 20):
        v = 0.5 + 0.5 * rng.random()
        wave = 0.3 * np.sin(0.2 * steps + rest[None, :, :1])
        r = rest[None] + np.concatenate([v * steps * 0.02 + wave, np.abs(wave)], axis=2)
        gaits_[seed] = None if seed == (4 if SMALL else 13) else {"r": r, "springs": springs, "dt": 0.02}
        results[seed] = {"open_speed": v, "ratio": 0.5 + rng.random(), "success": bool(seed % 3)}
    return L.plot_gaits(out / "gaits.png", gaits_, results, 2.0)


def closed_open_ratios(out: Path) -> Path:
    rng = _rng()
    seeds = list(range(20))
    results = {s: {"ratio": rng.uniform(0, 1.2), "handover_ratio": rng.uniform(0, 1.2),
                   "velocity_fl_ratio": rng.uniform(0, 1.2)} for s in seeds}
    return L.plot_closed_open_ratios(out / "closed_open_ratio.png", seeds, results,
                                     (("ratio", "FL on spring lengths (paper)"), ("handover_ratio", "1 s SWG→FL"),
                                      ("velocity_fl_ratio", "FL on velocities")), 0.7)


def headwind_speed(out: Path) -> Path:
    rng = _rng()
    on = (np.arange(3000) // 500) % 2 == 1
    tr = {"t": np.arange(1, 31, 1.0), "t0": 0.0, "on": on, "dt": DT}
    traces = {"switching": {**tr, "v": 0.2 + 0.03 * rng.standard_normal(30)},
              "forward": {**tr, "v": 0.3 + 0.1 * rng.standard_normal(30)}}
    return L.plot_headwind_speed(out / "headwind_speed.png", traces, 0.2, -1.0, 10.0)


def speed_vs_wind(out: Path) -> Path:
    winds = np.round(np.arange(-2.0, 1.0 + 1e-9, 0.05), 2)
    return L.plot_speed_vs_wind(out / "speed_vs_wind.png", winds, {"switching": 0.2 + 0.05 * winds,
                                                                   "forward": 0.3 + 0.15 * winds}, 0.2, (0.0, -1.0))


def return_rate(out: Path) -> Path:
    rng = _rng()
    sigmas = np.arange(0, 1.01, 0.1)
    rates = {"open": [np.linspace(1, 0.6, 11) - 0.1 * rng.random(11) for _ in range(3)],
             "closed": [np.linspace(1, 0.2, 11) - 0.1 * rng.random(11) for _ in range(3)]}
    mean = {k: np.mean(v, 0) for k, v in rates.items()}
    n_noise = 4
    x_before = np.cumsum(np.full(500, 0.3 * DT))
    x_after = x_before[-1] + np.cumsum(np.full((500, len(sigmas) * n_noise), 0.25 * DT), axis=0)
    example = {loop: {"x_before": x_before, "x_after": x_after, "success": np.ones((len(sigmas), n_noise), bool)}
               for loop in ("open", "closed")}
    return L.plot_return_rate(out / "return_rate.png", sigmas, rates, mean, example, 7, 5.0, DT)


def bars_over_seeds(out: Path) -> Path:
    """Five readouts over four seeds (one seed without the last system), the paper's values and a bound; beside
    them sixteen masses in two groups with a bound of ½."""
    rng = _rng()
    acc = 95 + rng.normal(0, 0.8, (4, 5))
    acc[2, 4] = np.nan
    names = ["only brain", "double-circle (N_mov 17)", "double-circle (N_mov 65)", "multiple-circle (N_mov 17)",
             "multiple-circle (N_mov 65)"]
    sizes = rng.uniform(0.4, 1.0, (4, 16))
    return S.plot_bars_over_seeds(out / "bars_over_seeds.png", [
        S.Bars(names, acc, "test accuracy [%]", paper=[91.18, 95.69, 96.77, 95.36, 96.22], bars=False,
               hline=(95.0, "95 %: a bound")),
        S.Bars([str(m) for m in range(20, 36)], sizes, "label-map size [-]", hline=(0.5, "½"),
               groups=["not joined"] * 12 + ["joined"] * 4, xlabel="placed mass [index]")],
        "Planted numbers over 4 seeds")


def seed_summary(out: Path) -> Path:
    per_seed = [{"experiment": "planted", "claims": [
        {"claim": "the first claim", "holds": h, "evidence": "planted"},
        {"claim": "a second claim with a longer text that the strip shortens", "holds": g, "evidence": "planted"}]}
        for h, g in ((True, None), (True, False), (False, True))]
    from bptsb_ros.experiments.seeds import aggregate_claims

    return S.plot_seed_summary(out / "seeds.png", aggregate_claims(per_seed), [0, 1, 2], "planted")


def band(out: Path) -> Path:
    rng = _rng()
    digits = np.arange(10)
    brain, body = rng.uniform(0, 0.5, (3, 10)), rng.uniform(0.3, 0.8, (3, 10))
    return S.plot_band(out / "band.png", digits, {"brain": brain, "body": body}, xlabel="digit [-]",
                       ylabel="silhouette [-]", title="Planted curves over 3 seeds", hline=0.0, highlight=(5, 7, 8),
                       highlight_label="digits 5, 7, 8")


def band_panels(out: Path) -> Path:
    rng = _rng()
    sigmas = np.arange(0, 1.01, 0.1)
    curves = {"SWG (open loop)": 1 - sigmas * rng.uniform(0.3, 0.6, (4, 1)),
              "FL (closed loop)": 1 - sigmas * rng.uniform(0.4, 0.9, (4, 1))}
    return S.plot_band_panels(out / "band_panels.png", {"paper": {"x": sigmas, "curves": curves},
                                                        "authors": {"x": sigmas, "curves": curves,
                                                                    "spans": [(0.3, 0.5, "a region")]}},
                              xlabel="perturbation σ [m]", ylabel="return rate [-]", title="planted", hline=0.5,
                              ylim=(-0.03, 1.03))


def share_panels(out: Path) -> Path:
    rng = _rng()
    n = np.arange(100)
    shares = {"fixed": rng.random((5, 100)) < np.where((n >= 22) & (n <= 69), 0.2, 0.9), "random": np.ones((5, 100))}
    return S.plot_share_panels(out / "share_panels.png", {"paper wind": {"x": n, "shares": shares,
                                                                         "spans": [(21.5, 69.5, "paper: fails")]}},
                               xlabel="switch phase n [1/100 period]", ylabel="seeds converging [share]",
                               title="planted")


def period_map(out: Path) -> Path:
    rng = _rng()
    winds = np.round(np.arange(-1.0, 2.0001, 0.05), 10)
    per = np.where(winds < 0.2, 1, rng.choice([0, 1, 2, -1], (4, len(winds))))
    return S.plot_period_map(out / "period_map.png", winds, {"paper wind": ([0, 1, 2, 3], per),
                                                             "published wind": ([0, 1, 2, 3], per[::-1])},
                             xlabel="F_wind [N]", title="planted", spans=[(-1.0, 0.2, "stable"), (0.2, 0.6, "chaotic")])


def count_histogram(out: Path) -> Path:
    return S.plot_count_histogram(out / "counts.png", [4, 1, 3, 8, 4, 2], total=20, paper=8,
                                  xlabel="agents whose closed loop succeeded [agents]", title="planted")


CASES: dict[str, Callable[[Path], Path]] = {f.__name__: f for f in (
    loss, lissajous, speed, series, spring_lengths, ipc_bars, ipc_panels, memory_error, narma_emulation, targets,
    best_drawings, error_bars, pca, label_maps, label_map_sizes, curves, live_drawings, perturbation,
    switching_curves, switching_dynamics, bifurcation, timing, scheme_ratios, perturbed_run, gaits,
    closed_open_ratios, headwind_speed, speed_vs_wind, return_rate, bars_over_seeds, seed_summary, band, band_panels,
    share_panels, period_map, count_histogram)}


if __name__ == "__main__":
    out_dir = Path(sys.argv[1])
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, case in CASES.items():
        print(name, case(out_dir))
