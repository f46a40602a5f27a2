"""A window of held external forces, read at the block ends, as one autograd node (the NARMA and memory
tasks' episode under ``training.backend: fused``).

The time-series tasks hold each input for τ steps and read one coordinate of one mass at the end of every
block. Through :func:`~bptsb_ros.body.adjoint.rollout_window` that episode is the whole trajectory
(W, 1, M, 2) three times over, a (W + 1, M, 2) force tensor from the brain, and their autograd graph: at
W = 3,000 steps most of an update went to torch's work on those tensors rather than to the kernel. Here the
brain's forces come per block, (K, M, 2); the window is one numba forward and one adjoint on numpy arrays
(``body/kernel.py``, the numba path's own kernels); the only tensor out is the read coordinate at the K block
ends. The same equations in the same order: outputs and every gradient equal the ``rollout_window`` path to
rounding (tests/body/test_held_window.py checks 1e-12 in float64).

Lanes: independent trainings of one topology run as threads of a gang (``bptsb_ros/jobs/gang.py``) hand their windows
to a :class:`LaneRunner` (:func:`as_lanes`), which runs the windows of every waiting thread as one call of
``body/held_window_kernel.py``, one lane each. A lane's output, final state and gradients are the solo path's
bit for bit (tests/jobs/test_gang.py).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from bptsb_ros.body.msdn import _NUMPY, MSDN, BodyState, _as_numpy


@dataclass
class WindowLane:
    """One body's held-force window, as numpy arrays in the body's dtype (``held_window_kernel``'s shapes for
    one lane: r0, v0, a0 (M, 2); k, d, l (E,); blocks (K, M, 2)); windows of equal ``key`` can share a call (the
    same topology, masses, scalars, K, τ and read coordinate)."""

    key: tuple
    r0: np.ndarray
    v0: np.ndarray
    a0: np.ndarray
    k: np.ndarray
    d: np.ndarray
    l: np.ndarray  # noqa: E741 - the paper's symbol for the rest lengths
    blocks: np.ndarray
    body: MSDN
    tau: int
    row: int
    coord: int


class LaneRunner(Protocol):
    """Runs the held-force windows of many threads together (``bptsb_ros.jobs.gang.Gang`` is one)."""

    def forward(self, lane: WindowLane) -> tuple[np.ndarray, tuple[np.ndarray, ...], Any]:
        """``(y (K,), end (r, v, a (M, 2), lengths (E,)), handle)`` once the lane has run."""

    def backward(self, handle: Any, g_y: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(lam_r, lam_v, lam_a (M, 2), g_k, g_d, g_l (E,), g_blocks (K, M, 2))`` of the lane ``handle``
        names, for the gradient ``g_y`` (K,) of its output."""


_local = threading.local()


@contextmanager
def as_lanes(runner: LaneRunner) -> Iterator[None]:
    """Within the block, this thread's held-force windows run as lanes of ``runner``."""
    _local.runner = runner
    try:
        yield
    finally:
        _local.runner = None


def _lane_runner() -> LaneRunner | None:
    return getattr(_local, "runner", None)


@dataclass
class LaneGroup:
    """Windows of one key run together: their stacked inputs and the block-start states the adjoint needs."""

    lanes: list[WindowLane]
    stacked: tuple[np.ndarray, ...]  # k, d, l (E, P), blocks (K, M, 2, P)
    saved: tuple[np.ndarray, ...]


def run_lanes_forward(lanes: Sequence[WindowLane]) -> tuple[LaneGroup, list[tuple[np.ndarray, tuple]]]:
    """Run windows of one key as one kernel call; each lane's ``(y (K,), end (r, v, a, lengths))`` in order."""
    from bptsb_ros.body import held_window_kernel

    first = lanes[0]
    body = first.body

    def stack(name: str) -> np.ndarray:
        return np.ascontiguousarray(np.stack([getattr(x, name) for x in lanes], axis=-1))

    r0, v0, a0, k, d, l, blocks = (stack(n) for n in ("r0", "v0", "a0", "k", "d", "l", "blocks"))
    _, _, offset, mass, coef = body.kernel_constants(body.k.dtype)
    y, saved, end = held_window_kernel.forward(r0, v0, a0, k, d, l, blocks, first.tau, first.row, first.coord,
                                               body.spring_i, body.spring_j, offset, mass, coef,
                                               body.integrator == "verlet")
    outs = [(y[:, p].copy(), tuple(x[..., p].copy() for x in end)) for p in range(len(lanes))]
    return LaneGroup(list(lanes), (k, d, l, blocks), saved), outs


