"""Physics of the MSDN step: energy, momenta, invariances, fixed masses, clamping, integrators, divergence."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bptsb_ros.body.msdn import MSDN, BodyState, Environment, SimulationDiverged
from bptsb_ros.body.shapes import Topology, build_shape

F64 = torch.float64


def make_body(shape: str = "double_circle", nodes: int = 25, *, seed: int = 0, dt: float = 0.01,
              damping: bool = True, **kwargs) -> MSDN:
    body = MSDN(build_shape(shape, nodes), dt=dt, dtype=F64, generator=torch.Generator().manual_seed(seed), **kwargs)
    if not damping:
        with torch.no_grad():
            body.d.zero_()
    return body


def randn(*shape: int, seed: int, scale: float = 1.0) -> torch.Tensor:
    return scale * torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=F64)


def total_energy(body: MSDN, state: BodyState) -> torch.Tensor:
    """(B,) kinetic + spring potential energy Σ ½k(L − l)² [J]."""
    kinetic = 0.5 * (body.mass.unsqueeze(-1) * state.v**2).sum((-2, -1))
    return kinetic + 0.5 * (body.k * (state.length - body.l) ** 2).sum(-1)


def energy_error(dt: float, seconds: float, batch: int = 3) -> torch.Tensor:
    """(T+1, B) relative energy error |E(t) − E(0)|/E(0) of undamped, perturbed double-circle bodies."""
    body = make_body(dt=dt, damping=False)
    with torch.no_grad():
        state = body.initial_state(batch, displacement=randn(batch, body.n_movable, 2, seed=1, scale=0.1))
        e0 = total_energy(body, state)
        errors = [torch.zeros_like(e0)]
        for _ in range(int(round(seconds / dt))):
            state = body.step(state)
            errors.append((total_energy(body, state) - e0).abs() / e0)
    return torch.stack(errors)


def test_energy_drift_is_bounded_over_long_runs() -> None:
    err = energy_error(0.01, 100.0)  # 10,000 steps, tens to hundreds of periods of the body's modes
    quarter = err.shape[0] // 4
    first, last = err[:quarter].max(0).values, err[-quarter:].max(0).values
    assert float(err.max()) < 1e-2  # measured 3.3e-3–5.5e-3 (k up to 100 N/m, dt = 0.01 s)
    assert bool((first > 1e-4).all())  # the bodies do oscillate, so the check is not vacuous
    # A symplectic integrator oscillates around the true energy: no secular growth (measured last/first 0.67–1.03).
    assert bool((last < 1.5 * first).all()), (first, last)


def test_energy_error_is_second_order_in_dt() -> None:
    coarse = energy_error(0.01, 10.0).max(0).values
    fine = energy_error(0.005, 10.0).max(0).values
    ratio = coarse / fine
    assert bool(((ratio > 3.5) & (ratio < 4.5)).all()), ratio  # measured 3.98–4.00


def free_caterpillar(damping: bool, seed: int = 3) -> tuple[MSDN, BodyState]:
    """A caterpillar without environment, perturbed and moving (net momentum and spin non-zero)."""
    body = make_body("caterpillar", 10, seed=seed, damping=damping)
    m = body.n_movable
    velocity = randn(1, m, 2, seed=seed + 1) + torch.tensor([0.7, -0.3], dtype=F64)
    with torch.no_grad():
        state = body.initial_state(1, displacement=randn(1, m, 2, seed=seed + 2, scale=0.2), velocity=velocity)
    return body, state


def momenta(body: MSDN, state: BodyState) -> tuple[torch.Tensor, torch.Tensor]:
    p = (body.mass.unsqueeze(-1) * state.v).sum(-2)  # (B, 2)
    r, v = state.r, state.v
    ang = (body.mass * (r[..., 0] * v[..., 1] - r[..., 1] * v[..., 0])).sum(-1)  # (B,)
    return p, ang


@pytest.mark.parametrize("integrator", ["verlet", "published"])
def test_free_body_conserves_momentum_even_with_damping(integrator: str) -> None:
    body, state = free_caterpillar(damping=True)
    body.integrator = integrator
    p0, _ = momenta(body, state)
    moved = 0.0
    with torch.no_grad():
        r0 = state.r.clone()
        for _ in range(2000):
            state = body.step(state)
        moved = float((state.r - r0).abs().max())
    p, _ = momenta(body, state)
    assert moved > 1.0
    assert float((p - p0).abs().max()) < 1e-12, (p, p0)


def test_undamped_free_body_conserves_angular_momentum() -> None:
    body, state = free_caterpillar(damping=False)
    _, l0 = momenta(body, state)
    with torch.no_grad():
        for _ in range(2000):
            state = body.step(state)
    _, ang = momenta(body, state)
    assert abs(float(l0)) > 0.5
    assert float((ang - l0).abs().max()) < 1e-11, (ang, l0)  # measured 1.5e-13


def test_damping_on_relative_velocity_does_change_angular_momentum() -> None:
    # Damping acts on v_i − v_j, not along the spring, so it exerts torque: the conservation above is not a given.
    body, state = free_caterpillar(damping=True)
    _, l0 = momenta(body, state)
    with torch.no_grad():
        for _ in range(500):
            state = body.step(state)
    assert float((momenta(body, state)[1] - l0).abs().max()) > 1e-3


def test_fixed_masses_stay_put() -> None:
    body = make_body("double_circle", 33, seed=5)
    topo = body.topology
    m, e = body.n_movable, topo.n_springs
    phase = randn(e, seed=6)
    with torch.no_grad():
        state = body.initial_state(2, displacement=randn(2, m, 2, seed=7, scale=0.2))
        for t in range(1, 501):
            rest = body.l * (1 + 0.4 * torch.sin(2 * math.pi * t * body.dt + phase))
            state = body.step(state, rest_length=rest, external_force=randn(2, m, 2, seed=t, scale=5.0))
        full = body.full_positions(state.r)
    pos0 = torch.tensor(topo.positions, dtype=F64)
    assert torch.equal(full[:, topo.fixed], pos0[topo.fixed].expand(2, -1, -1))
    assert float((full[:, ~topo.fixed] - pos0[~topo.fixed]).abs().max()) > 0.05


def rotation(theta: float) -> np.ndarray:
    return np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])


@pytest.mark.parametrize("shape,nodes", [("double_circle", 25), ("caterpillar", 10)])
def test_forces_are_translation_and_rotation_invariant(shape: str, nodes: int) -> None:
    base = build_shape(shape, nodes)
    rot = rotation(0.83)
    shift = np.array([3.0, -1.5])
    bodies = {}
    for name, positions in (("base", base.positions), ("rotated", base.positions @ rot.T),
                            ("shifted", base.positions + shift)):
        topo = Topology(base.name, positions, base.springs, base.fixed, base.cmp_index)
        bodies[name] = MSDN(topo, dtype=F64, generator=torch.Generator().manual_seed(11))
    m = bodies["base"].n_movable
    movable0 = torch.tensor(base.positions[base.movable], dtype=F64)
    r = movable0 + randn(2, m, 2, seed=12, scale=0.3)
    v = randn(2, m, 2, seed=13)
    f = randn(2, m, 2, seed=14)
    rest = bodies["base"].l * 1.1
    rot_t = torch.tensor(rot, dtype=F64)
    with torch.no_grad():
        a, length = bodies["base"].acceleration(r, v, rest, f)
        a_rot, length_rot = bodies["rotated"].acceleration(r @ rot_t.T, v @ rot_t.T, rest, f @ rot_t.T)
        a_shift, length_shift = bodies["shifted"].acceleration(r + torch.tensor(shift), v, rest, f)
    assert float(a.abs().max()) > 1.0
    torch.testing.assert_close(a_rot, a @ rot_t.T, rtol=0, atol=1e-10)
    torch.testing.assert_close(length_rot, length, rtol=0, atol=1e-12)
    torch.testing.assert_close(a_shift, a, rtol=0, atol=1e-10)
    torch.testing.assert_close(length_shift, length, rtol=0, atol=1e-12)


def test_clamp_parameters_keeps_k_d_l_non_negative() -> None:
    body = make_body()
    with torch.no_grad():
        for p in (body.k, body.d, body.l):
            p[::3] = -p[::3] - 0.5
    before = {n: getattr(body, n).detach().clone() for n in ("k", "d", "l")}
    body.clamp_parameters_()
    for name, old in before.items():
        new = getattr(body, name).detach()
        assert bool((new >= 0).all()), name
        assert bool((new[old < 0] == 0).all()), name
        assert torch.equal(new[old >= 0], old[old >= 0]), name
    assert all(getattr(body, n).requires_grad for n in ("k", "d", "l"))


def test_reset_projection_sets_negative_k_d_l_to_0_1_and_keeps_the_rest() -> None:
    body = make_body()
    planted = {"k": [-2.0, 0.0, 3.5, -1e-9], "d": [0.2, -0.3, float("nan"), 1.0], "l": [-5.0, 0.7, 0.05, 2.0]}
    expected = {"clamp": {"k": [0.0, 0.0, 3.5, 0.0], "d": [0.2, 0.0, float("nan"), 1.0], "l": [0.0, 0.7, 0.05, 2.0]},
                "reset": {"k": [0.1, 0.0, 3.5, 0.1], "d": [0.2, 0.1, float("nan"), 1.0], "l": [0.1, 0.7, 0.05, 2.0]}}
    for projection, want in expected.items():
        with torch.no_grad():
            for name, vals in planted.items():
                getattr(body, name)[:4] = torch.tensor(vals, dtype=body.k.dtype)
                getattr(body, name)[4:] = 1.25
        body.clamp_parameters_(projection)
        for name, vals in want.items():
            got = getattr(body, name).detach()
            torch.testing.assert_close(got[:4], torch.tensor(vals, dtype=got.dtype), equal_nan=True, rtol=0, atol=0)
            assert bool((got[4:] == 1.25).all()), (projection, name)
    with pytest.raises(ValueError, match="projection must be one of clamp, reset, got 'zero'"):
        body.clamp_parameters_("zero")


def reference_force(body: MSDN, r: torch.Tensor, v: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
    """Eq. (1) summed spring by spring over all masses (fixed ones at their layout), plus the environment."""
    topo = body.topology
    full_r = body.full_positions(r)
    full_v = torch.zeros_like(full_r)
    full_v[:, body.movable_index] = v
    force = torch.zeros_like(full_r)
    for e, (i, j) in enumerate(topo.springs.tolist()):
        delta = full_r[:, i] - full_r[:, j]
        dist = delta.norm(dim=-1, keepdim=True)
        f_ij = -body.k[e] * delta / dist * (dist - rest[e]) - body.d[e] * (full_v[:, i] - full_v[:, j])
        force[:, i] += f_ij
        force[:, j] -= f_ij
    env = body.environment
    force = force[:, body.movable_index]
    force[..., 1] += -env.gravity + env.ground_c * torch.exp(-env.ground_c * r[..., 1])
    return force - env.air_drag * v


@pytest.mark.parametrize("integrator", ["verlet", "published"])
def test_one_step_matches_the_documented_update(integrator: str) -> None:
    body = make_body("caterpillar", 10, seed=21, environment=Environment.locomotion(), integrator=integrator)
    m, dt = body.n_movable, body.dt
    r0 = torch.tensor(body.topology.positions, dtype=F64) + randn(1, m, 2, seed=22, scale=0.1)
    v0 = randn(1, m, 2, seed=23)
    a0 = randn(1, m, 2, seed=24, scale=3.0)  # a stale a(t): the published update must ignore it
    rest = body.l * (1 + 0.2 * randn(body.topology.n_springs, seed=25))
    f = randn(1, m, 2, seed=26)
    with torch.no_grad():
        state = body.step(BodyState(r0, v0, a0, torch.zeros(1, body.topology.n_springs, dtype=F64), 7),
                          rest_length=rest, external_force=f)
        if integrator == "verlet":
            r1 = r0 + v0 * dt + 0.5 * a0 * dt**2
        else:
            r1 = r0 + v0 * dt
        a1 = reference_force(body, r1, v0, rest) + f  # masses are 1
        v1 = v0 + 0.5 * dt * (a0 + a1) if integrator == "verlet" else v0 + 0.5 * dt * a1
    assert state.step == 8
    torch.testing.assert_close(state.r, r1, rtol=0, atol=1e-13)
    torch.testing.assert_close(state.a, a1, rtol=0, atol=1e-10)
    torch.testing.assert_close(state.v, v1, rtol=0, atol=1e-12)


def test_initial_acceleration_uses_initial_rest_length_and_force() -> None:
    body = make_body(seed=31)
    rest = body.l * 1.2
    f = randn(body.n_movable, 2, seed=32)
    with torch.no_grad():
        state = body.initial_state(1, rest_length=rest, external_force=f)
        expected = reference_force(body, state.r, state.v, rest) + f
    torch.testing.assert_close(state.a, expected, rtol=0, atol=1e-10)


def test_ground_clamp_puts_sunk_masses_on_the_floor_before_the_forces() -> None:
    env = Environment.locomotion()
    clamped = make_body("caterpillar", 10, seed=41, environment=Environment(env.gravity, env.air_drag, env.ground_c,
                                                                            ground_clamp=True))
    free = make_body("caterpillar", 10, seed=41, environment=env)
    m = clamped.n_movable
    velocity = torch.zeros(1, m, 2, dtype=F64)
    velocity[0, 1::2, 1] = -2.0  # feet (odd masses, on y = 0) pushed into the ground
    velocity[0, :, 0] = 0.5
    with torch.no_grad():
        s0 = clamped.initial_state(1, velocity=velocity)
        sc = clamped.step(s0)
        sf = free.step(free.initial_state(1, velocity=velocity))
    sunk = sf.r[0, :, 1] < 0
    assert int(sunk.sum()) == 5  # the soft ground alone lets the feet sink (the paper)
    assert bool((sc.r[0, :, 1] >= 0).all())
    assert bool((sc.r[0, sunk, 1] == 0).all())
    torch.testing.assert_close(sc.r[0, sunk, 0], sf.r[0, sunk, 0], rtol=0, atol=0)  # x is kept
    torch.testing.assert_close(sc.r[0, ~sunk], sf.r[0, ~sunk], rtol=0, atol=0)
    # The forces saw the clamped state, v(t) = 0 included: a sunk mass ends with v = Δt/2·(a(t) + a(t+Δt)).
    with torch.no_grad():
        v_seen = velocity.masked_fill(sunk.view(1, m, 1), 0.0)
        a_expected = reference_force(clamped, sc.r, v_seen, clamped.l)
    torch.testing.assert_close(sc.a, a_expected, rtol=0, atol=1e-10)
    torch.testing.assert_close(sc.v[0, sunk], 0.5 * clamped.dt * (s0.a[0, sunk] + sc.a[0, sunk]), rtol=0, atol=1e-15)
    assert bool((sc.v[0, sunk].abs() > 1e-3).all())  # not zeroed after the velocity update


def one_mass_on_a_slack_spring(integrator: str, height: float, backend: str = "numba") -> MSDN:
    """A movable mass at (0, height) tied to a fixed anchor at (0, 5) by a spring with k = d = 0: the only
    forces are gravity 10 m/s² (−y) and air drag −0.1·v; dt = 0.1 s; the hard floor on."""
    topology = Topology("hand", np.array([[0.0, 5.0], [0.0, height]]), np.array([[0, 1]]), np.array([True, False]), -1)
    body = MSDN(topology, dt=0.1, integrator=integrator, dtype=F64, backend=backend,
                environment=Environment(gravity=10.0, air_drag=0.1, ground_c=0.0, ground_clamp=True))
    with torch.no_grad():
        body.k.zero_()
        body.d.zero_()
    return body


# Worked by hand, v(0) = (1, 0), a = (−0.1·v_x, −10 − 0.1·v_y) away from the floor.
#   published, y(0) = 0.03: r1 = r0 + v0·dt = (0.1, 0.03); a1 = (−0.1, −10); v1 = v0 + a1·dt/2 = (0.995, −0.5);
#     r2 = r1 + v1·dt = (0.1995, −0.02) → clamp: r2 = (0.1995, 0), v(t) = 0; a2 = (0, −10) (no drag at v = 0);
#     v2 = 0 + a2·dt/2 = (0, −0.5).   [clamp after the update: a2 = (−0.0995, −9.95), v2 = (0, 0)]
#   verlet, y(0) = 0.08: a0 = (−0.1, −10); r1 = r0 + v0·dt + a0·dt²/2 = (0.0995, 0.03); a1 = (−0.1, −10);
#     v1 = v0 + (a0 + a1)·dt/2 = (0.99, −1.0); r2 = r1 + v1·dt + a1·dt²/2 = (0.198, −0.12) → clamp:
#     r2 = (0.198, 0), v(t) = 0; a2 = (0, −10); v2 = 0 + (a1 + a2)·dt/2 = (−0.005, −1.0).
HAND_TWO_STEPS = {
    "published": (0.03, [[0.1, 0.03], [0.1995, 0.0]], [[0.995, -0.5], [0.0, -0.5]], [[-0.1, -10.0], [0.0, -10.0]]),
    "verlet": (0.08, [[0.0995, 0.03], [0.198, 0.0]], [[0.99, -1.0], [-0.005, -1.0]], [[-0.1, -10.0], [0.0, -10.0]]),
}


@pytest.mark.parametrize("backend", ["numba", "torch"])
@pytest.mark.parametrize("integrator", sorted(HAND_TWO_STEPS))
def test_ground_clamp_order_on_a_hand_computed_two_step_example(integrator: str, backend: str) -> None:
    height, r_hand, v_hand, a_hand = HAND_TWO_STEPS[integrator]
    body = one_mass_on_a_slack_spring(integrator, height, backend)
    with torch.no_grad():
        state = body.initial_state(1, velocity=torch.tensor([[[1.0, 0.0]]], dtype=F64))
        states = [state := body.step(state) for _ in range(2)]
    for t, s in enumerate(states):
        torch.testing.assert_close(s.r[0, 0], torch.tensor(r_hand[t], dtype=F64), rtol=0, atol=1e-14)
        torch.testing.assert_close(s.v[0, 0], torch.tensor(v_hand[t], dtype=F64), rtol=0, atol=1e-14)
        torch.testing.assert_close(s.a[0, 0], torch.tensor(a_hand[t], dtype=F64), rtol=0, atol=1e-14)


# d(r2, v2)/d v0 by hand (rows: r2x, r2y, v2x, v2y; columns: v0x, v0y). Everything is linear in v0 here.
#   published: r2x = v0x·dt + v1x·dt, v1x = v0x(1 − 0.05·0.1) → 0.1 + 0.0995 = 0.1995; r2y = 0 (clamped);
#     v2 = a2·dt/2 with a2 at v = 0: no dependence.
#   verlet: r1x = v0x(0.1 − 0.0005) = 0.0995 v0x; v1x = v0x(1 − 0.05·0.2) = 0.99 v0x; a1x = −0.1 v0x;
#     r2x = 0.0995 + 0.099 − 0.0005 = 0.198; r2y = 0; v2 = (a1 + a2)·dt/2 → ∂v2x/∂v0x = ∂v2y/∂v0y = −0.005.
HAND_JACOBIAN = {
    "published": [[0.1995, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]],
    "verlet": [[0.198, 0.0], [0.0, 0.0], [-0.005, 0.0], [0.0, -0.005]],
}


@pytest.mark.parametrize(("backend", "adjoint"), [("numba", True), ("torch", True), ("torch", False)],
                         ids=["numba-adjoint", "torch-adjoint", "autograd"])
@pytest.mark.parametrize("integrator", sorted(HAND_JACOBIAN))
def test_gradient_through_the_clamp_on_the_hand_example(integrator: str, backend: str, adjoint: bool) -> None:
    from bptsb_ros.body.adjoint import rollout_window

    height = HAND_TWO_STEPS[integrator][0]
    body = one_mass_on_a_slack_spring(integrator, height, backend)
    v0 = torch.tensor([[[1.0, 0.0]]], dtype=F64, requires_grad=True)
    rows = []
    for out in range(4):
        win = rollout_window(body, body.initial_state(1, velocity=v0), body.l.detach().expand(2, -1), adjoint=adjoint)
        final = torch.cat([win.final.r[0, 0], win.final.v[0, 0]])
        rows.append(torch.autograd.grad(final[out], v0)[0].view(2))
    torch.testing.assert_close(torch.stack(rows), torch.tensor(HAND_JACOBIAN[integrator], dtype=F64),
                               rtol=0, atol=1e-14)


def test_blow_up_raises_with_the_step_and_parameters() -> None:
    body = make_body(seed=51)
    with torch.no_grad():
        body.k.mul_(1e4)  # ω·dt ≈ 60 ≫ 2: velocity Verlet is unstable
        state = body.initial_state(1, displacement=randn(1, body.n_movable, 2, seed=52, scale=0.01))
        with pytest.raises(SimulationDiverged, match=r"diverged at step \d+ .*k in \[") as info:
            for _ in range(500):
                state = body.step(state)
                body.check_finite(state)
    step = int(str(info.value).split("step ")[1].split()[0])
    assert 1 <= step < 500


def test_nan_raises_with_the_step() -> None:
    body = make_body(seed=53)
    rest = body.l.detach().clone()
    with torch.no_grad():
        state = body.initial_state(1, displacement=randn(1, body.n_movable, 2, seed=54, scale=0.05))
        for _ in range(4):
            state = body.step(state)
            body.check_finite(state)
        rest[3] = float("nan")
        with pytest.raises(SimulationDiverged, match=r"diverged at step (5|6) "):
            for _ in range(5, 10):
                state = body.step(state, rest_length=rest)
                body.check_finite(state)


def test_bad_body_options_are_rejected() -> None:
    with pytest.raises(ValueError, match="integrator"):
        make_body(integrator="euler")
    with pytest.raises(ValueError, match="dt"):
        make_body(dt=0.0)
