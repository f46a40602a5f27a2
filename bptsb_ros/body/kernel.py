"""The body over a whole window as one compiled call: forward (``MSDN.step``) and its hand-derived
adjoint (``body/adjoint.py``), in numba.

At the paper's sizes (10–33 masses, 24–64 springs) a torch step is ~20 tiny ops and the time goes to
per-op overhead, not arithmetic. Here a window of W steps of B bodies is one call: a loop over the
bodies (``prange``: the parallel build spreads them over threads) around a loop over steps around
loops over springs and masses, with no allocation inside the step. The arithmetic is the torch
path's, term by term, so trajectories and gradients agree with it to rounding (float64: ~1e-15
relative per step; tests/body/test_kernel.py checks 1e-12 over whole windows).

Conventions (numpy arrays, float32 or float64, one dtype throughout, the scalars included: ``coef``
from ``coefficients``, so a float32 window computes in float32; C-contiguous, which the compiled
loops rely on for speed: strided views run ~2× slower):
    r0, v0, a0        (B, M, 2)     start state of the movable masses [m, m/s, m/s²]
    k, d              (E,)          spring constants [N/m], damping [N·s/m]
    rest              (W, Br, E)    rest length in force at steps 1..W [m]; Br = 1 (shared) or B
    ext               (W, Be, M, 2) external force at steps 1..W [N]; Be = 1 (shared), B, or 0 (none)
    si, sj            (E,) int64    movable index of each spring's ends i, j, or −1 for a fixed mass
    offset            (E, 2)        the fixed masses' part of r_i − r_j [m]
    mass              (M,)          [kg]
    coef              (8,)          [Δt, Δt²/2, Δt/2, g_y, drag, c, c², 0] (g_y = −g: gravity acceleration)
    verlet, clamp     bool          integrator (False: published), ground clamp
    r_out, v_out, a_out (W, B, M, 2), len_out (W, B, E): states 1..W and the spring lengths the forces saw

The step (``MSDN.step``): r' = r + Δt v (+ Δt²/2 a, verlet); with the ground clamp every mass with
y' < 0 gets y' = 0 and v = 0 (then the forces); a' = F(r', v, l', f')/m + g; v' = v + Δt/2 (a + a')
(published: v + Δt/2 a'). F = springs (Eq. (1)) − drag·v + [0, c·exp(−c y')] + f'.
"""

from __future__ import annotations

import math
import os
import sys
import types

import numpy as np
from numba import njit, prange

from bptsb_ros.body import compile_notice


def _forward_impl(r0, v0, a0, k, d, rest, ext, si, sj, offset, mass, coef, verlet, clamp,
                  r_out, v_out, a_out, len_out):  # pragma: no cover - compiled
    n_steps, batch = r_out.shape[0], r_out.shape[1]
    n_mov, n_springs = r0.shape[1], k.shape[0]
    shared_rest = rest.shape[1] == 1
    n_ext = ext.shape[1]
    # scalars in the arrays' dtype (float32 stays float32): see ``coefficients``
    dt, h, half_dt, gravity_y, drag, ground_c = coef[0], coef[1], coef[2], coef[3], coef[4], coef[5]
    zero = coef[7]
    for b in prange(batch):
        eb = np.int64(b) if n_ext > 1 else np.int64(0)  # this body's forces (int64: prange's index may be unsigned)
        vc = np.empty((n_mov, 2), dtype=r0.dtype)  # the velocity the forces see (clamped)
        force = np.empty((n_mov, 2), dtype=r0.dtype)
        for t in range(n_steps):
            if t == 0:
                r, v, a = r0[b], v0[b], a0[b]
            else:
                r, v, a = r_out[t - 1, b], v_out[t - 1, b], a_out[t - 1, b]
            rn = r_out[t, b]
            for m in range(n_mov):
                for c in range(2):
                    x = r[m, c] + dt * v[m, c]
                    if verlet:
                        x = x + h * a[m, c]
                    rn[m, c] = x
                    vc[m, c] = v[m, c]
                    force[m, c] = zero
                if clamp and rn[m, 1] < zero:
                    rn[m, 1] = zero
                    vc[m, 0] = zero
                    vc[m, 1] = zero
            lrow = rest[t, 0] if shared_rest else rest[t, b]
            lens = len_out[t, b]
            for e in range(n_springs):
                i, j = si[e], sj[e]
                x0, x1 = offset[e, 0], offset[e, 1]
                w0 = zero
                w1 = zero
                if i >= 0:
                    x0 += rn[i, 0]
                    x1 += rn[i, 1]
                    w0 += vc[i, 0]
                    w1 += vc[i, 1]
                if j >= 0:
                    x0 -= rn[j, 0]
                    x1 -= rn[j, 1]
                    w0 -= vc[j, 0]
                    w1 -= vc[j, 1]
                length = math.sqrt(x0 * x0 + x1 * x1)
                lens[e] = length
                kq = k[e] * (length - lrow[e]) / length
                f0 = kq * x0 + d[e] * w0  # force on j; minus it on i
                f1 = kq * x1 + d[e] * w1
                if i >= 0:
                    force[i, 0] -= f0
                    force[i, 1] -= f1
                if j >= 0:
                    force[j, 0] += f0
                    force[j, 1] += f1
            an, vn = a_out[t, b], v_out[t, b]
            for m in range(n_mov):
                f0, f1 = force[m, 0], force[m, 1]
                if drag != zero:
                    f0 -= drag * vc[m, 0]
                    f1 -= drag * vc[m, 1]
                if ground_c != zero:
                    f1 += ground_c * math.exp(-ground_c * rn[m, 1])
                if n_ext > 0:
                    f0 += ext[t, eb, m, 0]
                    f1 += ext[t, eb, m, 1]
                an[m, 0] = f0 / mass[m]
                an[m, 1] = f1 / mass[m] + gravity_y
                for c in range(2):
                    if verlet:
                        vn[m, c] = vc[m, c] + half_dt * (a[m, c] + an[m, c])
                    else:
                        vn[m, c] = vc[m, c] + half_dt * an[m, c]