def run_lanes_backward(group: LaneGroup, g_y: dict[int, np.ndarray]) -> dict[int, tuple[np.ndarray, ...]]:
    """The adjoint of ``group`` for the lanes in ``g_y`` (lane → (K,) gradient of its output; the other lanes'
    is zero): lane → ``(lam_r, lam_v, lam_a, g_k, g_d, g_l, g_blocks)``."""
    from bptsb_ros.body import held_window_kernel

    first = group.lanes[0]
    body = first.body
    k, d, l, blocks = group.stacked
    g = np.zeros((blocks.shape[0], len(group.lanes)), dtype=k.dtype)
    for p, gp in g_y.items():
        g[:, p] = gp
    _, _, offset, mass, coef = body.kernel_constants(body.k.dtype)
    lam, grads, g_blocks = held_window_kernel.adjoint(
        k, d, l, blocks, first.tau, first.row, first.coord, body.spring_i, body.spring_j, offset, mass, coef,
        body.integrator == "verlet", group.saved, g)
    return {p: (*(x[..., p].copy() for x in (*lam, *grads)), g_blocks[..., p].copy()) for p in g_y}


def held_window_unsupported(body: MSDN, *, adjoint: bool = True) -> str | None:
    """Why :func:`held_force_readout` cannot run ``body`` (one phrase), or None when it can."""
    if not adjoint:
        return "training.adjoint is false (plain autograd was asked for)"
    if body.k.device.type != "cpu":
        return "it runs on CPU"
    if body.k.dtype not in _NUMPY:
        return f"it runs in float32 or float64, not {body.k.dtype}"
    return None


def held_force_readout(body: MSDN, state: BodyState, block_forces: torch.Tensor, tau: int, row: int,
                       coord: int) -> torch.Tensor:
    """Coordinate ``coord`` (0: x, 1: y) of movable mass ``row`` at the end of each of K blocks of ``tau`` steps.

    Args:
        body: the body; its k, d and l (the rest lengths, constant over the window) receive gradients.
        state: the start state, batch 1 (its r, v, a may carry gradients, e.g. from the brain's first force).
        block_forces: (K, M, 2) external force [N] of each block: block j's is in force at steps
            jτ + 1 .. (j + 1)τ after ``state``.
        tau: steps per block (τ ≥ 1).
        row: the read mass, its index among the movable masses.
        coord: the read coordinate (0: x, 1: y).

    Returns:
        (K,) the position [m] after steps τ, 2τ, …, Kτ; differentiable w.r.t. ``state``, k, d, l and
        ``block_forces``.

    Raises:
        SimulationDiverged: the final state is non-finite or beyond ``MSDN.check_finite``'s limit.
    """
    why = held_window_unsupported(body)
    if why:
        raise ValueError(f"held_force_readout: {why}")
    if tau < 1:
        raise ValueError(f"tau must be >= 1, got {tau}")
    if state.r.shape[0] != 1:
        raise ValueError(f"held_force_readout runs one body, the state has batch {state.r.shape[0]}")
    m = body.n_movable
    if block_forces.dim() != 3 or tuple(block_forces.shape[1:]) != (m, 2) or block_forces.shape[0] < 1:
        raise ValueError(f"block_forces must be (K >= 1, {m}, 2), got {tuple(block_forces.shape)}")
    if not (0 <= row < m and coord in (0, 1)):
        raise ValueError(f"no movable mass {row}, coordinate {coord} to read (M = {m})")
    return _HeldForceWindow.apply(state.r, state.v, state.a, body.k, body.d, body.l, block_forces, body, int(tau),
                                  int(row), int(coord), int(state.step))


