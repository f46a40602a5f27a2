"""The mass-spring-damper network (MSDN): trainable body parameters and the velocity-Verlet step.

This module holds the one step function used everywhere — offline simulation, BPTSB training and
the live ``body_sim`` node. The step (paper, Methods; supplement Eqs. for a(t+Δt)):

    r(t+Δt) = r(t) + v(t)Δt + a(t)Δt²/2
    a(t+Δt) = F(r(t+Δt), v(t), l(t+Δt), f_ext(t+Δt)) / m        (velocity-dependent forces use v(t))
    v(t+Δt) = v(t) + (a(t) + a(t+Δt))Δt/2

with a(0) = F(r(0), v(0), l(0), f_ext(0)) / m. ``integrator="published"`` reproduces the authors'
published code, which restarted the integrator every step so that a(t) was always zero:
r ← r + vΔt, v ← v + a(r_new, v_old)Δt/2. With ``Environment.ground_clamp`` every movable mass
that the position update put below y = 0 is set to y = 0 and v(t) = 0 before a(t+Δt) and v(t+Δt)
are computed (the published code's order), so the forces see the clamped state.

Only movable masses are integrated; fixed masses never move, so their contribution to every spring
vector is a constant folded into ``fixed_offset``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import nn

from bptsb_ros.body.forces import environment_forces, incidence_operators, spring_forces
from bptsb_ros.body.shapes import Topology

Integrator = Literal["verlet", "published"]


class SimulationDiverged(RuntimeError):
    """A simulation produced NaN/inf or left any physically sensible range."""


@dataclass
class BodyState:
    """Dynamic state of a batch of bodies (movable masses only).

    r, v, a: (B, M, 2) positions [m], velocities [m/s], accelerations [m/s²].
    length: (B, E) spring lengths at ``r``, the ones the forces of this step saw [m].
    step: number of integration steps taken since t = 0.
    """

    r: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    length: torch.Tensor
    step: int = 0

    def detach(self) -> BodyState:
        """Same state with gradients cut (truncated BPTT windows carry the state over detached)."""
        return BodyState(self.r.detach(), self.v.detach(), self.a.detach(), self.length.detach(), self.step)


@dataclass(frozen=True)
class Environment:
    """External physics: gravity magnitude g [m/s², pulls −y], air drag a [N·s/m], ground constant c [1/m].

    ``ground_clamp`` reproduces the published code's hard floor (y < 0 → y = 0, v = 0), in its order:
    right after the position update, before the forces and the velocity update, so a clamped mass
    ends the step with v = Δt/2·(a(t) + a(t+Δt)) (``published``: Δt/2·a(t+Δt)), not 0. The paper
    uses the soft ground only, so it is off by default.
    """

    gravity: float = 0.0
    air_drag: float = 0.0
    ground_c: float = 0.0
    ground_clamp: bool = False

    @staticmethod
    def locomotion() -> Environment:
        return Environment(gravity=9.81, air_drag=0.1, ground_c=10.0)


class MSDN(nn.Module):
    """A batched, differentiable mass-spring-damper network.

    Parameters (per spring, shape (E,)): ``k`` spring constant, ``d`` damping, ``l`` rest length.
    All masses are 1 (the paper); ``mass`` is a buffer so other values stay possible.
    """

    def __init__(
        self,
        topology: Topology,
        *,
        dt: float = 0.01,
        integrator: Integrator = "verlet",
        environment: Environment = Environment(),
        k_init: tuple[float, float] = (1.0, 100.0),
        d_init: tuple[float, float] = (0.0, 10.0),
        generator: torch.Generator | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        if integrator not in ("verlet", "published"):
            raise ValueError(f"integrator must be 'verlet' or 'published', got {integrator!r}")
        if dt <= 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.topology = topology
        self.dt = float(dt)
        self.integrator: Integrator = integrator
        self.environment = environment
        n_springs = topology.n_springs
        movable = topology.movable
        col = {int(m): c for c, m in enumerate(movable)}
        incidence = np.zeros((n_springs, len(movable)))
        fixed_offset = np.zeros((n_springs, 2))
        for e, (i, j) in enumerate(topology.springs):
            for node, sign in ((i, 1.0), (j, -1.0)):
                if topology.fixed[node]:
                    fixed_offset[e] += sign * topology.positions[node]
                else:
                    incidence[e, col[int(node)]] = sign
        self.register_buffer("incidence", torch.tensor(incidence, dtype=dtype))
        gather, scatter = incidence_operators(self.incidence)
        self.register_buffer("gather", gather, persistent=False)
        self.register_buffer("scatter", scatter, persistent=False)
        self.register_buffer("fixed_offset", torch.tensor(fixed_offset, dtype=dtype))
        self.register_buffer("positions0", torch.tensor(topology.positions, dtype=dtype))
        self.register_buffer("movable_index", torch.as_tensor(movable, dtype=torch.long))
        self.register_buffer("mass", torch.ones(len(movable), dtype=dtype))  # the paper: all masses 1 kg
        # Gravity is an acceleration [0, −g], independent of the masses.
        gravity = torch.tensor([0.0, -environment.gravity], dtype=dtype) if environment.gravity else None
        self.register_buffer("gravity", gravity, persistent=False)
        # The hard floor as a lower bound per coordinate: y ≥ 0, x free.
        self.register_buffer("floor", torch.tensor([-float("inf"), 0.0], dtype=dtype), persistent=False)
        g = torch.rand(n_springs, generator=generator, dtype=torch.float64)
        self.k = nn.Parameter((k_init[0] + (k_init[1] - k_init[0]) * g).to(dtype))
        g = torch.rand(n_springs, generator=generator, dtype=torch.float64)
        self.d = nn.Parameter((d_init[0] + (d_init[1] - d_init[0]) * g).to(dtype))
        self.l = nn.Parameter(torch.tensor(topology.rest_lengths(), dtype=dtype))

    # -- geometry helpers -------------------------------------------------------------------------
    @property
    def n_movable(self) -> int:
        return int(self.movable_index.numel())

    @property
    def cmp_local(self) -> int:
        """Index of the CMP among the movable masses (state rows); -1 if the shape has none."""
        if self.topology.cmp_index < 0:
            return -1
        return int((self.movable_index == self.topology.cmp_index).nonzero()[0, 0])

    def full_positions(self, r: torch.Tensor) -> torch.Tensor:
        """(B, M, 2) movable positions → (B, N, 2) positions of every mass, fixed ones included."""
        full = self.positions0.expand(r.shape[0], -1, -1).clone()
        full[:, self.movable_index] = r
        return full

    def clamp_parameters_(self) -> None:
        """Project k, d, l onto [0, ∞) (the paper: parameters never go below zero)."""
        with torch.no_grad():
            for p in (self.k, self.d, self.l):
                p.clamp_(min=0.0)

    # -- dynamics ---------------------------------------------------------------------------------
    def acceleration(
        self,
        r: torch.Tensor,
        v: torch.Tensor,
        rest_length: torch.Tensor,
        external_force: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """a = F/m for movable masses, and spring lengths. ``v`` is the velocity the damping sees."""
        force, length = spring_forces(
            r, v, self.gather, self.scatter, self.fixed_offset, self.k, self.d, rest_length
        )
        env = self.environment
        extra = environment_forces(r, v, env.air_drag, env.ground_c)
        if extra is not None:
            force = force + extra
        if external_force is not None:
            force = force + external_force
        a = force / self.mass.unsqueeze(-1)
        return (a if self.gravity is None else a + self.gravity), length

    def initial_state(
        self,
        batch: int = 1,
        *,
        rest_length: torch.Tensor | None = None,
        external_force: torch.Tensor | None = None,
        displacement: torch.Tensor | None = None,
        velocity: torch.Tensor | None = None,
    ) -> BodyState:
        """State at t = 0: the layout (plus ``displacement`` (B, M, 2)), at rest unless ``velocity``."""
        r = self.positions0[self.movable_index].expand(batch, -1, -1)
        if displacement is not None:
            r = r + displacement
        v = torch.zeros_like(r) if velocity is None else velocity.expand_as(r)
        l0 = self.l if rest_length is None else rest_length
        a, length = self.acceleration(r, v, l0, external_force)
        return BodyState(r, v, a, length, 0)

    def step(
        self,
        state: BodyState,
        rest_length: torch.Tensor | None = None,
        external_force: torch.Tensor | None = None,
    ) -> BodyState:
        """Advance one step of ``dt``.

        Args:
            state: the state at step t.
            rest_length: (E,) or (B, E) rest length in force at step t+1 (default: ``self.l``).
            external_force: (B, M, 2) or (M, 2) brain + wind force at step t+1 [N], or None.
        """
        dt = self.dt
        l_next = self.l if rest_length is None else rest_length
        verlet = self.integrator == "verlet"
        r = torch.add(state.r, state.v, alpha=dt)
        if verlet:
            r = r.add_(state.a, alpha=0.5 * dt * dt)
        v = state.v
        if self.environment.ground_clamp:  # the published order: clamp, then forces and velocity update
            v = v.masked_fill(r[..., 1:] < 0, 0.0)
            r = torch.maximum(r, self.floor)
        a, length = self.acceleration(r, v, l_next, external_force)
        if verlet:
            v = torch.add(v, state.a + a, alpha=0.5 * dt)
        else:
            v = torch.add(v, a, alpha=0.5 * dt)  # the stale a(t) was zero in the published code
        return BodyState(r, v, a, length, state.step + 1)

    def parameter_ranges(self) -> str:
        """``k in [lo, hi], d in [..], l in [..]``: for error messages."""
        named = (("k", self.k), ("d", self.d), ("l", self.l))
        return ", ".join(f"{n} in [{float(t.detach().min()):.4g}, {float(t.detach().max()):.4g}]" for n, t in named)

    def check_finite(self, state: BodyState, limit: float = 1e6) -> None:
        """Raise SimulationDiverged (with the step and parameter ranges) on NaN/inf or |r| > limit."""
        r = state.r.detach()
        finite = bool(torch.isfinite(r).all() and torch.isfinite(state.v).all() and torch.isfinite(state.a).all())
        if finite and float(r.abs().max()) <= limit:
            return
        raise SimulationDiverged(
            f"simulation diverged at step {state.step} (t = {state.step * self.dt:.2f} s): positions "
            f"non-finite or beyond {limit:g} m; body parameters {self.parameter_ranges()}. Lower the learning rates, "
            "the time step or the input scale."
        )