def _adjoint_impl(r0, v0, a0, k, d, rest, n_ext, si, sj, offset, mass, coef, verlet, clamp,
                  r_out, v_out, a_out, len_out, g_r, g_v, g_a, g_len,
                  lam_r, lam_v, lam_a, g_k, g_d, g_rest, g_ext):  # pragma: no cover - compiled
    """Reverse sweep of ``_forward_impl`` (see ``body/adjoint.py`` for the equations).

    g_r, g_v, g_a (W, B, M, 2) and g_len (W, B, E): the loss's gradients w.r.t. the outputs.
    Writes lam_r, lam_v, lam_a (B, M, 2) (gradients w.r.t. r0, v0, a0), g_k, g_d (B, E) and g_rest
    (W, B, E) per body, and g_ext (W, B, M, 2) per body when n_ext > 0 (the caller sums over shared axes).
    An output gradient array with 0 steps stands for zeros (the loss does not read that output).
    """
    n_steps, batch = r_out.shape[0], r_out.shape[1]
    n_mov, n_springs = r0.shape[1], k.shape[0]
    shared_rest = rest.shape[1] == 1
    dt, h, half_dt, drag, ground_c, cc = coef[0], coef[1], coef[2], coef[4], coef[5], coef[6]
    zero = coef[7]
    has_gr, has_gv, has_ga, has_gl = g_r.shape[0] > 0, g_v.shape[0] > 0, g_a.shape[0] > 0, g_len.shape[0] > 0
    for b in prange(batch):
        gr = np.zeros((n_mov, 2), dtype=r0.dtype)  # λ_r, λ_v, λ_a carried backwards
        gv = np.zeros((n_mov, 2), dtype=r0.dtype)
        ga = np.zeros((n_mov, 2), dtype=r0.dtype)
        g_force = np.empty((n_mov, 2), dtype=r0.dtype)
        gr_p = np.empty((n_mov, 2), dtype=r0.dtype)
        gv_p = np.empty((n_mov, 2), dtype=r0.dtype)
        vc = np.empty((n_mov, 2), dtype=r0.dtype)
        below = np.zeros(n_mov, dtype=np.bool_)
        acc_k = g_k[b]
        acc_d = g_d[b]
        for e in range(n_springs):
            acc_k[e] = zero
            acc_d[e] = zero
        for t in range(n_steps - 1, -1, -1):
            if t == 0:
                r, v, a = r0[b], v0[b], a0[b]
            else:
                r, v, a = r_out[t - 1, b], v_out[t - 1, b], a_out[t - 1, b]
            rn = r_out[t, b]
            for m in range(n_mov):
                if clamp:
                    y = r[m, 1] + dt * v[m, 1]
                    if verlet:
                        y = y + h * a[m, 1]
                    below[m] = y < zero
                for c in range(2):
                    vc[m, c] = zero if below[m] else v[m, c]
                    gv_new = gv[m, c] + g_v[t, b, m, c] if has_gv else gv[m, c]
                    ga_new = ga[m, c] + g_a[t, b, m, c] if has_ga else ga[m, c]
                    gf = (ga_new + half_dt * gv_new) / mass[m]  # Ḡ of the force at step t+1
                    g_force[m, c] = gf
                    gr_p[m, c] = gr[m, c] + g_r[t, b, m, c] if has_gr else gr[m, c]
                    gv_p[m, c] = gv_new - drag * gf
                    ga[m, c] = half_dt * gv_new if verlet else zero
                    if n_ext > 0:
                        g_ext[t, b, m, c] = gf
            lrow = rest[t, 0] if shared_rest else rest[t, b]
            lens = len_out[t, b]
            grest = g_rest[t, b]
            for e in range(n_springs):
                i, j = si[e], sj[e]
                x0, x1 = offset[e, 0], offset[e, 1]
                w0 = zero
                w1 = zero
                p0 = zero  # Ḡf = −(ḠF_i − ḠF_j)
                p1 = zero
                if i >= 0:
                    x0 += rn[i, 0]
                    x1 += rn[i, 1]
                    w0 += vc[i, 0]
                    w1 += vc[i, 1]
                    p0 -= g_force[i, 0]
                    p1 -= g_force[i, 1]
                if j >= 0:
                    x0 -= rn[j, 0]
                    x1 -= rn[j, 1]
                    w0 -= vc[j, 0]
                    w1 -= vc[j, 1]
                    p0 += g_force[j, 0]
                    p1 += g_force[j, 1]
                length = lens[e]
                rest_e = lrow[e]
                xg = x0 * p0 + x1 * p1
                xg_over_l = xg / length
                rest_over_l = rest_e / length
                q = (length - rest_e) / length  # 1 − l/L
                acc_k[e] += q * xg
                acc_d[e] += w0 * p0 + w1 * p1
                grest[e] = -(xg_over_l * k[e])
                kq = k[e] * q
                cx = (k[e] * rest_over_l) * xg_over_l / length
                if has_gl:
                    cx += g_len[t, b, e] / length
                gx0 = kq * p0 + cx * x0
                gx1 = kq * p1 + cx * x1
                dp0 = d[e] * p0
                dp1 = d[e] * p1
                if i >= 0:
                    gr_p[i, 0] += gx0
                    gr_p[i, 1] += gx1
                    gv_p[i, 0] += dp0
                    gv_p[i, 1] += dp1
                if j >= 0:
                    gr_p[j, 0] -= gx0
                    gr_p[j, 1] -= gx1
                    gv_p[j, 0] -= dp0
                    gv_p[j, 1] -= dp1
            for m in range(n_mov):
                if ground_c != zero:
                    gr_p[m, 1] -= cc * math.exp(-ground_c * rn[m, 1]) * g_force[m, 1]
                if clamp and below[m]:  # y and v of a clamped mass were set, not computed
                    gr_p[m, 1] = 0.0
                    gv_p[m, 0] = 0.0
                    gv_p[m, 1] = 0.0
                for c in range(2):
                    gr[m, c] = gr_p[m, c]
                    gv[m, c] = gv_p[m, c] + dt * gr_p[m, c]
                    if verlet:
                        ga[m, c] = ga[m, c] + h * gr_p[m, c]
        for m in range(n_mov):
            for c in range(2):
                lam_r[b, m, c] = gr[m, c]
                lam_v[b, m, c] = gv[m, c]
                lam_a[b, m, c] = ga[m, c]


