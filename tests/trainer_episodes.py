"""Shared pieces of the trainer tests (tests/test_trainers_learn*.py): a trainer's starting agent and the SWG-driven
body stepped with plain autograd (``MSDN.step``, not the trainers' window kernel), written out independently."""

from __future__ import annotations

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
