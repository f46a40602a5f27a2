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

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch
from torch import nn

from bptsb_ros.body.forces import environment_forces, incidence_operators, spring_forces
from bptsb_ros.body.shapes import Topology

Integrator = Literal["verlet", "published"]
#: how the body is integrated: ``numba`` = the compiled window kernel (``body/kernel.py``; CPU), ``torch`` = torch
#: ops (the reference; also runs on a GPU). Both give the same trajectories and gradients to rounding.
Backend = Literal["numba", "torch"]
BACKENDS = ("numba", "torch")
#: projections of k, d, l after a training update (:meth:`MSDN.clamp_parameters_`)
PROJECTIONS = ("clamp", "reset")
#: what the ``reset`` projection sets a negative k [N/m], d [N s/m] or l [m] to (the authors' code)
RESET_VALUE = 0.1


#: |position| [m] beyond which a simulation counts as diverged (:meth:`MSDN.check_finite`)
DIVERGENCE_LIMIT = 1e6


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
        backend: Backend = "numba",
    ) -> None:
        super().__init__()
        if integrator not in ("verlet", "published"):
            raise ValueError(f"integrator must be 'verlet' or 'published', got {integrator!r}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be 'numba' or 'torch', got {backend!r}")
        self.backend: Backend = backend
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be finite and positive, got {dt}")
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
        # The window kernel's view of the layout: each spring's movable end indices (−1: a fixed mass).
        ends = np.array([[col.get(int(n), -1) for n in pair] for pair in topology.springs], dtype=np.int64)
        self.spring_i = np.ascontiguousarray(ends.reshape(n_springs, 2)[:, 0])
        self.spring_j = np.ascontiguousarray(ends.reshape(n_springs, 2)[:, 1])
        self.register_buffer("incidence", torch.tensor(incidence, dtype=dtype))
        gather, scatter = incidence_operators(self.incidence)
        self.register_buffer("gather", gather, persistent=False)
        self.register_buffer("scatter", scatter, persistent=False)
        self.register_buffer("fixed_offset", torch.tensor(fixed_offset, dtype=dtype))
        self.register_buffer("positions0", torch.tensor(topology.positions, dtype=dtype))
        self.register_buffer("movable_index", torch.as_tensor(movable, dtype=torch.long))
        # the CMP's row among the movable masses, once: tasks read it every update
        self._cmp_local = ([int(i) for i in movable].index(topology.cmp_index)
                           if topology.cmp_index >= 0 else -1)
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
        return self._cmp_local

    def full_positions(self, r: torch.Tensor) -> torch.Tensor:
        """(B, M, 2) movable positions → (B, N, 2) positions of every mass, fixed ones included."""
        full = self.positions0.expand(r.shape[0], -1, -1).clone()
        full[:, self.movable_index] = r
        return full

    def clamp_parameters_(self, projection: str = "clamp") -> None:
        """Project k, d, l after an update, in place (NaN kept).

        ``clamp``: onto [0, ∞) (the paper: parameters never go below zero); ``reset``: a negative entry is set to
        :data:`RESET_VALUE` (the authors' published code)."""
        if projection not in PROJECTIONS:
            raise ValueError(f"projection must be one of {', '.join(PROJECTIONS)}, got {projection!r}")
        with torch.no_grad():
            for p in (self.k, self.d, self.l):
                if projection == "clamp":
                    p.clamp_(min=0.0)
                else:
                    p.masked_fill_(p < 0, RESET_VALUE)

    # -- dynamics ---------------------------------------------------------------------------------
    def acceleration(
        self,
        r: torch.Tensor,
        v: torch.Tensor,
        rest_length: torch.Tensor,
        external_force: torch.Tensor | None,
        k: torch.Tensor | None = None,
        d: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """a = F/m for movable masses, and spring lengths. ``v`` is the velocity the damping sees; ``k``, ``d``:
        (B, E) spring constants and damping of B bodies of this topology instead of the body's own (a population,
        ``workflows/population.py``)."""
        force, length = spring_forces(
            r, v, self.gather, self.scatter, self.fixed_offset, self.k if k is None else k, self.d if d is None else d,
            rest_length
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

    def displaced(
        self,
        state: BodyState,
        displacement: torch.Tensor,
        rest_length: torch.Tensor | None = None,
        external_force: torch.Tensor | None = None,
    ) -> BodyState:
        """``state`` with its movable masses moved by ``displacement`` (B, M, 2) [m], at the same step: velocities
        kept, accelerations and spring lengths recomputed with the rest length (E,) or (B, E) and the external force
        in force at that step (a perturbation, paper Fig. 4(b,c)). A one-row ``state`` is repeated to B rows."""
        r = state.r + displacement.to(state.r.dtype)
        v = state.v.expand_as(r).clone()
        rest = self.l if rest_length is None else rest_length
        rest = rest.reshape(-1, rest.shape[-1]).expand(r.shape[0], -1)
        a, length = self.acceleration(r, v, rest, external_force)
        return BodyState(r, v, a, length, state.step)

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

        With the numba backend and nothing to differentiate (``uses_kernel``) the step is the window
        kernel run for one step (what ``body_sim`` calls); otherwise the torch ops below.
        """
        dt = self.dt
        l_next = self.l if rest_length is None else rest_length
        if self.uses_kernel(state.r, state.v, state.a, l_next, external_force):
            shape = (1, *external_force.shape) if external_force is not None else None
            r, v, a, length = self.kernel_window(state.r, state.v, state.a, l_next.unsqueeze(0),
                                                 None if shape is None else external_force.reshape(shape))
            return BodyState(r[0], v[0], a[0], length[0], state.step + 1)
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

    # -- the compiled backend -------------------------------------------------------------------
    @torch.no_grad()
    def warm_up(self) -> None:
        """Run one throwaway step so the numba kernel is loaded from its cache (or compiled) before timing
        matters (the live node's first step); nothing for the torch backend."""
        if self.uses_kernel():
            self.step(self.initial_state(1))

    def uses_kernel(self, *tensors: torch.Tensor | None) -> bool:
        """True when a step or window on these tensors runs in the numba kernel: backend ``numba``, CPU
        tensors, and no autograd tape wanted through them (differentiable windows go through
        ``body.adjoint.rollout_window``, whose backward is the kernel's adjoint)."""
        if self.backend != "numba" or self.k.device.type != "cpu":
            return False
        if not torch.is_grad_enabled():
            return True
        return not (self.k.requires_grad or self.d.requires_grad
                    or any(t is not None and t.requires_grad for t in tensors))

    def kernel_window(
        self,
        r0: torch.Tensor,
        v0: torch.Tensor,
        a0: torch.Tensor,
        rest_lengths: torch.Tensor,
        external_forces: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """W steps in one compiled call, without autograd (the numba backend's forward).

        Args:
            r0: (B, M, 2) start positions [m].
            v0: (B, M, 2) start velocities [m/s].
            a0: (B, M, 2) start accelerations [m/s²].
            rest_lengths: (W, E) or (W, B', E) with B' ∈ {1, B} [m].
            external_forces: (W, M, 2) or (W, B', M, 2) [N], or None.

        Returns:
            r, v, a: (W, B, M, 2) states 1..W; length: (W, B, E) spring lengths the forces saw [m].
        """
        from bptsb_ros.body import kernel

        n_steps, dtype = rest_lengths.shape[0], r0.dtype
        rest = _as_numpy(rest_lengths if rest_lengths.dim() == 3 else rest_lengths.unsqueeze(1), dtype)
        ext = self._kernel_ext(external_forces, n_steps, dtype)
        batch = max(r0.shape[0], rest.shape[1], ext.shape[1])  # broadcast as the torch ops would
        for name, n in (("state", r0.shape[0]), ("rest_lengths", rest.shape[1]), ("external_forces", ext.shape[1])):
            if n not in (0, 1, batch):
                raise ValueError(f"{name} has batch {n}, the window {batch}: they must match or be 1")
        if r0.shape[0] != batch:
            r0, v0, a0 = (x.expand(batch, -1, -1) for x in (r0, v0, a0))
        r = torch.empty((n_steps, batch, r0.shape[1], 2), dtype=dtype)
        v, a = torch.empty_like(r), torch.empty_like(r)
        length = torch.empty((n_steps, batch, self.topology.n_springs), dtype=dtype)
        k, d, offset, mass, coef = self.kernel_constants(dtype)
        kernel.forward(_as_numpy(r0, dtype), _as_numpy(v0, dtype), _as_numpy(a0, dtype), k, d, rest, ext,
                       self.spring_i, self.spring_j, offset, mass, coef, self.integrator == "verlet",
                       bool(self.environment.ground_clamp), r.numpy(), v.numpy(), a.numpy(), length.numpy())
        return r, v, a, length

    def kernel_constants(self, dtype: torch.dtype) -> tuple[np.ndarray, ...]:
        """k, d, fixed offsets, masses (numpy views of the live tensors) and the kernels' scalars, in ``dtype``."""
        from bptsb_ros.body import kernel

        key = (dtype, self.k.data_ptr(), self.d.data_ptr(), self.fixed_offset.data_ptr(), self.mass.data_ptr())
        if getattr(self, "_kernel_views", (None,))[0] != key:
            views = tuple(_as_numpy(t, dtype) for t in (self.k, self.d, self.fixed_offset, self.mass))
            self._kernel_views = (key, views)
        env = self.environment
        coef = kernel.coefficients(self.dt, -float(env.gravity), float(env.air_drag), float(env.ground_c),
                                   _NUMPY[dtype])
        return (*self._kernel_views[1], coef)

    def _kernel_ext(self, external_forces: torch.Tensor | None, n_steps: int, dtype: torch.dtype) -> np.ndarray:
        """External forces as the kernel's (W, B', M, 2) array (B' = 0 when there are none)."""
        if external_forces is None or external_forces.numel() == 0:
            return np.zeros((n_steps, 0, self.n_movable, 2), dtype=_NUMPY[dtype])
        ext = external_forces if external_forces.dim() == 4 else external_forces.unsqueeze(1)
        return _as_numpy(ext, dtype)

    def parameter_ranges(self) -> str:
        """``k in [lo, hi], d in [..], l in [..]``: for error messages."""
        return parameter_ranges(self.k, self.d, self.l)

    def check_finite(self, state: BodyState, limit: float = DIVERGENCE_LIMIT) -> None:
        """Raise SimulationDiverged (with the step and parameter ranges) on NaN/inf or |r| > limit (the test:
        :func:`state_is_sound`, on numpy views of CPU states; a handful of torch reductions elsewhere)."""
        parts = (state.r, state.v, state.a)
        if all(t.device.type == "cpu" and t.dtype in _NUMPY for t in parts):
            if state_is_sound(*(_as_numpy(t, t.dtype) for t in parts), limit):
                return
        else:
            r = state.r.detach()
            finite = bool(torch.isfinite(r).all() and torch.isfinite(state.v).all() and torch.isfinite(state.a).all())
            if finite and float(r.abs().max()) <= limit:
                return
        raise SimulationDiverged(diverged_message(state.step, self.dt, self.parameter_ranges(), limit))


_NUMPY = {torch.float32: np.float32, torch.float64: np.float64}


def parameter_ranges(k: torch.Tensor, d: torch.Tensor, l: torch.Tensor) -> str:  # noqa: E741
    """``k in [lo, hi], d in [..], l in [..]`` of one body's parameters (E,): for error messages."""
    named = (("k", k), ("d", d), ("l", l))
    return ", ".join(f"{n} in [{float(t.detach().min()):.4g}, {float(t.detach().max()):.4g}]" for n, t in named)


def diverged_message(step: int, dt: float, ranges: str, limit: float = DIVERGENCE_LIMIT) -> str:
    """What :class:`SimulationDiverged` says for a body that left the sensible range at ``step`` (``dt`` [s];
    ``ranges``: :func:`parameter_ranges`)."""
    return (f"simulation diverged at step {step} (t = {step * dt:.2f} s): positions non-finite or beyond {limit:g} m; "
            f"body parameters {ranges}. Lower the learning rates, the time step or the input scale.")


def state_is_sound(r: np.ndarray, v: np.ndarray, a: np.ndarray, limit: float = DIVERGENCE_LIMIT) -> bool:
    """:meth:`MSDN.check_finite`'s test on numpy arrays: everything finite and every |r| ≤ ``limit`` [m]."""
    return bool(lanes_sound(*(x.reshape(-1, 1) for x in (r, v, a)), limit)[0])


def lanes_sound(r: np.ndarray, v: np.ndarray, a: np.ndarray, limit: float = DIVERGENCE_LIMIT) -> np.ndarray:
    """:func:`state_is_sound` of each of P bodies whose states are stacked along the last axis (..., P): (P,)
    bool."""
    axes = tuple(range(r.ndim - 1))
    with np.errstate(invalid="ignore"):  # NaN in |r| compares False, as intended
        return (np.isfinite(r).all(axis=axes) & np.isfinite(v).all(axis=axes) & np.isfinite(a).all(axis=axes)
                & (np.abs(r).max(axis=axes) <= limit))


def _as_numpy(t: torch.Tensor, dtype: torch.dtype) -> np.ndarray:
    """A C-contiguous numpy view (a copy only when needed) of a CPU tensor, without its autograd history."""
    t = t.detach()
    if t.dtype != dtype:
        raise TypeError(f"the body runs in {dtype}, got a {t.dtype} tensor")
    return t.contiguous().numpy()
