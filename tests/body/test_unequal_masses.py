"""Bodies whose masses differ (``MSDN.mass``; the paper's are all 1 kg, where a mass misplaced in a = F/m + g changes
nothing): a three-mass body under gravity, air drag, a soft ground and external forces, stepped by every path —
the numba kernel, the torch step, the torch adjoint and the lane kernel of the held-force windows — against an
independent velocity-Verlet written out below (a loop over the springs of Eq. (1), a = F/m + g), and every
path's gradient against central finite differences of that independent loop; the fused training window against
the torch autograd path on a body of unequal masses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bptsb_ros.agent import build_agent
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.held_window import population_readout
from bptsb_ros.body.msdn import MSDN, BodyState, Environment
from bptsb_ros.body.shapes import Topology
from bptsb_ros.config import validate
from bptsb_ros.tasks import get_task
from bptsb_ros.training.fused import PARAMETERS, fused_training
from bptsb_ros.training.optim import make_optimizer

F64 = torch.float64
DT, STEPS = 0.01, 40
MASSES = np.array([0.5, 2.0, 1.3])  # [kg] of the movable masses 2, 3, 4
G, DRAG, GROUND = 9.81, 0.3, 2.0
#: two fixed masses on top, three movable ones hanging below; springs in both orientations (fixed mass as i and j)
TOPOLOGY = Topology("hanging", np.array([[-1.0, 2.0], [1.0, 2.0], [-0.4, 1.4], [0.5, 1.3], [0.05, 0.8]]),
                    np.array([[0, 2], [3, 1], [2, 3], [2, 4], [4, 3], [0, 4], [4, 1]]),
                    np.array([True, True, False, False, False]), 4)
MOVABLE = [2, 3, 4]


def body_of(backend: str, integrator: str = "verlet", ground: float = GROUND) -> MSDN:
    body = MSDN(TOPOLOGY, dt=DT, integrator=integrator, environment=Environment(G, DRAG, ground), dtype=F64,
                backend=backend, generator=torch.Generator().manual_seed(5))
    body.mass.copy_(torch.as_tensor(MASSES))
    return body


# -- the independent simulation --------------------------------------------------------------------------------
def accel(k, d, r, v, rest, ext, ground=GROUND) -> np.ndarray:
    """a = F/m + g of the movable masses (3, 2): Eq. (1) spring by spring over the whole layout, drag −a·v, the
    soft ground [0, c·exp(−c·y)], the external force."""
    pos = TOPOLOGY.positions.copy()
    vel = np.zeros_like(pos)
    pos[MOVABLE], vel[MOVABLE] = r, v
    force = np.zeros_like(pos)
    for e, (i, j) in enumerate(TOPOLOGY.springs):
        x = pos[i] - pos[j]
        length = np.sqrt(x @ x)
        f = -k[e] * x / length * (length - rest[e]) - d[e] * (vel[i] - vel[j])
        force[i] += f
        force[j] -= f
    f = force[MOVABLE] - DRAG * v + ext
    f[:, 1] += ground * np.exp(-ground * r[:, 1])
    return f / MASSES[:, None] + np.array([0.0, -G])


def lengths(r) -> np.ndarray:
    pos = TOPOLOGY.positions.copy()
    pos[MOVABLE] = r
    return np.linalg.norm(pos[TOPOLOGY.springs[:, 0]] - pos[TOPOLOGY.springs[:, 1]], axis=1)


def verlet(k, d, r, v, a, rest, ext, *, published=False, ground=GROUND):
    """Steps 1..W from (r, v, a): rest (W, E), ext (W, 3, 2) in force at each step → r, v, a (W, 3, 2), lengths."""
    rs, vs, as_, ls = [], [], [], []
    for rest_t, ext_t in zip(rest, ext, strict=True):
        r = r + DT * v + (0.0 if published else 0.5 * DT * DT * a)
        a_new = accel(k, d, r, v, rest_t, ext_t, ground)
        v = v + 0.5 * DT * (a_new if published else a + a_new)
        a = a_new
        rs.append(r)
        vs.append(v)
        as_.append(a)
        ls.append(lengths(r))
    return np.array(rs), np.array(vs), np.array(as_), np.array(ls)


class Window:
    """A window of STEPS steps: SWG-like rest lengths, random forces, a displaced and moving start; the loss
    Σ w_r·r + Σ w_v·v over the window."""

    def __init__(self) -> None:
        g = np.random.default_rng(11)
        e = TOPOLOGY.n_springs
        l0 = TOPOLOGY.rest_lengths()
        t = np.arange(STEPS + 1)[:, None] * DT
        self.rest = l0 * (1 + 0.15 * np.sin(2 * np.pi * t + np.linspace(0, 3, e)))  # (W+1, E): steps 0..W
        self.ext = 0.5 * g.standard_normal((STEPS + 1, 3, 2))
        self.r0 = TOPOLOGY.positions[MOVABLE] + 0.05 * g.standard_normal((3, 2))
        self.v0 = 0.2 * g.standard_normal((3, 2))
        self.w_r, self.w_v = g.standard_normal((STEPS, 3, 2)), g.standard_normal((STEPS, 3, 2))
        self.dirs = {"k": g.standard_normal(e), "d": g.standard_normal(e), "rest": g.standard_normal((STEPS, e)),
                     "ext": g.standard_normal((STEPS, 3, 2)), "r0": g.standard_normal((3, 2))}

    def a0(self, k, d) -> np.ndarray:
        return accel(k, d, self.r0, self.v0, self.rest[0], self.ext[0])

    def loss(self, k, d, published, delta: dict | None = None) -> float:
        """The loss of the independent simulation, each input moved by ``delta[name]`` (the start's a held)."""
        delta = delta or {}
        a0 = self.a0(k, d)
        r, v, _, _ = verlet(k + delta.get("k", 0), d + delta.get("d", 0), self.r0 + delta.get("r0", 0), self.v0,
                            a0, self.rest[1:] + delta.get("rest", 0), self.ext[1:] + delta.get("ext", 0),
                            published=published)
        return float((self.w_r * r).sum() + (self.w_v * v).sum())


@pytest.fixture(scope="module")
def window() -> Window:
    return Window()


def _start(body: MSDN, win: Window, r0: torch.Tensor | None = None) -> BodyState:
    k, d = body.k.detach().numpy(), body.d.detach().numpy()
    r = torch.as_tensor(win.r0)[None] if r0 is None else r0
    return BodyState(r, torch.as_tensor(win.v0)[None], torch.as_tensor(win.a0(k, d))[None],
                     torch.as_tensor(lengths(win.r0))[None], 0)


# -- trajectories ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("integrator", ["verlet", "published"])
@pytest.mark.parametrize("backend", ["numba", "torch"])
def test_every_step_path_follows_the_independent_verlet_with_unequal_masses(window, backend, integrator):
    body = body_of(backend, integrator)
    k, d = body.k.detach().numpy(), body.d.detach().numpy()
    # the start's acceleration (MSDN.initial_state, the torch ops) is F/m + g with these masses
    init = body.initial_state(1, rest_length=torch.as_tensor(window.rest[0]),
                              external_force=torch.as_tensor(window.ext[0]),
                              displacement=torch.as_tensor(window.r0 - TOPOLOGY.positions[MOVABLE])[None],
                              velocity=torch.as_tensor(window.v0))
    np.testing.assert_allclose(init.a[0].detach().numpy(), window.a0(k, d), rtol=0, atol=1e-12)
    ref = verlet(k, d, window.r0, window.v0, window.a0(k, d), window.rest[1:], window.ext[1:],
                 published=integrator == "published")
    with torch.no_grad():  # numba: the compiled window (kernel.forward); torch: MSDN.step's torch ops
        win = rollout_window(body, _start(body, window), torch.as_tensor(window.rest[1:]),
                             torch.as_tensor(window.ext[1:]))
    for ours, theirs in zip((win.r, win.v, win.a, win.length), ref, strict=True):
        np.testing.assert_allclose(ours[:, 0].numpy(), theirs, rtol=0, atol=1e-10)
    # the masses matter: the same body with unit masses ends up elsewhere by far more than that
    with torch.no_grad():
        body.mass.fill_(1.0)
        ones = rollout_window(body, _start(body, window), torch.as_tensor(window.rest[1:]),
                              torch.as_tensor(window.ext[1:]))
    assert np.abs(ones.r[:, 0].numpy() - ref[0]).max() > 1e-3


# -- gradients -------------------------------------------------------------------------------------------------
GRADIENT_PATHS = {"numba adjoint": ("numba", True), "torch adjoint": ("torch", True), "autograd": ("torch", False)}


@pytest.mark.parametrize("integrator", ["verlet", "published"])
@pytest.mark.parametrize("path", list(GRADIENT_PATHS))
def test_every_gradient_path_matches_finite_differences_of_the_independent_verlet(window, path, integrator):
    backend, adjoint = GRADIENT_PATHS[path]
    published = integrator == "published"
    body = body_of(backend, integrator)
    k, d = body.k.detach().numpy().copy(), body.d.detach().numpy().copy()
    rest = torch.tensor(window.rest[1:], requires_grad=True)
    ext = torch.tensor(window.ext[1:], requires_grad=True)
    r0 = torch.tensor(window.r0[None], requires_grad=True)
    win = rollout_window(body, _start(body, window, r0), rest, ext, adjoint=adjoint)
    loss = (torch.as_tensor(window.w_r) * win.r[:, 0]).sum() + (torch.as_tensor(window.w_v) * win.v[:, 0]).sum()
    assert float(loss.detach()) == pytest.approx(window.loss(k, d, published), rel=1e-12)
    loss.backward()
    grads = {"k": body.k.grad, "d": body.d.grad, "rest": rest.grad, "ext": ext.grad, "r0": r0.grad[0]}
    for name, u in window.dirs.items():
        h = 1e-6
        fd = (window.loss(k, d, published, {name: h * u}) - window.loss(k, d, published, {name: -h * u})) / (2 * h)
        ours = float((grads[name].numpy() * u).sum())
        assert abs(fd) > 1e-3, name
        assert ours == pytest.approx(fd, rel=1e-6), (name, ours, fd)


# -- the lane kernel of the held-force windows -------------------------------------------------------------------
def test_the_lane_kernel_follows_the_independent_verlet_and_its_gradients_match_finite_differences():
    """Two lanes (bodies of this topology with their own k, d, l), 5 blocks of 10 steps of held forces, the y of
    mass 3 (movable row 1) read at each block's end; no ground (the lane kernel has none)."""
    body = body_of("numba", ground=0.0)
    g = np.random.default_rng(12)
    e, tau, blocks_n = TOPOLOGY.n_springs, 10, 5
    k = np.stack([body.k.detach().numpy(), 0.7 * body.k.detach().numpy()])
    d = np.stack([body.d.detach().numpy(), 1.3 * body.d.detach().numpy()])
    rest = np.stack([TOPOLOGY.rest_lengths(), 1.05 * TOPOLOGY.rest_lengths()])
    blocks = 0.5 * g.standard_normal((2, blocks_n, 3, 2))
    r0 = TOPOLOGY.positions[MOVABLE] + 0.05 * g.standard_normal((2, 3, 2))
    v0 = 0.1 * g.standard_normal((2, 3, 2))
    w_y = g.standard_normal((2, blocks_n))

    def reference(b: int, dk=0.0, dd=0.0, dl=0.0, db=0.0) -> np.ndarray:
        kb, db_, lb, fb = k[b] + dk, d[b] + dd, rest[b] + dl, blocks[b] + db
        a0 = accel(k[b], d[b], r0[b], v0[b], rest[b], blocks[b][0], 0.0)  # the start as NARMA's: block 0's force
        r, _, _, _ = verlet(kb, db_, r0[b], v0[b], a0, np.tile(lb, (blocks_n * tau, 1)),
                            np.repeat(fb, tau, axis=0), ground=0.0)
        return r[tau - 1:: tau, 1, 1]

    a0 = np.stack([accel(k[b], d[b], r0[b], v0[b], rest[b], blocks[b][0], 0.0) for b in range(2)])
    tk, td, tl, tb = (torch.tensor(x, requires_grad=True) for x in (k, d, rest, blocks))
    out = population_readout(body, torch.as_tensor(r0), torch.as_tensor(v0), torch.as_tensor(a0), tk, td, tl, tb,
                             tau, 1, 1)
    assert out.sound.all()
    for b in range(2):
        np.testing.assert_allclose(out.y[b].detach().numpy(), reference(b), rtol=0, atol=1e-10)
    (torch.as_tensor(w_y) * out.y).sum().backward()
    h = 1e-6
    for name, grad, size in (("dk", tk.grad, e), ("dd", td.grad, e), ("dl", tl.grad, e),
                             ("db", tb.grad, (blocks_n, 3, 2))):
        for b in range(2):
            u = g.standard_normal(size)
            fd = float(w_y[b] @ (reference(b, **{name: h * u}) - reference(b, **{name: -h * u}))) / (2 * h)
            ours = float((grad[b].numpy() * u).sum())
            assert abs(fd) > 1e-5, (name, b)
            assert ours == pytest.approx(fd, rel=1e-5), (name, b, ours, fd)


# -- the fused training window -------------------------------------------------------------------------------------
LOCO = {"task": "locomotion", "dtype": "float64",
        "body": {"shape": "caterpillar", "nodes": 10, "environment": "locomotion"},
        "brain": {"amplitude": 0.4}, "training": {"update_steps": 40}, "feedback": {"enabled": False},
        "locomotion": {"speed_block": 20, "warmup_windows": 2, "eval_time": 0.5}}


def _masses_task(backend: str):
    data = {**LOCO, "training": {**LOCO["training"], "backend": backend, "adjoint": backend != "torch"}}
    cfg = validate(data)
    torch.manual_seed(cfg.seed)
    agent = build_agent(cfg)
    agent.body.mass.copy_(torch.linspace(0.5, 2.0, agent.body.n_movable, dtype=F64))
    return agent, get_task(cfg.task)(agent, cfg), make_optimizer(agent, cfg.training)


def test_the_fused_window_equals_the_autograd_path_with_unequal_masses():
    agent, task, _ = _masses_task("torch")
    params = {"k": agent.body.k, "d": agent.body.d, "l": agent.body.l, "amplitude": agent.brain.amplitude,
              "phase": agent.brain.phase}
    for _ in range(2):
        for p in params.values():
            p.grad = None
        loss_ref, _ = task.update_loss(0)
        loss_ref.backward()
    fagent, ftask, opt = _masses_task("fused")
    fused, why = fused_training(ftask, opt)
    assert why is None
    for _ in range(2):
        loss, ok = fused.update_loss(0)
    assert ok and loss == pytest.approx(float(loss_ref.detach()), rel=1e-12, abs=0)
    grads = fused.fused.gradients()
    for name in PARAMETERS:
        scale = float(params[name].grad.abs().max())
        assert scale > 0, name
        assert float((grads[name] - params[name].grad).abs().max()) <= 1e-12 * scale, name
    assert torch.allclose(ftask.state.v, task.state.v, rtol=0, atol=1e-12)