def _renamed(fn, suffix: str):
    """The same function under another qualified name. numba's on-disk cache is keyed by the function's
    name and bytecode, not by its compile options: the parallel build needs a name of its own, or it would
    load (and overwrite) the serial build's cache entries."""
    copy = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + suffix, fn.__defaults__, fn.__closure__)
    copy.__qualname__ = fn.__qualname__ + suffix
    copy.__doc__ = fn.__doc__
    return copy


# error_model="numpy": a division by zero (a spring of zero length) gives inf/NaN as in torch, which the divergence
# checks report, instead of numba's default ZeroDivisionError from inside the kernel
_JIT = dict(cache=True, nogil=True, error_model="numpy")
_forward_serial = njit(**_JIT)(_forward_impl)
_forward_parallel = njit(**_JIT, parallel=True)(_renamed(_forward_impl, "_parallel"))
_adjoint_serial = njit(**_JIT)(_adjoint_impl)
_adjoint_parallel = njit(**_JIT, parallel=True)(_renamed(_adjoint_impl, "_parallel"))

#: what the first use of a kernel with a cold cache takes [s], for the line of :mod:`bptsb_ros.body.compile_notice`.
#: Measured on 2 busy cores (load 4-5; on idle cores about half): the first Lissajous training window (forward and
#: adjoint, serial, float32) 8.5 s, the first NARMA one (float64) 7.4 s, the first batch-1000 sweep window
#: (parallel forward) 11.3 s. The serial figures are the pair's: a training run compiles both, one after the other.
COMPILE_S = {"forward": 8.0, "adjoint": 8.0, "forward_parallel": 11.0, "adjoint_parallel": 11.0}

