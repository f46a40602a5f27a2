"""The numba window kernel (``body/kernel.py``) against the torch path (``MSDN.step`` + the torch adjoint):
trajectories and gradients equal to 1e-12 (float64) on every body, environment and integrator; one step at
a time equals a whole window bit for bit (the live ``body_sim`` and offline simulation share it); the batch
spread over threads equals one thread bit for bit; float32 agrees to float32 rounding."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from bptsb_ros.body import kernel
from bptsb_ros.body.adjoint import rollout_window
from bptsb_ros.body.msdn import MSDN, Environment
from bptsb_ros.body.shapes import build_shape
from bptsb_ros.brains import LinearInputLayer, SineWaveGenerator
from bptsb_ros.sim.rollout import simulate_commands

F64 = torch.float64
LOCOMOTION = Environment.locomotion()
CLAMPED = replace(LOCOMOTION, ground_clamp=True)
WIND = Environment(gravity=0.0, air_drag=0.3, ground_c=0.0)  # drag without gravity: a damped double circle

BODIES = {  # name: (shape, nodes, environment)
    "double_circle_25": ("double_circle", 25, Environment()),
    "double_circle_33": ("double_circle", 33, Environment()),
    "multiple_circle_17": ("multiple_circle", 17, WIND),
    "caterpillar": ("caterpillar", 10, LOCOMOTION),
    "caterpillar_clamp": ("caterpillar", 10, CLAMPED),
}
CASES = [(b, i) for b in BODIES for i in ("verlet", "published")]


class Case:
    """A window of W steps of B bodies with everything the kernel takes: SWG rest lengths per body, LIL
    forces per body plus a shared wind, a displaced start whose displacement is trainable; the loss reads
    r, v, a and the lengths."""

    def __init__(self, body_name: str, integrator: str, backend: str, *, dtype=F64, steps: int = 60,
                 batch: int = 3) -> None:
        shape, nodes, env = BODIES[body_name]
        gen = torch.Generator().manual_seed(7)
        self.body = MSDN(build_shape(shape, nodes), dtype=dtype, generator=gen, integrator=integrator,
                         environment=env, backend=backend)
        m, e = self.body.n_movable, self.body.topology.n_springs
        self.swg = SineWaveGenerator(e, amplitude=0.3, generator=gen, dtype=dtype)
        self.lil = LinearInputLayer(1, 2 * m, generator=gen, dtype=dtype)
        self.displacement = torch.nn.Parameter(0.05 * torch.randn(batch, m, 2, generator=gen, dtype=F64).to(dtype))
        if env.ground_clamp:
            with torch.no_grad():
                self.displacement[..., 1] -= 0.05  # feet below the floor: the clamp acts
        self.u = torch.rand(steps + 1, batch, 1, generator=gen, dtype=F64).to(dtype)
        self.wind = torch.tensor([-0.5, 0.2], dtype=dtype)
        self.phase_shift = torch.linspace(0, 1, batch, dtype=dtype).view(1, batch, 1)
        self.steps, self.batch = steps, batch

    def parameters(self) -> dict[str, torch.nn.Parameter]:
        return {"k": self.body.k, "d": self.body.d, "l": self.body.l, "amplitude": self.swg.amplitude,
                "phase": self.swg.phase, "lil.weight": self.lil.weight, "displacement": self.displacement}

    def commands(self) -> tuple[torch.Tensor, torch.Tensor]:
        body = self.body
        t = torch.arange(self.steps + 1, dtype=body.l.dtype) * body.dt
        rest = self.swg.rest_length(body.l, t).unsqueeze(1) * (1 + 0.1 * self.phase_shift)  # (T+1, B, E)
        forces = 0.2 * self.lil(self.u).view(self.steps + 1, self.batch, body.n_movable, 2) + self.wind
        return rest, forces

    def window(self, windows: int = 2):
        body = self.body
        rest, forces = self.commands()
        state = body.initial_state(self.batch, rest_length=rest[0], external_force=forces[0],
                                   displacement=self.displacement)
        outs = []
        bounds = torch.linspace(0, self.steps, windows + 1).round().long().tolist()
        for lo, hi in zip(bounds[:-1], bounds[1:]):  # the state is carried with its gradient
            win = rollout_window(body, state, rest[lo + 1: hi + 1], forces[lo + 1: hi + 1])
            state = win.final
            outs.append(win)
        return outs

    def loss(self) -> torch.Tensor:
        total = torch.zeros((), dtype=self.body.l.dtype)
        for win in self.window():
            total = total + (win.r[..., 0, :] ** 2).mean() + 0.1 * (win.v**2).mean() + 1e-4 * (win.a**2).mean() \
                + ((win.length - self.body.l) ** 2).mean()
        return total


def trajectories_and_gradients(body_name: str, integrator: str, backend: str, **kw):
    case = Case(body_name, integrator, backend, **kw)
    loss = case.loss()
    grads = torch.autograd.grad(loss, list(case.parameters().values()))
    with torch.no_grad():
        wins = case.window()
    traj = {key: torch.cat([getattr(w, key) for w in wins]) for key in ("r", "v", "a", "length")}
    return traj, dict(zip(case.parameters(), grads))


def assert_rel_close(a: torch.Tensor, b: torch.Tensor, rel: float, what: str) -> None:
    scale = float(b.abs().max())
    assert scale > 0, what
    err = float((a - b).abs().max()) / scale
    assert err <= rel, f"{what}: relative difference {err:.3g} > {rel:g}"


@pytest.mark.parametrize(("body_name", "integrator"), CASES)
def test_kernel_equals_torch_float64(body_name: str, integrator: str) -> None:
    traj_t, grad_t = trajectories_and_gradients(body_name, integrator, "torch")
    traj_n, grad_n = trajectories_and_gradients(body_name, integrator, "numba")
    for key in traj_t:
        assert_rel_close(traj_n[key], traj_t[key], 1e-12, key)
    for name in grad_t:
        assert grad_n[name].shape == grad_t[name].shape, name
        assert_rel_close(grad_n[name], grad_t[name], 1e-12, f"d loss / d {name}")
    if BODIES[body_name][2].ground_clamp:  # the floor acted: some y exactly 0 after a step
        assert bool((traj_n["r"][..., 1] == 0).any())


def test_kernel_equals_torch_float32() -> None:
    traj_t, grad_t = trajectories_and_gradients("caterpillar_clamp", "verlet", "torch", dtype=torch.float32)
    traj_n, grad_n = trajectories_and_gradients("caterpillar_clamp", "verlet", "numba", dtype=torch.float32)
    assert traj_n["r"].dtype == torch.float32 and grad_n["k"].dtype == torch.float32
    for key in traj_t:
        assert_rel_close(traj_n[key], traj_t[key], 1e-4, key)
    for name in grad_t:
        assert_rel_close(grad_n[name], grad_t[name], 1e-3, f"d loss / d {name}")


def test_float32_kernel_is_not_float64() -> None:
    """The float32 kernel computes in float32 (its own compiled version), not in float64 and rounded."""
    t32, _ = trajectories_and_gradients("double_circle_25", "verlet", "numba", dtype=torch.float32)
    t64, _ = trajectories_and_gradients("double_circle_25", "verlet", "numba")
    diff = float((t32["r"].double() - t64["r"]).abs().max())
    assert 1e-9 < diff < 1e-3


@pytest.mark.parametrize("body_name", ["double_circle_25", "caterpillar_clamp"])
def test_one_step_at_a_time_equals_the_window_bit_for_bit(body_name: str) -> None:
    case = Case(body_name, "verlet", "numba", steps=120, batch=2)
    body = case.body
    with torch.no_grad():
        rest, forces = case.commands()
        roll = simulate_commands(body, case.steps, rest, forces, displacement=case.displacement)  # windows
        state = body.initial_state(2, rest_length=rest[0], external_force=forces[0], displacement=case.displacement)
        rows = []
        for i in range(1, case.steps + 1):
            state = body.step(state, rest[i], forces[i])  # what body_sim calls, one step per call
            rows.append(state.r)
    assert torch.equal(torch.stack(rows), roll.r[1:])


def test_threads_over_the_batch_equal_one_thread_bit_for_bit(monkeypatch) -> None:
    # the parallel build caches under its own name (numba's cache key ignores compile options)
    for serial, parallel in ((kernel._forward_serial, kernel._forward_parallel),
                             (kernel._adjoint_serial, kernel._adjoint_parallel)):
        assert parallel.targetoptions.get("parallel") and not serial.targetoptions.get("parallel")
        assert parallel.py_func.__qualname__ != serial.py_func.__qualname__
    case = Case("caterpillar_clamp", "verlet", "numba", steps=40, batch=19)
    results = []
    for threshold in (10**9, 1):  # serial build, then the parallel one
        monkeypatch.setattr(kernel, "PARALLEL_MIN_BATCH", threshold)
        loss = case.loss()
        grads = torch.autograd.grad(loss, list(case.parameters().values()))
        results.append((loss.detach(), grads))
    assert torch.equal(results[0][0], results[1][0])
    for a, b in zip(results[0][1], results[1][1]):
        assert torch.equal(a, b)


@pytest.mark.slow
def test_a_parallel_kernel_leaves_torch_on_its_thread_count() -> None:
    """numba's OpenMP layer shares torch's libgomp: the first parallel region of a process used to leave torch on
    numba's thread count (a one-thread pool worker then ran torch on every core). A fresh process, forward and
    adjoint of a batch the parallel build takes."""
    import subprocess
    import sys

    import numba

    if numba.get_num_threads() < 2:
        pytest.skip("one numba thread: a parallel region cannot change the team size")
    script = (
        "import torch\n"
        "torch.set_num_threads(1)\n"
        "from bptsb_ros.body import kernel\n"
        "from bptsb_ros.body.msdn import MSDN\n"
        "from bptsb_ros.body.shapes import double_circle\n"
        "from bptsb_ros.body.adjoint import rollout_window\n"
        "kernel.PARALLEL_MIN_BATCH = 8\n"
        "body = MSDN(double_circle(13), dt=0.01, dtype=torch.float64, backend='numba')\n"
        "win = rollout_window(body, body.initial_state(300), body.l.expand(4, -1), None)\n"
        "after_forward = torch.get_num_threads()\n"
        "win.r.sum().backward()\n"
        "print(after_forward, torch.get_num_threads(), body.k.grad is not None)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.split() == ["1", "1", "True"], out.stdout + out.stderr


def test_kernel_path_is_taken() -> None:
    """The numba body does not fall back to torch ops where the kernel applies (and does where it must)."""
    case = Case("double_circle_25", "verlet", "numba")
    body = case.body
    state = body.initial_state(1)
    assert body.uses_kernel(state.r) is False  # k, d require grad: a tape is wanted
    with torch.no_grad():
        assert body.uses_kernel(state.r) is True
    win = rollout_window(body, state, body.l.expand(3, -1))
    assert type(win.r.grad_fn).__name__ == "_KernelWindowFunctionBackward"
    body.backend = "torch"
    with torch.no_grad():
        assert body.uses_kernel(state.r) is False


def test_bad_backend_is_rejected() -> None:
    with pytest.raises(ValueError, match="backend"):
        MSDN(build_shape("double_circle", 25), backend="jax")


def test_state_batch_broadcasts_like_torch() -> None:
    """One start state with per-body forces: both backends broadcast the state over the forces' batch."""
    out = {}
    for backend in ("torch", "numba"):
        case = Case("double_circle_25", "verlet", backend, steps=5, batch=3)
        body = case.body
        with torch.no_grad():
            rest, forces = case.commands()
            state = body.initial_state(1)
            for i in range(1, 4):
                state = body.step(state, rest[i, 0], forces[i])
        out[backend] = state.r
    assert out["numba"].shape == (3, case.body.n_movable, 2)
    assert_rel_close(out["numba"], out["torch"], 1e-12, "r")
    with pytest.raises(ValueError, match="batch"):
        with torch.no_grad():
            body.kernel_window(state.r, state.v, state.a, rest[1:3, :2], None)


def test_a_spring_of_zero_length_gives_nan_in_both_backends_not_an_exception() -> None:
    """Two masses on one point (it happened to a caterpillar at paper scale): k (L − l) / L divides by zero. Torch
    gives NaN, which the divergence checks report; the kernel must do the same, not raise ZeroDivisionError."""
    out = {}
    for backend in ("torch", "numba"):
        body = MSDN(build_shape("double_circle", 25), backend=backend, dtype=torch.float64)
        with torch.no_grad():
            state = body.initial_state(1)
            i, j = (int(x) for x in body.topology.springs[0])  # put one end of spring 0 onto the other
            full = body.full_positions(state.r)[0]
            movable = body.movable_index.tolist()
            moved, onto = (i, j) if i in movable else (j, i)
            state.r[0, movable.index(moved)] = full[onto]
            out[backend] = body.step(state, body.l)
    for backend, new in out.items():
        assert bool(torch.isnan(new.a).any()), backend
        assert float(new.length[0, 0]) == 0.0, backend
