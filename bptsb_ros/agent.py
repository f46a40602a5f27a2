"""An agent: a body, its brain and (for SWG agents) a feedback layer, built from a config."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import nn

from bptsb_ros.body.msdn import MSDN, Environment
from bptsb_ros.body.shapes import build_shape
from bptsb_ros.brains import FeedbackLayer, LinearInputLayer, MLPBrain, SineWaveGenerator
from bptsb_ros.config import ExperimentConfig

Brain = SineWaveGenerator | MLPBrain | LinearInputLayer


@dataclass
class Agent:
    """A brain–body system. ``config`` is the resolved experiment config as a plain dict; ``feedback_fitted``
    says whether ``feedback`` holds a ridge fit (a fresh feedback layer is all zeros)."""

    config: dict
    body: MSDN
    brain: Brain
    feedback: FeedbackLayer | None
    feedback_fitted: bool = False

    @property
    def task(self) -> str:
        return str(self.config["task"])

    @property
    def dtype(self) -> torch.dtype:
        return self.body.positions0.dtype

    @property
    def dt(self) -> float:
        return self.body.dt

    def modules(self) -> dict[str, nn.Module]:
        out: dict[str, nn.Module] = {"body": self.body, "brain": self.brain}
        if self.feedback is not None:
            out["feedback"] = self.feedback
        return out


def dtype_of(name: str) -> torch.dtype:
    return {"float32": torch.float32, "float64": torch.float64}[name]


def force_inputs(body: MSDN) -> torch.Tensor:
    """(M,) bool: movable masses that receive brain forces — all but the CMP (paper, NARMA task)."""
    mask = torch.ones(body.n_movable, dtype=torch.bool)
    if body.cmp_local >= 0:
        mask[body.cmp_local] = False
    return mask


def body_backend(training_backend: str) -> str:
    """The body's backend for a ``training.backend``: ``fused`` trains through compiled calls of its own and
    simulates everything else (evaluation, feedback fit, live nodes) on the numba kernel."""
    return "numba" if training_backend == "fused" else training_backend


def build_agent(cfg: ExperimentConfig) -> Agent:
    """Fresh agent from a config: random k, d (seeded), rest lengths = geometry, fresh brain."""
    dtype = dtype_of(cfg.dtype)
    gen = torch.Generator().manual_seed(cfg.seed)
    b = cfg.body
    topology = build_shape(b.shape, b.nodes, b.size, b.neighbours)
    env = Environment.locomotion() if b.environment == "locomotion" else Environment()
    if b.ground_clamp:
        env = replace(env, ground_clamp=True)
    body = MSDN(topology, dt=b.dt, integrator=b.integrator, environment=env, k_init=b.k_init,
                d_init=b.d_init, generator=gen, dtype=dtype, backend=body_backend(cfg.training.backend))
    br = cfg.brain
    brain: Brain
    if br.type == "swg":
        brain = SineWaveGenerator(topology.n_springs, amplitude=br.amplitude, omega=br.omega,
                                  generator=gen, dtype=dtype)
    else:
        n_out = 2 * int(force_inputs(body).sum())
        if br.type == "mlp":
            brain = MLPBrain(1, n_out, hidden=br.hidden, gain=br.gain, generator=gen, dtype=dtype)
        else:
            brain = LinearInputLayer(1, n_out, generator=gen, dtype=dtype)
    feedback = None
    if br.type == "swg" and cfg.feedback.enabled:
        n_features = topology.n_springs if cfg.feedback.state == "spring_length" else 2 * body.n_movable
        feedback = FeedbackLayer(n_features, topology.n_springs, state_type=cfg.feedback.state, dtype=dtype)
    return Agent(cfg.model_dump(mode="json"), body, brain, feedback)


def brain_forces(agent: Agent, u: torch.Tensor) -> torch.Tensor:
    """Task input u (..., 1) → external forces (..., M, 2) on the movable masses (CMP force zero)."""
    body = agent.body
    out = agent.brain(u)
    mask = force_inputs(body)
    forces = out.new_zeros((*out.shape[:-1], body.n_movable, 2))
    forces[..., mask, :] = out.view(*out.shape[:-1], -1, 2)
    return forces
