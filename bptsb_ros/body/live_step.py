"""One step of one body at a time, for the live loop: ``MSDN.step``'s compiled kernel without torch around it.

``MSDN.step`` of a single body on the numba backend runs :func:`bptsb_ros.body.kernel.forward` for a window of one
step; the rest of its cost (a few microseconds of arithmetic) is torch: tensors made, reshaped and viewed as numpy
arrays, the kernel's constants looked up, the divergence checks as numpy reductions — over 100 µs a step. A
:class:`LiveStep` calls the same kernel function on numpy arrays it keeps, and checks the new state in one more
compiled call (:func:`soundness`: the test of ``MSDN.check_finite`` and of :func:`bptsb_ros.live.safety.runaway`), so
a live step is the offline step bit for bit (the kernel is the one of offline simulation and training).

It serves bodies whose steps run in the kernel (:meth:`MSDN.uses_kernel`: numba backend on the CPU); the body's
parameters are read once (the live body does not change them).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

from bptsb_ros.body import kernel
from bptsb_ros.body.msdn import DIVERGENCE_LIMIT, MSDN, BodyState

#: :func:`soundness` codes
SOUND, BROKEN, RUNAWAY = 0, 1, 2


class KernelState(BodyState):
    """A :class:`BodyState` the kernel wrote: its numpy arrays r, v, a (1, M, 2) and length (1, E) (``arrays``), seen
    as tensors (views, made when first read: the live loop reads the arrays)."""

    def __init__(self, r: np.ndarray, v: np.ndarray, a: np.ndarray, length: np.ndarray, step: int) -> None:
        self.arrays = (r, v, a, length)
        self.step = step
        self._tensors: tuple[torch.Tensor, ...] | None = None

    def _tensor(self, i: int) -> torch.Tensor:
        if self._tensors is None:
            self._tensors = tuple(torch.from_numpy(x) for x in self.arrays)
        return self._tensors[i]

    r = property(lambda self: self._tensor(0))  # type: ignore[assignment]
    v = property(lambda self: self._tensor(1))  # type: ignore[assignment]
    a = property(lambda self: self._tensor(2))  # type: ignore[assignment]
    length = property(lambda self: self._tensor(3))  # type: ignore[assignment]


def state_arrays(state: BodyState) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """r, v, a (B, M, 2) and length (B, E) of ``state`` as C-contiguous numpy arrays (no copy where they are)."""
    if isinstance(state, KernelState):
        return state.arrays
    return tuple(np.ascontiguousarray(t.detach().numpy()) for t in (state.r, state.v, state.a, state.length))


@njit(cache=True, nogil=True)
def soundness(r, v, a, limit, dt):  # pragma: no cover - compiled
    """0 (:data:`SOUND`): r, v, a finite and every |r| <= ``limit``; 1 (:data:`BROKEN`): not (``MSDN.check_finite``
    fails); 2 (:data:`RUNAWAY`): sound now but |v|·dt or |a|·dt² beyond ``limit`` (``safety.runaway``: a mass would
    leave the box within one step). Arrays of any shape; ``limit``, ``dt`` floats."""
    rf, vf, af = r.ravel(), v.ravel(), a.ravel()
    speed = 0.0
    accel = 0.0
    for i in range(rf.size):
        x, u, w = float(rf[i]), float(vf[i]), float(af[i])
        if not (math.isfinite(x) and math.isfinite(u) and math.isfinite(w)) or abs(x) > limit:
            return BROKEN
        speed = max(speed, abs(u))
        accel = max(accel, abs(w))
    if speed * dt > limit or accel * dt * dt > limit:
        return RUNAWAY
    return SOUND


class LiveStep:
    """``MSDN.step`` of ``body`` for one body (batch 1), on numpy arrays, with the new state's soundness code.

    Call it with the state of step k (a :class:`BodyState` of batch 1), the rest lengths (E,) [m] and the external
    force (M, 2) [N] (or None) in force at step k+1, all in the body's dtype; it returns the state of step k+1 (a
    :class:`KernelState` of new arrays) and :func:`soundness` of it.
    """

    def __init__(self, body: MSDN, limit: float = DIVERGENCE_LIMIT) -> None:
        if not body.uses_kernel():
            raise ValueError("LiveStep needs a body whose steps run in the numba kernel (backend numba, CPU)")
        self.body, self.limit = body, float(limit)
        dtype = body.k.dtype
        self.k, self.d, self.offset, self.mass, self.coef = (np.ascontiguousarray(x) for x in
                                                             body.kernel_constants(dtype))
        self.np_dtype = self.k.dtype
        n, e = body.n_movable, body.topology.n_springs
        self.shape, self.n_springs = (1, 1, n, 2), e
        self.rest = np.empty((1, 1, e), dtype=self.np_dtype)
        self.ext = np.empty((1, 1, n, 2), dtype=self.np_dtype)
        self.no_ext = np.zeros((1, 0, n, 2), dtype=self.np_dtype)
        self.verlet = body.integrator == "verlet"
        self.clamp = bool(body.environment.ground_clamp)
        self.dt = float(body.dt)

    def __call__(self, state: BodyState, rest: np.ndarray, force: np.ndarray | None) -> tuple[BodyState, int]:
        self.rest[0, 0] = rest
        ext = self.no_ext
        if force is not None:
            self.ext[0, 0] = force
            ext = self.ext
        r0, v0, a0, _ = state_arrays(state)
        r, v, a = (np.empty(self.shape, dtype=self.np_dtype) for _ in range(3))
        length = np.empty((1, 1, self.n_springs), dtype=self.np_dtype)
        kernel.forward(r0, v0, a0, self.k, self.d, self.rest, ext, self.body.spring_i, self.body.spring_j,
                       self.offset, self.mass, self.coef, self.verlet, self.clamp, r, v, a, length)
        code = soundness(r, v, a, self.limit, self.dt)
        return KernelState(r[0], v[0], a[0], length[0], state.step + 1), int(code)