#: batch size from which the bodies of a window are spread over threads (below it one thread is faster)
PARALLEL_MIN_BATCH = int(os.environ.get("BPTSB_PARALLEL_MIN_BATCH", "256"))


def threads_for(batch: int) -> int:
    """Threads the kernels use for a window of ``batch`` bodies."""
    if batch < PARALLEL_MIN_BATCH:
        return 1
    import numba

    return min(batch, numba.get_num_threads())


def coefficients(dt: float, gravity_y: float, drag: float, ground_c: float, dtype) -> np.ndarray:
    """The kernels' scalars as one array of the simulation's dtype: [Δt, Δt²/2, Δt/2, g_y, drag, c, c², 0]."""
    return np.array([dt, 0.5 * dt * dt, 0.5 * dt, gravity_y, drag, ground_c, ground_c * ground_c, 0.0], dtype=dtype)


def _call_keeping_torch_threads(fn, args) -> None:
    """``fn(*args)`` for a parallel kernel. numba's OpenMP threading layer runs on the libgomp torch loaded, and a
    parallel region sets the calling thread's OpenMP team size to numba's thread count, which torch's own
    parallel ops then use: a process set to one torch thread (a pool worker) ran torch on every core after its
    first parallel kernel (measured: MNIST readout epochs 3× slower with two such workers on 2 cores). The torch
    thread count is put back."""
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    try:
        fn(*args)
    finally:
        if before is not None and torch.get_num_threads() != before:
            torch.set_num_threads(before)


def forward(r0, v0, a0, k, d, rest, ext, si, sj, offset, mass, coef, verlet, clamp, r_out, v_out, a_out,
            len_out) -> None:
    """Run a window (see the module docstring for shapes; ``coef`` from ``coefficients``); writes r_out, v_out,
    a_out, len_out."""
    fn = _forward_parallel if r0.shape[0] >= PARALLEL_MIN_BATCH else _forward_serial
    args = (r0, v0, a0, k, d, rest, ext, si, sj, offset, mass, coef, verlet, clamp, r_out, v_out, a_out, len_out)
    if not fn.overloads:  # the first call in this process: say so if it compiles
        compile_notice.announce_if_cold(fn, args, COMPILE_S["forward_parallel" if fn is _forward_parallel
                                                            else "forward"])
    if fn is _forward_parallel:
        _call_keeping_torch_threads(fn, args)
    else:
        fn(*args)


def adjoint(r0, v0, a0, k, d, rest, n_ext, si, sj, offset, mass, coef, verlet, clamp,
            r_out, v_out, a_out, len_out, g_r, g_v, g_a, g_len,
            lam_r, lam_v, lam_a, g_k, g_d, g_rest, g_ext) -> None:
    """Reverse sweep of a window (see ``_adjoint_impl``)."""
    fn = _adjoint_parallel if r0.shape[0] >= PARALLEL_MIN_BATCH else _adjoint_serial
    args = (r0, v0, a0, k, d, rest, n_ext, si, sj, offset, mass, coef, verlet, clamp,
            r_out, v_out, a_out, len_out, g_r, g_v, g_a, g_len, lam_r, lam_v, lam_a, g_k, g_d, g_rest, g_ext)
    if not fn.overloads:
        compile_notice.announce_if_cold(fn, args, COMPILE_S["adjoint_parallel" if fn is _adjoint_parallel
                                                            else "adjoint"])
    if fn is _adjoint_parallel:
        _call_keeping_torch_threads(fn, args)
    else:
        fn(*args)
