"""The SWG clock at a large step (k ≥ 3.2·10⁶, t = 32,000 s at Δt = 0.01 s) against closed forms computed here
in exact rational arithmetic: the SWG module, the offline open loop and training windows
(``swg_rest_lengths``, ``simulate_open_loop``), the batched population run, the SWG → feedback handover, the
live ``swg_brain`` node's clock callback, and the Lissajous training target. A float32 clock (t = k·Δt and
ω·t in float32, as before) is shown to miss each tolerance by orders of magnitude."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT

from bptsb_ros.body.clock import clock_phase, step_times, steps_per_period
from bptsb_ros.brains import SineWaveGenerator

CONFIG = REPO_ROOT / "config"
K0 = 3_200_000  # t = 32,000 s
DT = 0.01
#: |error| allowed on A·sin(ωt + φ) (A ≤ 0.5): a few roundings of the result in the model dtype
ATOL = {torch.float32: 1e-6, torch.float64: 1e-14}


def _pi() -> Fraction:
    """π to ~10⁻⁴⁵ by Machin's formula π = 16 atan(1/5) − 4 atan(1/239), in exact fractions."""
    def atan_inv(n: int, terms: int) -> Fraction:
        return sum((Fraction((-1) ** j, (2 * j + 1) * n ** (2 * j + 1)) for j in range(terms)), Fraction(0))
    return 16 * atan_inv(5, 35) - 4 * atan_inv(239, 12)


PI = _pi()


def exact_phase(steps: np.ndarray, omega_over_2pi: Fraction | None = None, omega: Fraction | None = None) -> np.ndarray:
    """ω·k·Δt mod 2π [rad] with Δt = 1/100 s exactly: from the frequency f = ω/2π (cycles k·f·Δt mod 1) or, for
    an ω incommensurate with 2π, from ω itself (ω·k·Δt − 2π·⌊ω·k·Δt / 2π⌋ with the Machin π)."""
    dt = Fraction(1, 100)
    out = []
    for k in steps.tolist():
        if omega_over_2pi is not None:
            out.append(2 * math.pi * float((k * omega_over_2pi * dt) % 1))
        else:
            x = k * omega * dt
            out.append(float(x - 2 * PI * math.floor(x / (2 * PI))))
    return np.array(out)