_SECOND_BACKWARD = ("held_force_readout: backward through the same window a second time (its trajectory was freed "
                    "after the first); run the window again")


def lanes_unsupported(body: MSDN) -> str | None:
    """Why ``body``'s windows cannot run as lanes (``body/held_window_kernel.py`` has no ground), or None."""
    env = body.environment
    if env.ground_clamp or float(env.ground_c) != 0.0:
        return "the lane kernel has no ground"
    return None


def _lane_key(body: MSDN, n_blocks: int, tau: int, row: int, coord: int) -> tuple:
    """Equal for windows that can share one lane-kernel call: topology, masses, fixed offsets and scalars (the
    body's part computed once per body and dtype: none of it changes in training)."""
    cached = body.__dict__.get("_lane_key_base")
    if cached is None or cached[0] != body.k.dtype:
        _, _, offset, mass, coef = body.kernel_constants(body.k.dtype)
        cached = (body.k.dtype, (str(body.k.dtype), body.integrator, body.spring_i.tobytes(), body.spring_j.tobytes(),
                                 offset.tobytes(), mass.tobytes(), coef.tobytes()))
        body.__dict__["_lane_key_base"] = cached
    return (*cached[1], n_blocks, tau, row, coord)


class _HeldForceWindow(torch.autograd.Function):
    """Forward: ``kernel.forward`` over the K·τ steps; backward: ``kernel.adjoint`` with the readout's gradient
    on the read rows, then the rest lengths' gradient summed over the steps and the forces' over each block. In a
    thread with a :class:`LaneRunner` (and a body without ground) both go to the runner as one lane instead."""

    @staticmethod
    def forward(ctx, r0, v0, a0, k, d, l, block_forces, body: MSDN, tau: int, row: int, coord: int,
                step: int):  # type: ignore[override]
        from bptsb_ros.body import kernel

        dtype = r0.dtype
        runner = _lane_runner()
        if runner is not None and lanes_unsupported(body) is None:
            lane = WindowLane(_lane_key(body, block_forces.shape[0], tau, row, coord),
                              *(_as_numpy(x, dtype)[0] for x in (r0, v0, a0)),
                              *(_as_numpy(x, dtype) for x in (k, d, l, block_forces)), body, tau, row, coord)
            y, end, handle = runner.forward(lane)
            final = BodyState(*(torch.from_numpy(x).unsqueeze(0) for x in end), step + block_forces.shape[0] * tau)
            body.check_finite(final)
            ctx.body = body
            ctx.lane = (runner, handle)
            ctx.arrays = None
            return torch.from_numpy(y)
        ctx.lane = None
        np_dtype = _NUMPY[dtype]
        n_blocks, m, n_springs = block_forces.shape[0], body.n_movable, body.topology.n_springs
        steps = n_blocks * tau
        ext = np.repeat(_as_numpy(block_forces, dtype), tau, axis=0).reshape(steps, 1, m, 2)
        rest = np.ascontiguousarray(np.broadcast_to(_as_numpy(l, dtype), (steps, 1, n_springs)))
        start = tuple(_as_numpy(x, dtype) for x in (r0, v0, a0))
        r_out, v_out, a_out = (np.empty((steps, 1, m, 2), dtype=np_dtype) for _ in range(3))
        len_out = np.empty((steps, 1, n_springs), dtype=np_dtype)
        k_np, d_np, offset, mass, coef = body.kernel_constants(dtype)
        verlet, clamp = body.integrator == "verlet", bool(body.environment.ground_clamp)
        kernel.forward(*start, k_np, d_np, rest, ext, body.spring_i, body.spring_j, offset, mass, coef, verlet,
                       clamp, r_out, v_out, a_out, len_out)
        final = BodyState(*(torch.from_numpy(x[-1]) for x in (r_out, v_out, a_out, len_out)), step + steps)
        body.check_finite(final)
        ctx.body = body
        ctx.read = (tau, row, coord)
        ctx.arrays = (start, rest, (r_out, v_out, a_out, len_out))
        return torch.from_numpy(r_out[tau - 1:: tau, 0, row, coord].copy())

    @staticmethod
    def backward(ctx, g_out):  # type: ignore[override]
        from bptsb_ros.body import kernel

        body: MSDN = ctx.body
        if ctx.lane is not None:
            if ctx.lane[1] is None:
                raise RuntimeError(_SECOND_BACKWARD)
            runner, handle = ctx.lane
            ctx.lane = (runner, None)
            dtype = body.k.dtype
            *lam, g_k, g_d, g_l, g_blocks = runner.backward(handle, _as_numpy(g_out, dtype))
            return (*(torch.from_numpy(x).unsqueeze(0) for x in lam), *(torch.from_numpy(x) for x in (g_k, g_d, g_l)),
                    torch.from_numpy(g_blocks), None, None, None, None, None)
        tau, row, coord = ctx.read
        if ctx.arrays is None:  # freed by the first backward, as torch frees a graph's saved tensors
            raise RuntimeError(_SECOND_BACKWARD)
        start, rest, outs = ctx.arrays
        r_out = outs[0]
        steps, m, n_springs = r_out.shape[0], r_out.shape[2], rest.shape[2]
        np_dtype = r_out.dtype
        dtype = body.k.dtype
        g_r = np.zeros_like(r_out)
        g_r[tau - 1:: tau, 0, row, coord] = _as_numpy(g_out, dtype)
        none4, none3 = np.empty((0, 0, 0, 0), dtype=np_dtype), np.empty((0, 0, 0), dtype=np_dtype)
        lam = tuple(np.empty((1, m, 2), dtype=np_dtype) for _ in range(3))
        g_k, g_d = np.empty((1, n_springs), dtype=np_dtype), np.empty((1, n_springs), dtype=np_dtype)
        g_rest = np.empty((steps, 1, n_springs), dtype=np_dtype)
        g_ext = np.empty((steps, 1, m, 2), dtype=np_dtype)
        k_np, d_np, offset, mass, coef = body.kernel_constants(dtype)
        kernel.adjoint(*start, k_np, d_np, rest, 1, body.spring_i, body.spring_j, offset, mass, coef,
                       body.integrator == "verlet", bool(body.environment.ground_clamp), *outs, g_r, none4, none4,
                       none3, *lam, g_k, g_d, g_rest, g_ext)
        ctx.arrays = None  # the trajectory is not needed again
        grad_blocks = g_ext.reshape(steps // tau, tau, m, 2).sum(1)
        # the steps summed last to first, one after another, as the lane kernel sums them (and k's and d's are)
        grad_rest = np.cumsum(g_rest[::-1, 0], axis=0)[-1]
        return (*(torch.from_numpy(x) for x in lam), torch.from_numpy(g_k[0]), torch.from_numpy(g_d[0]),
                torch.from_numpy(grad_rest), torch.from_numpy(grad_blocks), None, None, None, None, None)


@dataclass
class PopulationWindow:
    """What :func:`population_readout` returns for B bodies: ``y`` (B, K) the read coordinate at each block end
    [m] (differentiable); ``sound`` (B,) bool: :func:`~bptsb_ros.body.msdn.state_is_sound` of each final state
    (False: that body diverged, its ``y`` and gradients are not to be used; the others' are unaffected)."""

    y: torch.Tensor
    sound: np.ndarray


def population_readout(body: MSDN, r0: torch.Tensor, v0: torch.Tensor, a0: torch.Tensor, k: torch.Tensor,
                       d: torch.Tensor, l: torch.Tensor, blocks: torch.Tensor, tau: int, row: int,  # noqa: E741
                       coord: int) -> PopulationWindow:
    """:func:`held_force_readout` for B bodies of ``body``'s topology, each with its own parameters, in one call
    of ``body/held_window_kernel.py`` (one lane each; a lane's arithmetic is the solo window's).

    Args:
        body: the topology, masses, scalars and integrator (its own k, d, l are not used).
        r0: (B, M, 2) start positions [m].
        v0: (B, M, 2) start velocities [m/s].
        a0: (B, M, 2) start accelerations [m/s²].
        k: (B, E) spring constants [N/m].
        d: (B, E) damping [N·s/m].
        l: (B, E) rest lengths [m].
        blocks: (B, K, M, 2) external forces [N], block j in force at steps jτ + 1 … (j + 1)τ.
        tau: steps per block, as :func:`held_force_readout`.
        row: the read mass, as :func:`held_force_readout`.
        coord: the read coordinate, as :func:`held_force_readout`.

    Differentiable w.r.t. r0, v0, a0, k, d, l and blocks. Raises ValueError for shapes that do not fit or a body
    the lane kernel cannot run (ground)."""
    why = held_window_unsupported(body) or lanes_unsupported(body)
    if why:
        raise ValueError(f"population_readout: {why}")
    b, m, e = r0.shape[0], body.n_movable, body.topology.n_springs
    if blocks.dim() != 4 or tuple(blocks.shape[2:]) != (m, 2) or blocks.shape[0] != b or blocks.shape[1] < 1:
        raise ValueError(f"blocks must be ({b}, K >= 1, {m}, 2), got {tuple(blocks.shape)}")
    for name, t, shape in (("r0", r0, (b, m, 2)), ("v0", v0, (b, m, 2)), ("a0", a0, (b, m, 2)), ("k", k, (b, e)),
                           ("d", d, (b, e)), ("l", l, (b, e))):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must be {shape}, got {tuple(t.shape)}")
    if tau < 1 or not (0 <= row < m and coord in (0, 1)):
        raise ValueError(f"tau must be >= 1 and (row, coord) a movable mass's coordinate, got {tau}, ({row}, {coord})")
    box: dict[str, Any] = {}
    y = _PopulationWindow.apply(r0, v0, a0, k, d, l, blocks, body, int(tau), int(row), int(coord), box)
    return PopulationWindow(y, box["sound"])


def _lanes_last(t: torch.Tensor, dtype: torch.dtype) -> np.ndarray:
    """(B, ...) tensor → C-contiguous (..., B) numpy array (the lane kernel's layout)."""
    x = _as_numpy(t, dtype)
    return np.ascontiguousarray(np.moveaxis(x, 0, -1))


class _PopulationWindow(torch.autograd.Function):
    """Forward: ``held_window_kernel.forward`` with one lane per body; backward: its adjoint."""

    @staticmethod
    def forward(ctx, r0, v0, a0, k, d, l, blocks, body: MSDN, tau: int, row: int, coord: int,
                box: dict):  # type: ignore[override]
        from bptsb_ros.body import held_window_kernel
        from bptsb_ros.body.msdn import lanes_sound

        dtype = body.k.dtype
        arrays = [_lanes_last(x, dtype) for x in (r0, v0, a0, k, d, l, blocks)]
        _, _, offset, mass, coef = body.kernel_constants(dtype)
        verlet = body.integrator == "verlet"
        y, saved, end = held_window_kernel.forward(*arrays, tau, row, coord, body.spring_i, body.spring_j, offset,
                                                   mass, coef, verlet)
        box["sound"] = lanes_sound(*end[:3])
        ctx.body, ctx.read = body, (tau, row, coord)
        ctx.arrays = (arrays[3:], saved)
        return torch.from_numpy(np.ascontiguousarray(y.T))

    @staticmethod
    def backward(ctx, g_y):  # type: ignore[override]
        from bptsb_ros.body import held_window_kernel

        if ctx.arrays is None:
            raise RuntimeError(_SECOND_BACKWARD)
        body: MSDN = ctx.body
        (k, d, l, blocks), saved = ctx.arrays
        ctx.arrays = None
        tau, row, coord = ctx.read
        _, _, offset, mass, coef = body.kernel_constants(body.k.dtype)
        lam, grads, g_blocks = held_window_kernel.adjoint(
            k, d, l, blocks, tau, row, coord, body.spring_i, body.spring_j, offset, mass, coef,
            body.integrator == "verlet", saved, _lanes_last(g_y, body.k.dtype))
        first = [torch.from_numpy(np.ascontiguousarray(np.moveaxis(x, -1, 0))) for x in (*lam, *grads, g_blocks)]
        return (*first, None, None, None, None, None)
