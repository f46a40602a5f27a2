"""Task targets and metrics against values typed from the paper's equations (worked by hand, not by the
code under test): the expanded NARMA recursion, the Lissajous figure-eight, the shift-minimised
closed-loop error and the locomotion speed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT

from bptsb_ros.tasks.lissajous import lissajous_target, target_from_config, windowed_shift_error
from bptsb_ros.tasks.locomotion import mean_speed
from bptsb_ros.tasks.narma import expanded_narma, nmse

CONFIG = REPO_ROOT / "config"


def test_expanded_narma_first_values_by_hand() -> None:
    """y(t+1) = 0.3 y(t) + Σ_{i<m} (u(t−i)³ − u(t−i)⁴) + 0.2 Σ_{i<m} (y(t−i)³ − y(t−i)⁴) + 0.1 (paper, Eq. of the
    time-series task), y(0) = 0, everything before t = 0 zero; u = 0.5, 0.2, 0.9, 0.4."""
    u = np.array([0.5, 0.2, 0.9, 0.4])
    # y1 = 0.3·0 + (0.125 − 0.0625) + 0.2·0 + 0.1                                  = 0.1625
    # y2 = 0.3·0.1625 + (0.008 − 0.0016) + 0.0625 + 0.2·(0.1625³ − 0.1625⁴) + 0.1  = 0.2183687451171875
    #      (0.1625³ = 0.004291015625, 0.1625⁴ = 0.000697290039...)
    # y3 (m = 2) = 0.3·y2 + (0.729 − 0.6561) + 0.0064 + 0.2·((y2³ − y2⁴) + (y1³ − y1⁴)) + 0.1 = 0.247157177287...
    narma2 = [0.1625, 0.2183687451171875, 0.24715717728711142, 0.2893482473630896]
    np.testing.assert_allclose(expanded_narma(u, 2), narma2, rtol=1e-13)
    np.testing.assert_allclose(expanded_narma(u), narma2, rtol=1e-13)  # the paper's m = 2 is the default
    # m = 10: while t < m every earlier term is in the sums; y1, y2 agree with m = 2 (the extra terms are 0),
    # y3 adds u(0)³ − u(0)⁴ = 0.0625 (and y(0) terms, which are 0)
    narma10 = [0.1625, 0.2183687451171875, 0.24715717728711142 + 0.0625, 0.3795432765143839]
    np.testing.assert_allclose(expanded_narma(u, 10), narma10, rtol=1e-13)


def test_nmse_of_planted_errors() -> None:
    target = np.array([0.0, 1.0, 0.0, 1.0])  # variance 0.25
    assert nmse(target + 0.1, target) == pytest.approx(0.01 / 0.25)
    assert nmse(np.full(4, 0.5), target) == pytest.approx(1.0)  # predicting the mean


def test_lissajous_target_at_quarter_periods() -> None:
    """x = X cos(αωt), y = Y sin(βωt + δ), (α, β, δ) = (1, 2, 0), X = Y = size/20 = 0.2 m, ω = 2π: a figure-eight."""
    t = torch.tensor([0.0, 0.125, 0.25, 0.5, 0.75], dtype=torch.float64)
    s = math.sqrt(0.5) * 0.2
    # x: cos(0), cos(π/4), cos(π/2), cos(π), cos(3π/2); y: sin(0), sin(π/2), sin(π), sin(2π), sin(3π)
    expected = [[0.2, 0.0], [s, 0.2], [0.0, 0.0], [-0.2, 0.0], [0.0, 0.0]]
    got = lissajous_target(t, 0.2, 0.2, 1, 2, 0, 2 * math.pi).numpy()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)
    # the shipped config gives this target and a 100-step period
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import load_config

    target, period = target_from_config(build_agent(load_config(CONFIG / "lissajous_single.yaml")).config)
    assert period == 100
    np.testing.assert_allclose(target(t.numpy()), expected, rtol=0, atol=1e-15)
    # δ shifts y only: δ = π/2 gives y = Y cos(2ωt)
    np.testing.assert_allclose(lissajous_target(t, 0.2, 0.2, 1, 2, math.pi / 2, 2 * math.pi).numpy()[:, 1],
                               [0.2, 0.0, -0.2, 0.2, -0.2], atol=1e-15)


def test_windowed_shift_error_of_a_delayed_offset_figure() -> None:
    """A CMP that runs 30 steps behind the target and 0.01 m off in x and y: the best shift (70 = 100 − 30)
    removes the delay exactly, leaving mean((0.01)², (0.01)²) = 1e-4 m² in every period."""
    period, dt = 100, 0.01

    def target(t):
        return np.stack([0.2 * np.cos(2 * np.pi * t), 0.2 * np.sin(4 * np.pi * t)], -1)

    t = 0.37 + dt * np.arange(5 * period + 1)
    traj = target(t - 30 * dt) + 0.01
    assert windowed_shift_error(traj, target, 0.37, dt, period) == pytest.approx(1e-4, rel=1e-9)
    with pytest.raises(ValueError, match="more than one period"):
        windowed_shift_error(traj[:period], target, 0.37, dt, period)


def test_mean_speed_of_a_planted_walk() -> None:
    t = np.arange(501) * 0.01
    x = 0.3 * t[:, None] + np.array([0.0, 0.1, 0.2]) + 0.05 * np.sin(2 * np.pi * t)[:, None]  # 0.3 m/s + a wobble
    assert mean_speed(x, 5.0) == pytest.approx(0.3, abs=1e-12)