def float32_signal(steps: np.ndarray, omega: float, amplitude: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """The float32 clock: t = k·Δt and ω·t + φ in float32 (what a float32 model computed before)."""
    t = steps.astype(np.float32) * np.float32(DT)
    return (amplitude.astype(np.float32) * np.sin(np.float32(omega) * t[:, None] + phase.astype(np.float32))
            ).astype(np.float64)


def _swg(n: int, dtype: torch.dtype, omega: float = 2 * math.pi) -> SineWaveGenerator:
    swg = SineWaveGenerator(n, omega=omega, generator=torch.Generator().manual_seed(3), dtype=dtype)
    with torch.no_grad():
        swg.amplitude.copy_(torch.linspace(0.1, 0.5, n, dtype=dtype))
    return swg


def _params(swg: SineWaveGenerator) -> tuple[np.ndarray, np.ndarray]:
    return swg.amplitude.detach().double().numpy(), swg.phase.detach().double().numpy()


def test_float32_clock_misses_the_tolerance_at_the_large_step() -> None:
    """The tolerance is tight enough: the float32 clock is off by > 10³ × ATOL at 32,000 s (about 2 % of A)."""
    steps = np.arange(K0, K0 + 200)
    a, phi = np.full(4, 0.5), np.array([0.0, 1.0, 2.0, 4.0])
    exact = a * np.sin(exact_phase(steps, Fraction(1))[:, None] + phi)
    err = np.abs(float32_signal(steps, 2 * math.pi, a, phi) - exact).max()
    assert err > 1e3 * ATOL[torch.float32]
    assert err > 0.01 * 0.5  # over 1 % of the amplitude


def test_steps_per_period_is_an_integer_only_within_its_tolerance() -> None:
    assert steps_per_period(2 * math.pi, 0.01) == 100  # the paper's ω = 2π rad/s at Δt = 0.01 s
    assert steps_per_period(2 * math.pi, 0.005) == 200
    assert steps_per_period(5.0, 0.01) is None  # 125.66... steps
    assert steps_per_period(2 * math.pi / (1 + 5e-13), 0.01) == 100  # within 10⁻¹² of 100 steps: accepted
    assert steps_per_period(2 * math.pi / (1 + 3e-12), 0.01) is None  # just past: not an integer period
    for omega, dt in ((0.0, 0.01), (2 * math.pi, 0.0), (math.nan, 0.01), (2 * math.pi, math.inf)):
        with pytest.raises(ValueError, match="ω > 0 and Δt > 0"):
            steps_per_period(omega, dt)
    with pytest.raises(TypeError, match="integers"):
        clock_phase(torch.tensor([1.0]), 0.01, 2 * math.pi)


def test_clock_phase_is_exact_and_periodic_at_the_large_step() -> None:
    steps = np.array([0, 1, 99, 100, K0, K0 + 37, 10_000_000 + 99, 2**40 + 3])
    np.testing.assert_allclose(clock_phase(torch.from_numpy(steps), DT, 2 * math.pi).numpy(),
                               exact_phase(steps, Fraction(1)), rtol=0, atol=1e-15)
    # bit-periodic: step K0 + j has the phase of step j (K0 is a multiple of the 100-step period)
    j = torch.arange(250)
    assert torch.equal(clock_phase(K0 + j, DT, 2 * math.pi), clock_phase(j, DT, 2 * math.pi))
    # an incommensurate ω = 5 rad/s: float64-accurate (the bound in bptsb_ros.body.clock)
    steps = np.array([1, K0, K0 + 1, 10_000_000])
    got = clock_phase(torch.from_numpy(steps), DT, 5.0).numpy()
    np.testing.assert_allclose(got, exact_phase(steps, omega=Fraction(5)), rtol=0, atol=1e-9)
    times = step_times(K0, 3, DT)
    assert times.dtype == torch.float64
    np.testing.assert_allclose(times.numpy(), [32_000.0, 32_000.01, 32_000.02], rtol=1e-15, atol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("omega, freq", [(2 * math.pi, Fraction(1)), (5.0, None)])
def test_swg_module_at_the_large_step(dtype: torch.dtype, omega: float, freq: Fraction | None) -> None:
    swg = _swg(6, dtype, omega)
    a, phi = _params(swg)
    steps = np.arange(K0, K0 + 150)
    theta = exact_phase(steps, freq) if freq is not None else exact_phase(steps, omega=Fraction(5))
    expected = a * np.sin(theta[:, None] + phi)
    atol = ATOL[dtype] if freq is not None else max(ATOL[dtype], 1e-9)  # incommensurate: float64-accurate
    got = swg.signal_at_steps(torch.from_numpy(steps), DT)
    assert got.dtype == dtype
    np.testing.assert_allclose(got.detach().double().numpy(), expected, rtol=0, atol=atol)
    if dtype == torch.float32:
        assert np.abs(float32_signal(steps, omega, a, phi) - expected).max() > 1e3 * atol
    base = torch.linspace(0.5, 1.5, 6, dtype=dtype)
    np.testing.assert_allclose(swg.rest_length_at_steps(base, steps.tolist(), DT).detach().double().numpy(),
                               base.double().numpy() * (1 + expected), rtol=0, atol=2 * atol)


def test_swg_gradients_at_the_large_step() -> None:
    """d/dA A·sin(θ + φ) = sin(θ + φ), d/dφ = A·cos(θ + φ), θ exact (float64 model, closed form)."""
    swg = _swg(4, torch.float64)
    a, phi = _params(swg)
    steps = np.arange(K0, K0 + 30)
    theta = exact_phase(steps, Fraction(1))[:, None] + phi
    w = np.linspace(-1.0, 2.0, 30)[:, None]  # a weighted sum, so that every step counts differently
    (swg.signal_at_steps(torch.from_numpy(steps), DT) * torch.from_numpy(w)).sum().backward()
    np.testing.assert_allclose(swg.amplitude.grad.numpy(), (w * np.sin(theta)).sum(0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(swg.phase.grad.numpy(), (w * a * np.cos(theta)).sum(0), rtol=0, atol=1e-12)
    # float32: the same gradients to float32 accuracy, in float32
    swg32 = _swg(4, torch.float32)
    a32, phi32 = _params(swg32)
    theta32 = exact_phase(steps, Fraction(1))[:, None] + phi32
    (swg32.signal_at_steps(torch.from_numpy(steps), DT) * torch.from_numpy(w).float()).sum().backward()
    assert swg32.phase.grad.dtype == torch.float32
    np.testing.assert_allclose(swg32.phase.grad.double().numpy(), (w * a32 * np.cos(theta32)).sum(0), atol=2e-5)


@pytest.fixture(scope="module")
def agent():
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import load_config

    return build_agent(load_config(CONFIG / "lissajous_single.yaml"))  # float32, Δt = 0.01 s, ω = 2π


def _expected_rest(agent, steps: np.ndarray, scale: np.ndarray | float = 1.0) -> np.ndarray:
    a, phi = _params(agent.brain)
    driven = agent.brain.driven.numpy()
    s = a * np.sin(exact_phase(steps, Fraction(1))[:, None] + phi) * driven
    return agent.body.l.detach().double().numpy() * (1 + np.asarray(scale).reshape(-1, 1) * s)


def _float32_rest(agent, steps: np.ndarray) -> np.ndarray:
    a, phi = _params(agent.brain)
    s = float32_signal(steps, agent.brain.omega, a, phi) * agent.brain.driven.numpy()
    return agent.body.l.detach().double().numpy() * (1 + s)


REST_ATOL = 2e-6  # [m]: rest lengths ≤ ~1 m in float32


def test_offline_open_loop_and_training_windows_at_the_large_step(agent) -> None:
    from bptsb_ros.sim.rollout import simulate_open_loop, swg_rest_lengths

    body = agent.body
    steps = np.arange(K0, K0 + 5)
    expected = _expected_rest(agent, steps)
    assert np.abs(_float32_rest(agent, steps) - expected).max() > 1e2 * REST_ATOL  # the float32 clock fails
    with torch.no_grad():
        rest = swg_rest_lengths(body, agent.brain, K0, 5)
        start = body.initial_state(1, rest_length=rest[0])
    np.testing.assert_allclose(rest.double().numpy(), expected, rtol=0, atol=REST_ATOL)
    start = type(start)(start.r, start.v, start.a, start.length, K0)
    roll = simulate_open_loop(agent, 4, state=start)
    np.testing.assert_allclose(roll.rest_length[:, 0].double().numpy(), expected, rtol=0, atol=REST_ATOL)


def test_population_run_at_the_large_step(agent, monkeypatch) -> None:
    from bptsb_ros.sim.batched import run_population

    body = agent.body
    seen: list[torch.Tensor] = []
    step = body.step

    def spy(state, rest, *args, **kwargs):
        seen.append(rest.detach().clone())
        return step(state, rest, *args, **kwargs)

    with torch.no_grad():
        s0 = body.initial_state(3)
    s0 = type(s0)(s0.r, s0.v, s0.a, s0.length, K0)
    monkeypatch.setattr(body, "step", spy)
    run_population(body, 4, s0, swg=agent.brain)
    # the rest length in force at step K0 + i, i = 1..4
    np.testing.assert_allclose(torch.stack(seen).double().numpy(), _expected_rest(agent, np.arange(K0 + 1, K0 + 5)),
                               rtol=0, atol=REST_ATOL)


def test_swg_to_feedback_handover_at_the_large_step(agent) -> None:
    """(1 − α)·SWG + α·FL with the FL's weights zero: l·(1 + (1 − i/H)·A sin(ω (K0 + i) Δt + φ))."""
    from bptsb_ros.sim.rollout import simulate_closed_loop

    body, fb = agent.body, agent.feedback
    saved = fb.weight.detach().clone()
    with torch.no_grad():
        fb.weight.zero_()
        s0 = body.initial_state(1)
    try:
        s0 = type(s0)(s0.r, s0.v, s0.a, s0.length, K0)
        roll = simulate_closed_loop(body, fb, 3, state=s0, handover=agent.brain, handover_steps=4)
    finally:
        with torch.no_grad():
            fb.weight.copy_(saved)
    expected = _expected_rest(agent, np.arange(K0 + 1, K0 + 4), scale=np.array([0.75, 0.5, 0.25]))
    np.testing.assert_allclose(roll.rest_length[1:, 0].double().numpy(), expected, rtol=0, atol=REST_ATOL)


def test_lissajous_training_target_at_the_large_step(agent) -> None:
    """The target the Lissajous task trains on at window times K0+1.. : x = X cos(2πk/100), y = Y sin(4πk/100)."""
    from bptsb_ros.config import load_config
    from bptsb_ros.tasks.lissajous import LissajousTask

    task = LissajousTask(agent, load_config(CONFIG / "lissajous_single.yaml"))
    steps = np.arange(K0 + 1, K0 + 1 + task.window)
    theta = exact_phase(steps, Fraction(1))
    amp = 0.2  # size/20 of the 4 m double circle (test_tasks)
    expected = np.stack([amp * np.cos(theta), amp * np.sin(2 * theta)], -1)
    got = task.target(task.window_times(K0)).double().numpy()
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    t32 = steps.astype(np.float32) * np.float32(DT)  # a float32 window time misses it
    w32 = np.float32(2 * math.pi) * t32
    assert np.abs(np.stack([amp * np.cos(w32), amp * np.sin(2 * w32)], -1) - expected).max() > 1e-4


LIVE = """
import json, sys
import rclpy
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.runtime import StopFlag
from bptsb_ros.ros.swg_brain import SwgBrain

results = {}
for dtype in ("float32", "float64"):
    # message objects, not the pre-serialized bytes (whose equality with these is tests/live/test_live_speed.py's)
    # nothing publishes /clock here: the node waits startup_timeout for one before it makes its output
    rclpy.init(args=["--ros-args", "-p", "task:=lissajous", "-p", "min_subscribers:=0", "-p", f"dtype:={dtype}",
                     "-p", "raw_outputs:=false", "-p", "startup_timeout:=0.2"])
    node = SwgBrain(StopFlag())
    sent = []
    node.publish_timed = lambda pub, msg, started: sent.append(msg)
    brain = node.agent.brain
    out = {"amplitude": brain.amplitude.tolist(), "phase": brain.phase.tolist(), "driven": brain.driven.tolist(),
           "base": node.agent.body.l.tolist(), "dtype": str(node.agent.body.l.dtype), "rest": [], "stamp": []}
    for k in map(int, sys.argv[1:]):
        node._on_clock(serialize_message(Clock(clock=m.stamp(k, node.dt_ns))))  # the node takes /clock raw
        out["rest"].append(list(sent[-1].position))
        out["stamp"].append(m.step_of(sent[-1].header.stamp, node.dt_ns))
    node.destroy_node()
    rclpy.shutdown()
    results[dtype] = out
print(json.dumps(results))
"""


@pytest.mark.slow
def test_live_swg_brain_clock_callback_at_the_large_step(ros_env) -> None:
    """The live node answers /clock at step k with l·(1 + A sin(ω k Δt + φ)), in float32 and in float64 (its
    default); run in a process of its own (its own rclpy context and arguments)."""
    steps = [K0, K0 + 1, K0 + 57]
    proc = subprocess.run([sys.executable, "-c", LIVE, *map(str, steps)], capture_output=True, text=True,
                          env=ros_env, cwd=REPO_ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    k = np.array(steps)
    for dtype, atol in (("float32", REST_ATOL), ("float64", 1e-13)):
        out = runs[dtype]
        assert out["dtype"] == f"torch.{dtype}" and out["stamp"] == steps
        a, phi, driven, base = (np.array(out[key], dtype=np.float64) for key in ("amplitude", "phase", "driven",
                                                                                 "base"))
        expected = base * (1 + a * np.sin(exact_phase(k, Fraction(1))[:, None] + phi) * driven)
        np.testing.assert_allclose(np.array(out["rest"]), expected, rtol=0, atol=atol)
        if dtype == "float32":
            old = base * (1 + float32_signal(k, 2 * math.pi, a, phi) * driven)
            assert np.abs(old - expected).max() > 1e2 * atol
