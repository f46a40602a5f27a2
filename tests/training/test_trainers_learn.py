"""Every training loop is shown to train what it says (the trainer of ``bptsb train``: Lissajous, locomotion,
NARMA and memory).

For each trainer, on a tiny planted episode in float64:

(a) the loss it reports equals a loss computed here in a few independent lines: the body stepped with plain
    autograd (``MSDN.step``; the trainers use the window kernel and its hand-derived adjoint), the SWG signal
    A·sin(ωt + φ), the targets and their times written out by hand, over exactly the documented slice (warm-up
    and washout excluded);
(b) one update moves every trained parameter by −η·∂L/∂θ (SGD; η the paper's or the authors' rate, written here
    as a number from the paper's table or published-code-facts.md, never read from the code), projected onto
    θ ≥ 0 for the body, and lowers that same loss.

Locomotion includes the headwind variant. The other trainers (MNIST, switching, closed-loop schemes, feedback-layer
refits) and the learning-rate tables are in ``tests/training/test_trainers_learn_more.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from trainer_episodes import CONFIG, F64, check_sgd, fresh_agent, lissajous_start, swg_run, swg_signal

from bptsb_ros.body.msdn import BodyState
from bptsb_ros.config import load_config
from bptsb_ros.workflows.train import train


def named(agent) -> dict[str, torch.nn.Parameter]:
    """The trained parameters by the paper's names: k, d, l and A, φ (SWG) or the brain's weights."""
    body, brain = agent.body, agent.brain
    out = {"k": body.k, "d": body.d, "l": body.l}
    if hasattr(brain, "amplitude"):
        out.update(amplitude=brain.amplitude, phase=brain.phase)
    else:
        out.update({f"brain.{n}": p for n, p in brain.named_parameters()})
    return out


# -- Lissajous, single curve ---------------------------------------------------------------------------------
#: the paper's table, row "Lissajous curve (single)": k 1e4, d 1e3, l 1e1, A 1e1, φ 1e2
LISSAJOUS_LR = {"k": 1e4, "d": 1e3, "l": 1e1, "amplitude": 1e1, "phase": 1e2}
W_LISS = 25


def lissajous_cfg(windows: int):
    return load_config(CONFIG / "lissajous_single.yaml", [
        "dtype=float64", f"training.update_steps={W_LISS}", f"sim_time={windows * W_LISS * 0.01}",
        "feedback.enabled=false", "lissajous.eval_periods=1"])


def lissajous_loss(agent, state: BodyState, window: int = W_LISS) -> tuple[torch.Tensor, BodyState]:
    """MSE of the CMP at steps k0+1 .. k0+W against x = 0.2 cos(2πt), y = 0.2 sin(4πt) (X = Y = size/20 = 0.2 m,
    (α, β, δ) = (1, 2, 0)), and the state after the window."""
    body = agent.body
    s, cmp = state, []
    steps = range(state.step + 1, state.step + window + 1)
    for k in steps:
        s = body.step(s, body.l * (1 + swg_signal(agent.brain, k, body.dt)))
        cmp.append(s.r[0, body.cmp_local])
    t = torch.tensor(list(steps), dtype=F64) * body.dt
    target = torch.stack([0.2 * torch.cos(2 * math.pi * t), 0.2 * torch.sin(4 * math.pi * t)], -1)
    return ((torch.stack(cmp) - target) ** 2).mean(), s


def test_lissajous_trainer_reports_the_window_loss_and_one_sgd_step_lowers_it():
    cfg = lissajous_cfg(1)
    a0 = fresh_agent(cfg)
    s0 = lissajous_start(a0)
    res = train(cfg, None, progress=False)
    with torch.no_grad():
        hand, _ = lissajous_loss(a0, s0)
        after, _ = lissajous_loss(res.agent, s0)
    assert res.losses == pytest.approx([float(hand)], rel=1e-10)
    check_sgd(a0, named, lambda a: lissajous_loss(a, s0)[0], res.agent, LISSAJOUS_LR)
    assert float(after) < 0.9 * float(hand), (float(after), float(hand))


def test_lissajous_trainer_projects_the_body_parameters_onto_non_negative_values():
    """Damping coefficients planted near 0 (d ~ U(0, 1e-3)): the SGD step takes some below 0 and the trainer sets
    those to exactly 0 (the paper: parameters never go below zero)."""
    cfg = load_config(CONFIG / "lissajous_single.yaml", [
        "dtype=float64", f"training.update_steps={W_LISS}", f"sim_time={W_LISS * 0.01}", "feedback.enabled=false",
        "lissajous.eval_periods=1", "body.d_init=[0.0, 0.001]"])
    a0 = fresh_agent(cfg)
    s0 = lissajous_start(a0)
    res = train(cfg, None, progress=False)
    check_sgd(a0, named, lambda a: lissajous_loss(a, s0)[0], res.agent, LISSAJOUS_LR)
    zero = int((res.agent.body.d == 0).sum())
    assert 0 < zero < res.agent.body.d.numel(), zero


def test_lissajous_trainer_carries_the_state_and_the_clock_to_the_next_window():
    """Window 2's loss: the trained parameters from the state window 1 ended in, at steps W+1 .. 2W."""
    one = train(lissajous_cfg(1), None, progress=False)
    two = train(lissajous_cfg(2), None, progress=False)
    a0 = fresh_agent(lissajous_cfg(2))
    with torch.no_grad():
        _, s1 = lissajous_loss(a0, lissajous_start(a0))
        hand, _ = lissajous_loss(one.agent, s1.detach())
    assert s1.step == W_LISS
    assert two.losses[1] == pytest.approx(float(hand), rel=1e-10)


