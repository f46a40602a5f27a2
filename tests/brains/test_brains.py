"""The brains above the body against values computed independently of them: the SWG formula at chosen
t, A, φ (hand-computed), the feedback law l·(1 + W·[s, 1]) (hand-computed, and a closed loop re-simulated
by plain NumPy from the fitted W), ridge regression on planted data, and the noise and targets the
feedback fit regresses on."""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch
from conftest import REPO_ROOT
from reintegrate import load_keys, reintegrate, spring_lengths

from bptsb_ros.brains import FeedbackLayer, SineWaveGenerator, fit_ridge

CONFIG = REPO_ROOT / "config"
R3 = math.sqrt(3) / 2  # sin(π/3) = sin(2π/3)


def test_swg_signal_and_rest_length_at_chosen_times() -> None:
    swg = SineWaveGenerator(3, dtype=torch.float64)  # ω defaults to 2π rad/s (paper, Methods)
    with torch.no_grad():
        swg.amplitude.copy_(torch.tensor([0.5, 0.4, 0.2], dtype=torch.float64))
        swg.phase.copy_(torch.tensor([0.0, math.pi / 6, math.pi / 2], dtype=torch.float64))
    t = torch.tensor([0.0, 1 / 12, 0.25], dtype=torch.float64)  # ωt = 0, π/6, π/2
    # A·sin(ωt + φ), by hand: angles (0, π/6, π/2), (π/6, π/3, 2π/3), (π/2, 2π/3, π)
    expected = np.array([[0.0, 0.4 * 0.5, 0.2 * 1.0],
                         [0.5 * 0.5, 0.4 * R3, 0.2 * R3],
                         [0.5 * 1.0, 0.4 * R3, 0.0]])
    np.testing.assert_allclose(swg.signal(t).detach().numpy(), expected, rtol=0, atol=1e-15)
    base = torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64)
    np.testing.assert_allclose(swg.rest_length(base, t).detach().numpy(),
                               [[1.0, 2.4, 0.6], [1.25, 2 * (1 + 0.4 * R3), 0.5 * (1 + 0.2 * R3)],
                                [1.5, 2 * (1 + 0.4 * R3), 0.5]], rtol=0, atol=1e-15)
    # undriven springs keep their rest length
    masked = SineWaveGenerator(3, driven=torch.tensor([True, False, True]), dtype=torch.float64)
    with torch.no_grad():
        masked.amplitude.copy_(swg.amplitude)
        masked.phase.copy_(swg.phase)
    np.testing.assert_allclose(masked.signal(t).detach().numpy(), expected * [1, 0, 1], rtol=0, atol=1e-15)


def test_swg_initialisation_follows_the_paper() -> None:
    swg = SineWaveGenerator(400, amplitude=0.4, generator=torch.Generator().manual_seed(1))
    assert swg.omega == 2 * math.pi
    assert torch.all(swg.amplitude == 0.4)
    phase = swg.phase.detach().numpy()
    assert phase.min() >= 0 and phase.max() < 2 * math.pi and np.ptp(phase) > 6.0  # φ ~ U(0, 2π)


def test_feedback_rest_length_is_base_times_one_plus_w_s() -> None:
    fl = FeedbackLayer(2, 3, driven=torch.tensor([True, True, False]), dtype=torch.float64)
    fl.load_fit(np.array([[0.1, -0.2, 0.05], [0.3, 0.0, -0.1], [1.0, 1.0, 1.0]]))
    features = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    base = torch.tensor([2.0, 1.0, 0.7], dtype=torch.float64)
    # W·[s, 1] = 0.1 − 0.4 + 0.05 = −0.25 and 0.3 + 0 − 0.1 = 0.2; the undriven third spring gets 0
    np.testing.assert_allclose(fl.signal_from_features(features).detach().numpy(), [[-0.25, 0.2, 0.0]], atol=1e-15)
    np.testing.assert_allclose(fl.rest_length_from_features(base, features).detach().numpy(),
                               [[1.5, 1.2, 0.7]], atol=1e-15)


def test_ridge_recovers_a_planted_map_and_bias() -> None:
    rng = np.random.default_rng(0)
    n = 400
    x = 5.0 + rng.standard_normal((n, 3)) * [1.0, 0.5, 2.0]  # far from zero mean: the bias must undo it
    w_true = np.array([[0.7, -1.2, 0.3], [0.0, 2.0, -0.5]])
    b_true = np.array([0.25, -1.5])
    y = x @ w_true.T + b_true + 1e-3 * rng.standard_normal((n, 2))
    weights, lambdas = fit_ridge(x, y)
    assert weights.shape == (2, 4) and lambdas.shape == (2,)
    np.testing.assert_allclose(weights[:, :3], w_true, atol=2e-3)
    np.testing.assert_allclose(weights[:, 3], b_true, atol=2e-2)
    fitted = np.concatenate([x, np.ones((n, 1))], 1) @ weights.T
    assert np.sqrt(np.mean((fitted - y) ** 2)) < 1.5e-3  # the residual is the planted noise
    # nearly noiseless data: AIC picks a small ridge; pure noise targets: the largest (shrink to the mean)
    assert lambdas.max() <= 1e-2
    _, noise_lambda = fit_ridge(x, rng.standard_normal((n, 1)))
    assert noise_lambda[0] == 1e4


