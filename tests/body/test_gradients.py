"""Finite-difference checks (float64, short horizons) of the gradients that BPTSB trains with.

Each case builds a scalar loss from a rollout through ``MSDN.step`` and compares the autograd gradient
with central differences, per parameter tensor: a random subset of partial derivatives plus
directional derivatives along random unit vectors (which involve every entry). The error measure is
‖g_fd − g‖ / ‖g‖ over the compared derivatives.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from finite_differences import fd_relative_error

from bptsb_ros.body.msdn import MSDN, Environment
from bptsb_ros.body.shapes import build_shape
from bptsb_ros.brains import LinearInputLayer, MLPBrain, SineWaveGenerator

F64 = torch.float64
TOLERANCE = 1e-5


def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def cmp_target(steps: int, dt: float) -> torch.Tensor:
    """(T, 2) a Lissajous-like target for the CMP [m]."""
    t = torch.arange(1, steps + 1, dtype=F64) * dt
    return torch.stack([0.2 * torch.cos(2 * math.pi * t), 0.2 * torch.sin(4 * math.pi * t)], dim=-1)


class SwgCircle:
    """Double-circle body driven by an SWG, perturbed at t = 0; loss = CMP trajectory MSE."""

    def __init__(self, integrator: str = "verlet", steps: int = 30) -> None:
        self.body = MSDN(build_shape("double_circle", 25), dtype=F64, generator=gen(1), integrator=integrator)
        self.swg = SineWaveGenerator(self.body.topology.n_springs, amplitude=0.3, generator=gen(2), dtype=F64)
        self.steps = steps
        self.displacement = 0.1 * torch.randn(1, self.body.n_movable, 2, generator=gen(3), dtype=F64)
        self.target = cmp_target(steps, self.body.dt)

    def loss(self) -> torch.Tensor:
        body = self.body
        rest = self.swg.rest_length(body.l, torch.arange(self.steps + 1, dtype=F64) * body.dt)  # (T+1, E)
        state = body.initial_state(1, rest_length=rest[0], displacement=self.displacement)
        cmp = []
        for t in range(1, self.steps + 1):
            state = body.step(state, rest_length=rest[t])
            cmp.append(state.r[0, body.cmp_local])
        return ((torch.stack(cmp) - self.target) ** 2).mean()


@pytest.mark.parametrize("name", ["k", "d", "l"])
def test_body_parameter_gradients(name: str) -> None:
    case = SwgCircle()
    err, norm = fd_relative_error(case.loss, getattr(case.body, name))
    assert norm > 1e-8 and err < TOLERANCE, (err, norm)


@pytest.mark.parametrize("name", ["amplitude", "phase"])
def test_swg_gradients(name: str) -> None:
    case = SwgCircle()
    err, norm = fd_relative_error(case.loss, getattr(case.swg, name))
    assert norm > 1e-8 and err < TOLERANCE, (err, norm)


@pytest.mark.parametrize("name", ["k", "amplitude"])
def test_published_integrator_gradients(name: str) -> None:
    case = SwgCircle(integrator="published")
    module = case.body if name == "k" else case.swg
    err, norm = fd_relative_error(case.loss, getattr(module, name))
    assert norm > 1e-8 and err < TOLERANCE, (err, norm)


class ForcedCircle:
    """Double-circle body pushed by a brain: u(t) → forces on the movable masses except the CMP (NARMA-like)."""

    def __init__(self, brain: torch.nn.Module, steps: int = 30) -> None:
        self.body = MSDN(build_shape("double_circle", 25), dtype=F64, generator=gen(4))
        self.brain = brain
        self.steps = steps
        self.u = torch.rand(steps + 1, 1, generator=gen(5), dtype=F64)
        self.target = 0.1 * torch.sin(torch.linspace(0, 3, steps, dtype=F64))
        self.mask = torch.ones(self.body.n_movable, 1, dtype=F64)
        self.mask[self.body.cmp_local] = 0.0

    def loss(self) -> torch.Tensor:
        body = self.body
        forces = self.brain(self.u).view(self.steps + 1, body.n_movable, 2) * self.mask
        state = body.initial_state(1, external_force=forces[0])
        ys = []
        for t in range(1, self.steps + 1):
            state = body.step(state, external_force=forces[t])
            ys.append(state.r[0, body.cmp_local, 1])
        return ((torch.stack(ys) - self.target) ** 2).mean()


@pytest.mark.parametrize("name", ["weight", "bias"])
def test_lil_gradients(name: str) -> None:
    case = ForcedCircle(LinearInputLayer(1, 26, generator=gen(6), dtype=F64))
    err, norm = fd_relative_error(case.loss, getattr(case.brain, name))
    assert norm > 1e-8 and err < TOLERANCE, (err, norm)


@pytest.mark.parametrize("layer", [0, 1, 2])
def test_mlp_gradients(layer: int) -> None:
    case = ForcedCircle(MLPBrain(1, 26, hidden=128, gain=2.7, generator=gen(7), dtype=F64))
    for name in ("weight", "bias"):
        param = getattr(case.brain.layers[layer], name)
        err, norm = fd_relative_error(case.loss, param, coordinates=4, directions=4, seed=layer)
        assert norm > 1e-10 and err < TOLERANCE, (layer, name, err, norm)


class Crawler:
    """Caterpillar in the locomotion environment driven by an SWG; loss on the mean forward speed."""

    def __init__(self, steps: int = 40) -> None:
        self.body = MSDN(build_shape("caterpillar", 10), dtype=F64, generator=gen(8),
                         environment=Environment.locomotion())
        self.swg = SineWaveGenerator(self.body.topology.n_springs, amplitude=0.4, generator=gen(9), dtype=F64)
        self.steps = steps

    def loss(self) -> torch.Tensor:
        body = self.body
        rest = self.swg.rest_length(body.l, torch.arange(self.steps + 1, dtype=F64) * body.dt)
        state = body.initial_state(1, rest_length=rest[0])
        speed, height = [], []
        for t in range(1, self.steps + 1):
            state = body.step(state, rest_length=rest[t])
            speed.append(state.v[0, :, 0].mean())
            height.append(state.r[0, :, 1].mean())
        return ((torch.stack(speed) - 0.5) ** 2).mean() + 0.1 * torch.stack(height).mean()


@pytest.mark.parametrize("name", ["k", "d", "l", "amplitude", "phase"])
def test_locomotion_gradients(name: str) -> None:
    case = Crawler()
    module = case.swg if name in ("amplitude", "phase") else case.body
    err, norm = fd_relative_error(case.loss, getattr(module, name))
    assert norm > 1e-8 and err < TOLERANCE, (err, norm)


class AdjointCase:
    """One window through ``rollout_window``: SWG rest lengths, LIL forces, a displaced start state whose
    displacement is trainable (as an MNIST brain's output); the loss reads r, v, a and the lengths."""

    def __init__(self, shape: str = "double_circle", *, integrator: str = "verlet", environment: Environment
                 | None = None, steps: int = 30, batch: int = 2, backend: str = "numba") -> None:
        nodes = 10 if shape == "caterpillar" else 25
        self.body = MSDN(build_shape(shape, nodes), dtype=F64, generator=gen(10), integrator=integrator,
                         environment=environment or Environment(), backend=backend)
        m, e = self.body.n_movable, self.body.topology.n_springs
        self.swg = SineWaveGenerator(e, amplitude=0.3, generator=gen(11), dtype=F64)
        self.lil = LinearInputLayer(1, 2 * m, generator=gen(12), dtype=F64)
        self.displacement = torch.nn.Parameter(0.05 * torch.randn(batch, m, 2, generator=gen(13), dtype=F64))
        self.u = torch.rand(steps + 1, batch, 1, generator=gen(14), dtype=F64)
        self.steps = steps
        self.watch = self.body.cmp_local if self.body.cmp_local >= 0 else 0

    def parameters(self) -> dict[str, torch.nn.Parameter]:
        return {"k": self.body.k, "d": self.body.d, "l": self.body.l, "amplitude": self.swg.amplitude,
                "phase": self.swg.phase, "lil.weight": self.lil.weight, "displacement": self.displacement}

    def loss(self, adjoint: bool = True, windows: int = 1) -> torch.Tensor:
        from bptsb_ros.body.adjoint import rollout_window

        body = self.body
        times = torch.arange(self.steps + 1, dtype=F64) * body.dt
        rest = self.swg.rest_length(body.l, times)  # (T+1, E)
        forces = 0.2 * self.lil(self.u).view(self.steps + 1, -1, body.n_movable, 2)  # (T+1, B, M, 2)
        state = body.initial_state(self.u.shape[1], rest_length=rest[0], external_force=forces[0],
                                   displacement=self.displacement)
        total = torch.zeros((), dtype=F64)
        bounds = torch.linspace(0, self.steps, windows + 1).round().long().tolist()
        for lo, hi in zip(bounds[:-1], bounds[1:]):  # consecutive windows, state carried with its gradient
            win = rollout_window(body, state, rest[lo + 1: hi + 1], forces[lo + 1: hi + 1], adjoint=adjoint)
            state = win.final
            total = total + (win.r[:, :, self.watch] ** 2).mean() + 0.1 * (win.v**2).mean() \
                + 1e-4 * (win.a**2).mean() + ((win.length - body.l) ** 2).mean()
        return total


ADJOINT_CASES = {
    "double_circle": dict(),
    "published": dict(integrator="published"),
    "locomotion": dict(shape="caterpillar", environment=Environment.locomotion()),
    "locomotion_clamp": dict(shape="caterpillar", environment=replace(Environment.locomotion(), ground_clamp=True)),
}


def clamp_counts(case: AdjointCase) -> tuple[int, int, int]:
    """(steps, masses, mass-steps put back on the floor) in the case body's unforced rollout from its
    displaced start (the feet start on y = 0 and gravity pulls them down)."""
    body = case.body
    state = body.initial_state(case.u.shape[1], displacement=case.displacement)
    clamped = 0
    for _ in range(case.steps):
        free = state.r + body.dt * state.v + 0.5 * body.dt**2 * state.a
        clamped += int((free[..., 1] < 0).sum())
        state = body.step(state)
    return case.steps, body.n_movable, clamped


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("case_name", sorted(ADJOINT_CASES))
def test_adjoint_matches_finite_differences(case_name: str, backend: str) -> None:
    case = AdjointCase(**ADJOINT_CASES[case_name], backend=backend)
    if case_name == "locomotion_clamp":
        with torch.no_grad():
            _, _, clamped = clamp_counts(case)
        assert clamped > 10, "the floor acts in this case"
    for name, param in case.parameters().items():
        err, norm = fd_relative_error(case.loss, param, coordinates=6, directions=2)
        assert norm > 1e-8 and err < TOLERANCE, (name, err, norm)


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("case_name", sorted(ADJOINT_CASES) + ["ground_clamp"])
def test_adjoint_equals_autograd(case_name: str, backend: str) -> None:
    if case_name == "ground_clamp":
        env = Environment.locomotion()
        kwargs: dict = dict(shape="caterpillar", environment=Environment(env.gravity, env.air_drag, env.ground_c,
                                                                         ground_clamp=True))
    else:
        kwargs = ADJOINT_CASES[case_name]
    case = AdjointCase(**kwargs, steps=40, backend=backend)
    if case_name == "ground_clamp":
        with torch.no_grad():
            case.displacement[..., 1] -= 0.1  # start the feet below ground so the clamp acts
    params = list(case.parameters().values())
    grads = {}
    for adjoint in (True, False):
        grads[adjoint] = torch.autograd.grad(case.loss(adjoint=adjoint, windows=2), params)
    for name, fast, slow in zip(case.parameters(), grads[True], grads[False]):
        assert float(slow.norm()) > 0, name
        torch.testing.assert_close(fast, slow, rtol=1e-9, atol=1e-12 * float(slow.abs().max()), msg=name)