# -- locomotion ----------------------------------------------------------------------------------------------
#: the paper's table, row "Locomotion (forward motion)": k 1e2, d 1e0, l 1e-1, A 1e-3, φ 1e-2
LOCOMOTION_LR = {"k": 1e2, "d": 1e0, "l": 1e-1, "amplitude": 1e-3, "phase": 1e-2}
W_LOC, BLOCK, WARMUP = 40, 20, 2


def locomotion_cfg(windows: int):
    return load_config(CONFIG / "locomotion_forward.yaml", [
        "dtype=float64", f"training.update_steps={W_LOC}", f"locomotion.speed_block={BLOCK}",
        f"locomotion.warmup_windows={WARMUP}", f"sim_time={windows * W_LOC * 0.01}", "feedback.enabled=false",
        "locomotion.eval_time=0.4"])


def locomotion_loss(agent, state: BodyState, train_start: int) -> torch.Tensor:
    """The forward speed (x-velocity after each step, mean over the 10 masses) averaged over blocks of BLOCK steps,
    against v = 0.004·t, t the simulated seconds since training began (the warm-up excluded), MSE."""
    states, _ = swg_run(agent, state, W_LOC)
    speed = torch.stack([s.v[0, :, 0].mean() for s in states]).view(-1, BLOCK).mean(-1)
    block_end = state.step + BLOCK * torch.arange(1, W_LOC // BLOCK + 1, dtype=F64)
    return ((speed - 0.004 * (block_end - train_start) * 0.01) ** 2).mean()


def test_locomotion_trainer_reports_the_speed_loss_after_the_warm_up_and_one_step_lowers_it():
    cfg = locomotion_cfg(1)
    a0 = fresh_agent(cfg)
    with torch.no_grad():
        _, s0 = swg_run(a0, lissajous_start(a0), WARMUP * W_LOC)  # the warm-up: no update, not in any loss
        s0 = s0.detach()
        hand = locomotion_loss(a0, s0, WARMUP * W_LOC)
    res = train(cfg, None, progress=False)
    assert res.losses == pytest.approx([float(hand)], rel=1e-10)
    check_sgd(a0, named, lambda a: locomotion_loss(a, s0, WARMUP * W_LOC), res.agent, LOCOMOTION_LR)
    with torch.no_grad():
        after = locomotion_loss(res.agent, s0, WARMUP * W_LOC)
    assert float(after) < 0.9 * float(hand), (float(after), float(hand))


# -- NARMA and the memory task ----------------------------------------------------------------------------------
#: the authors' config timeseries/expandedNARMA.yaml (published-code-facts.md, "Expanded NARMA rates"): k 1000,
#: d 100, l 1, brain 0.01
NARMA_LR = {"k": 1e3, "d": 1e2, "l": 1.0, "brain": 1e-2}
N_IN, TAU, WASHOUT, TRAIN_END, DELAY = 14, 5, 3, 10, 2


def narma_cfg(target: str, epochs: int = 1):
    return load_config(CONFIG / "narma.yaml", [
        "dtype=float64", f"epochs={epochs}", "body.nodes=13", "brain.type=lil", f"narma.n_inputs={N_IN}",
        f"narma.tau={TAU}", f"narma.washout={WASHOUT}", f"narma.train_end={TRAIN_END}", f"narma.target={target}",
        f"narma.delay={DELAY}", "narma.eval_seed=99"])


def narma_target(u: np.ndarray, target: str) -> np.ndarray:
    """Expanded NARMA2, y(t+1) = 0.3 y(t) + Σ_{i<2} (u(t−i)³ − u(t−i)⁴) + 0.2 Σ_{i<2} (y(t−i)³ − y(t−i)⁴) + 0.1,
    entry t = y(t+1); the memory task: u(t − Δt) (0 before the series starts)."""
    if target == "memory":
        return np.concatenate([np.zeros(DELAY), u[:-DELAY]])
    y = [0.0, 0.0]  # y(−1), y(0)
    for t in range(len(u)):
        u1 = u[t - 1] if t else 0.0
        y.append(0.3 * y[-1] + u[t] ** 3 - u[t] ** 4 + u1 ** 3 - u1 ** 4 + 0.2 * (y[-1] ** 3 - y[-1] ** 4
                                                                                  + y[-2] ** 3 - y[-2] ** 4) + 0.1)
    return np.array(y[2:])


def narma_output(agent, u: np.ndarray) -> torch.Tensor:
    """The CMP's y at the end of each τ-step block, from rest; input 20·u(j) held at steps jτ+1 .. (j+1)τ (and 0),
    the LIL's 2(M−1) outputs the forces on the movable masses except the CMP."""
    body, brain = agent.body, agent.brain
    movable = [i for i in range(body.n_movable) if i != body.cmp_local]

    def force(value: float) -> torch.Tensor:
        f = torch.zeros(1, body.n_movable, 2, dtype=F64)
        f[0, movable] = brain(torch.tensor([20.0 * value], dtype=F64)).view(-1, 2)
        return f

    s = body.initial_state(1, external_force=force(u[0]))
    out = []
    for k in range(1, len(u) * TAU + 1):
        s = body.step(s, body.l, force(u[(k - 1) // TAU]))
        if k % TAU == 0:
            out.append(s.r[0, body.cmp_local, 1])
    return torch.stack(out)


def narma_loss(agent, u: np.ndarray, target: str) -> torch.Tensor:
    """MSE over the training samples washout .. train_end − 1 only."""
    y = torch.as_tensor(narma_target(u, target))
    return ((narma_output(agent, u) - y)[WASHOUT:TRAIN_END] ** 2).mean()


@pytest.mark.parametrize("target", ["expanded", "memory"])
def test_narma_trainer_reports_the_loss_after_the_washout_and_one_step_lowers_it(target):
    cfg = narma_cfg(target)
    a0 = fresh_agent(cfg)
    u = np.random.default_rng(cfg.seed).uniform(0.0, 1.0, N_IN)  # epoch 0's input: the task's first draw
    res = train(cfg, None, progress=False)
    with torch.no_grad():
        hand = narma_loss(a0, u, target)
        after = narma_loss(res.agent, u, target)
    assert res.losses == pytest.approx([float(hand)], rel=1e-10)
    check_sgd(a0, named, lambda a: narma_loss(a, u, target), res.agent, NARMA_LR)
    assert float(after) < 0.9 * float(hand), (float(after), float(hand))
    # the reported metric: NMSE = mean((out − y)²) / var(y) on the held-out sequence's test samples train_end ..
    u_eval = np.random.default_rng(99).uniform(0.0, 1.0, N_IN)
    with torch.no_grad():
        out = narma_output(res.agent, u_eval).numpy()
    y = narma_target(u_eval, target)
    ev = res.metrics["evaluation"]
    assert ev["nmse_test"] == pytest.approx(np.mean((out - y)[TRAIN_END:] ** 2) / np.var(y[TRAIN_END:]), rel=1e-9)
    assert ev["nmse_after_washout"] == pytest.approx(np.mean((out - y)[WASHOUT:] ** 2) / np.var(y[WASHOUT:]),
                                                     rel=1e-9)


def test_narma_epochs_draw_fresh_inputs():
    """Epoch 1 trains on the task's second draw (a new sequence from rest), with the parameters of epoch 0."""
    cfg = narma_cfg("expanded", epochs=2)
    one = train(narma_cfg("expanded"), None, progress=False)
    two = train(cfg, None, progress=False)
    rng = np.random.default_rng(cfg.seed)
    rng.uniform(0.0, 1.0, N_IN)
    u1 = rng.uniform(0.0, 1.0, N_IN)
    with torch.no_grad():
        hand = narma_loss(one.agent, u1, "expanded")
    assert two.losses[1] == pytest.approx(float(hand), rel=1e-10)


#: the paper's table, row "Locomotion (switching)": k 1e0, d 1e-2, l 1e-3, A 1e-5, φ 1e-4
HEADWIND_LR = {"k": 1e0, "d": 1e-2, "l": 1e-3, "amplitude": 1e-5, "phase": 1e-4}


def test_headwind_trainer_pushes_with_the_periodic_wind_against_a_constant_target():
    """locomotion_headwind: −1 N along x on every mass at the steps k with (k mod 30) ≥ 15 (period 0.3 s: calm for
    its first half, blowing for the second), the speed compared with a constant 0.5 m/s."""
    cfg = load_config(CONFIG / "locomotion_headwind.yaml", [
        "dtype=float64", f"training.update_steps={W_LOC}", f"locomotion.speed_block={BLOCK}",
        "locomotion.wind_period=0.3", "locomotion.target_speed=0.5", f"sim_time={W_LOC * 0.01}",
        "locomotion.eval_time=0.4"])
    a0 = fresh_agent(cfg)
    s0 = lissajous_start(a0)

    def loss(agent):
        body, s, speed = agent.body, s0, []
        for k in range(1, W_LOC + 1):
            f = torch.zeros(1, body.n_movable, 2, dtype=F64)
            f[..., 0] = -1.0 if k % 30 >= 15 else 0.0
            s = body.step(s, body.l * (1 + swg_signal(agent.brain, k, body.dt)), f)
            speed.append(s.v[0, :, 0].mean())
        return ((torch.stack(speed).view(-1, BLOCK).mean(-1) - 0.5) ** 2).mean()

    res = train(cfg, None, progress=False)
    with torch.no_grad():
        hand, after = loss(a0), loss(res.agent)
    assert res.losses == pytest.approx([float(hand)], rel=1e-10)
    check_sgd(a0, named, loss, res.agent, HEADWIND_LR)
    assert float(after) < 0.999 * float(hand), (float(after), float(hand))  # measured: −0.5 % at these small rates