def _lissajous_agent(*overrides: str):
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import load_config

    cfg = load_config(CONFIG / "lissajous_single.yaml", ["dtype=float64", *overrides])
    return cfg, build_agent(cfg)


def test_feedback_fit_regresses_the_next_swg_signal_on_noisy_spring_lengths(monkeypatch) -> None:
    """What fit_feedback hands to the ridge regression: the body state at step k with N(0, σ²) noise (σ from
    the config), against A·sin(ω t_{k+1} + φ) computed here, on the middle 60 % of the run."""
    import bptsb_ros.training.feedback_fit as ff
    from bptsb_ros.sim.rollout import simulate_open_loop

    cfg, agent = _lissajous_agent("feedback.fit_time=10")
    seen = {}

    def spy(x, y, **kw):
        seen["x"], seen["y"] = x.copy(), y.copy()
        return fit_ridge(x, y, **kw)

    monkeypatch.setattr(ff, "fit_ridge", spy)
    info = ff.fit_feedback(agent, cfg.feedback, None, seed=5)
    steps, lo, hi = 1000, 200, 800  # fit_time 10 s at dt 0.01 s; the middle 60 %
    clean = simulate_open_loop(agent, steps).length[:-1, 0].numpy()[lo:hi]  # (600, 48) spring lengths at step k
    noise = seen["x"] - clean
    assert cfg.feedback.noise == 0.08 and noise.shape == (600, 48)
    assert abs(noise.mean()) < 3e-3 and abs(noise.std() / 0.08 - 1) < 0.03  # 28,800 draws: ±1 % is 2σ
    amp, phase = agent.brain.amplitude.detach().numpy(), agent.brain.phase.detach().numpy()
    t_next = np.arange(lo + 1, hi + 1)[:, None] * 0.01
    np.testing.assert_allclose(seen["y"], amp * np.sin(2 * np.pi * t_next + phase), rtol=0, atol=1e-12)
    assert info["fit_steps"] == 600 and info["fit_rmse_clean_inputs"] < 0.5 * info["signal_rms"]


def test_closed_loop_equals_numpy_resimulation_from_the_fitted_w(tmp_path) -> None:
    """``bptsb simulate --loop closed`` of an agent with a fitted feedback layer, re-integrated by plain NumPy
    whose rest lengths come from the checkpoint's W and l and its own spring lengths: l·(1 + W·[s_k, 1])."""
    from bptsb_ros.cli import simulate_cmd
    from bptsb_ros.training.checkpoint import load_agent, save_checkpoint
    from bptsb_ros.training.feedback_fit import fit_feedback

    cfg, agent = _lissajous_agent("feedback.fit_time=10")
    fit_feedback(agent, cfg.feedback, None, seed=0)
    run_dir = tmp_path / "agent"
    save_checkpoint(run_dir, agent, extra={"feedback_fitted": True})
    out = tmp_path / "closed.npz"
    parser = argparse.ArgumentParser()
    simulate_cmd.add_arguments(parser)
    argv = ["--agent", str(run_dir), "--steps", "300", "--loop", "closed", "--perturb", "0.05", "--dtype", "float64",
            "--out", str(out)]
    assert simulate_cmd.run(parser.parse_args(argv)) == 0
    keys = load_keys(out)
    saved = load_agent(run_dir, dtype=torch.float64)
    w = saved.feedback.weight.numpy()  # (E, E + 1), bias last
    base = saved.body.l.numpy()
    assert np.abs(w[:, :-1]).max() > 0.1, "a fitted, non-trivial feedback map"

    def rest_law(r: np.ndarray) -> np.ndarray:
        return base * (1 + w[:, :-1] @ spring_lengths(keys, r) + w[:, -1])

    positions, velocities = reintegrate(keys, rest_law)
    assert np.abs(positions - keys["positions"]).max() < 1e-8  # measured ≈ 1e-15
    assert np.abs(velocities - keys["velocities"]).max() < 1e-8
    # the feedback really drives the body: the modulation is large and differs from the fixed rest lengths
    assert np.ptp(keys["rest_length"][1:], axis=0).max() > 0.05 * base.max()


def test_numpy_resimulation_tells_the_feedback_sign(tmp_path) -> None:
    """The re-simulation above can fail: the opposite feedback sign gives another trajectory."""
    from bptsb_ros.sim.rollout import simulate_closed_loop
    from bptsb_ros.sim.trajectory import trajectory_from_rollout
    from bptsb_ros.training.feedback_fit import fit_feedback

    cfg, agent = _lissajous_agent("feedback.fit_time=10")
    fit_feedback(agent, cfg.feedback, None, seed=0)
    traj = trajectory_from_rollout(agent.body, simulate_closed_loop(agent.body, agent.feedback, 100))
    path = traj.save_npz(tmp_path / "c.npz")
    keys = load_keys(path)
    w, base = agent.feedback.weight.detach().numpy(), agent.body.l.detach().numpy()
    positions, _ = reintegrate(keys, lambda r: base * (1 - (w[:, :-1] @ spring_lengths(keys, r) + w[:, -1])))
    assert np.abs(positions - keys["positions"]).max() > 1e-3
