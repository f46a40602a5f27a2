"""Shared pieces of the trainer tests (tests/training/test_trainers_learn*.py): a trainer's starting agent, the
SWG-driven body stepped with plain autograd (``MSDN.step``, not the trainers' window kernel), written out
independently, and the check that one update is the documented optimiser step."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import torch

from bptsb_ros.agent import build_agent
from bptsb_ros.body.msdn import BodyState

CONFIG = Path(__file__).resolve().parents[1] / "config"
F64 = torch.float64


def fresh_agent(cfg):
    """The agent train() starts from (it seeds torch with cfg.seed, then builds)."""
    torch.manual_seed(cfg.seed)
    return build_agent(cfg)


def swg_signal(swg, k: int, dt: float) -> torch.Tensor:
    """A·sin(ω k Δt + φ), ω = 2π (the paper's SWG), written out: (E,)."""
    return swg.amplitude * torch.sin(2 * math.pi * k * dt + swg.phase)


def lissajous_start(agent) -> BodyState:
    body = agent.body
    return body.initial_state(1, rest_length=body.l * (1 + swg_signal(agent.brain, 0, body.dt)))


def swg_run(agent, state: BodyState, steps: int) -> tuple[list[BodyState], BodyState]:
    """Every state after steps k0+1 .. k0+steps of the SWG-driven body."""
    body, out, s = agent.body, [], state
    for k in range(state.step + 1, state.step + steps + 1):
        s = body.step(s, body.l * (1 + swg_signal(agent.brain, k, body.dt)))
        out.append(s)
    return out, s


def check_sgd(before, params_of, loss_fn, after, lr: dict[str, float], *, adam: bool = False) -> None:
    """``params_of(after)`` = ``params_of(before)`` moved by one SGD step −η·∂L/∂θ (``adam``: Adam's first step,
    −η·g/(|g| + ε), ε = 1e-8), body kinds k, d, l projected onto ≥ 0; every kind moved. ``loss_fn(model)`` is the
    independent loss; η = ``lr[name before the first dot]``."""
    model = copy.deepcopy(before)
    params = params_of(model)
    for p in params.values():
        p.requires_grad_(True)
        p.grad = None
    loss_fn(model).backward()
    got = params_of(after)
    for name, p in params.items():
        rate = lr[name.split(".")[0]]
        step = p.grad / (p.grad.abs() + 1e-8) if adam else p.grad
        expected = p.detach() - rate * step
        if name in ("k", "d", "l"):
            expected = expected.clamp(min=0.0)
        assert float((got[name].detach() - p.detach()).abs().max()) > 0, f"{name} did not move"
        torch.testing.assert_close(got[name].detach(), expected, rtol=1e-7, atol=1e-10, msg=name)
