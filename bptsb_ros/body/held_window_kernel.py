"""The held-force window of ``body/held_window.py`` for P bodies of one topology at once, in numba: the lanes
(one body each, with its own k, d, l, start state and forces) are the innermost axis of every array, so the
loops over springs and masses run over all lanes at once (SIMD), and a window keeps only one state per input
block: the adjoint recomputes each block's τ steps from it (one extra forward, in cache, instead of the whole
trajectory in memory).

The arithmetic is ``body/kernel.py``'s, term by term, without the ground (clamp, ground force), which the
held windows' tasks do not have; each lane computes exactly what it would alone (no sum runs across lanes), so a
body's result does not depend on which lanes it shares a call with.

Conventions (numpy, float32 or float64, one dtype throughout; C-contiguous), P lanes, K blocks of τ steps:
    r0, v0, a0      (M, 2, P)     start state of the movable masses [m, m/s, m/s²]
    k, d, l         (E, P)        spring constants [N/m], damping [N·s/m], rest lengths [m] (constant over the window)
    blocks          (K, M, 2, P)  external force [N] of each block (block j in force at steps jτ+1 … (j+1)τ)
    si, sj          (E,) int64    movable index of each spring's ends i, j, or −1 for a fixed mass
    offset          (E, 2)        the fixed masses' part of r_i − r_j [m]
    mass            (M,)          [kg]
    coef            (8,)          ``kernel.coefficients`` (the ground's c must be 0)
    saved r, v, a   (K, M, 2, P)  the state at the start of each block (written by the forward)
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bptsb_ros.body import compile_notice

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@njit(**_JIT)
def _step(r, v, a, rn, vn, an, lens, force, tmp, k, d, l, ext, si, sj, offset, mass, coef,
          verlet):  # pragma: no cover - compiled
    """One step of every lane: (r, v, a) → (rn, vn, an), the spring lengths the forces saw into ``lens`` (E, P);
    ``ext`` (M, 2, P); ``force`` (M, 2, P) and ``tmp`` (4, P) are scratch."""
    n_mov, n_springs, lanes = r.shape[0], si.shape[0], r.shape[2]
    dt, h, half_dt, gravity_y, drag = coef[0], coef[1], coef[2], coef[3], coef[4]
    zero = coef[7]
    for m in range(n_mov):
        for c in range(2):
            for p in range(lanes):
                x = r[m, c, p] + dt * v[m, c, p]
                if verlet:
                    x = x + h * a[m, c, p]
                rn[m, c, p] = x
                force[m, c, p] = zero
    x0, x1, w0, w1 = tmp[0], tmp[1], tmp[2], tmp[3]
    for e in range(n_springs):
        i, j = si[e], sj[e]
        for p in range(lanes):
            x0[p] = offset[e, 0]
            x1[p] = offset[e, 1]
            w0[p] = zero
            w1[p] = zero
        if i >= 0:
            for p in range(lanes):
                x0[p] += rn[i, 0, p]
                x1[p] += rn[i, 1, p]
                w0[p] += v[i, 0, p]
                w1[p] += v[i, 1, p]
        if j >= 0:
            for p in range(lanes):
                x0[p] -= rn[j, 0, p]
                x1[p] -= rn[j, 1, p]
                w0[p] -= v[j, 0, p]
                w1[p] -= v[j, 1, p]
        for p in range(lanes):
            length = math.sqrt(x0[p] * x0[p] + x1[p] * x1[p])
            lens[e, p] = length
            kq = k[e, p] * (length - l[e, p]) / length
            x0[p] = kq * x0[p] + d[e, p] * w0[p]  # the force on j; minus it on i
            x1[p] = kq * x1[p] + d[e, p] * w1[p]
        if i >= 0:
            for p in range(lanes):
                force[i, 0, p] -= x0[p]
                force[i, 1, p] -= x1[p]
        if j >= 0:
            for p in range(lanes):
                force[j, 0, p] += x0[p]
                force[j, 1, p] += x1[p]
    for m in range(n_mov):
        for p in range(lanes):
            f0, f1 = force[m, 0, p], force[m, 1, p]
            if drag != zero:
                f0 -= drag * v[m, 0, p]
                f1 -= drag * v[m, 1, p]
            f0 += ext[m, 0, p]
            f1 += ext[m, 1, p]
            an[m, 0, p] = f0 / mass[m]
            an[m, 1, p] = f1 / mass[m] + gravity_y
        for c in range(2):
            for p in range(lanes):
                if verlet:
                    vn[m, c, p] = v[m, c, p] + half_dt * (a[m, c, p] + an[m, c, p])
                else:
                    vn[m, c, p] = v[m, c, p] + half_dt * an[m, c, p]


@njit(**_JIT)
def _forward(r0, v0, a0, k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet,
             saved_r, saved_v, saved_a, y, end_r, end_v, end_a, end_len):  # pragma: no cover - compiled
    """Run the window: ``y`` (K, P) gets coordinate ``coord`` of movable mass ``row`` after every block,
    ``saved_*`` the state at every block start, ``end_*`` the final state and spring lengths."""
    n_blocks = blocks.shape[0]
    n_mov, lanes = r0.shape[0], r0.shape[2]
    n_springs = si.shape[0]
    dtype = r0.dtype
    cur = (r0.copy(), v0.copy(), a0.copy())
    nxt = (np.empty_like(r0), np.empty_like(r0), np.empty_like(r0))
    force = np.empty((n_mov, 2, lanes), dtype=dtype)
    tmp = np.empty((4, lanes), dtype=dtype)
    lens = np.empty((n_springs, lanes), dtype=dtype)
    for b in range(n_blocks):
        saved_r[b] = cur[0]
        saved_v[b] = cur[1]
        saved_a[b] = cur[2]
        for _ in range(tau):
            _step(cur[0], cur[1], cur[2], nxt[0], nxt[1], nxt[2], lens, force, tmp, k, d, l, blocks[b], si, sj,
                  offset, mass, coef, verlet)
            cur, nxt = nxt, cur
        for p in range(lanes):
            y[b, p] = cur[0][row, coord, p]
    end_r[...] = cur[0]
    end_v[...] = cur[1]
    end_a[...] = cur[2]
    end_len[...] = lens


@njit(**_JIT)
def _adjoint(k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet, saved_r, saved_v, saved_a,
             g_y, lam_r, lam_v, lam_a, g_k, g_d, g_l, g_blocks):  # pragma: no cover - compiled
    """Reverse sweep of :func:`_forward` for the loss gradient ``g_y`` (K, P) w.r.t. its ``y``: writes the
    gradients w.r.t. the start state (``lam_*``, (M, 2, P)), k, d, l ((E, P), summed over the steps) and each
    block's force (``g_blocks``, (K, M, 2, P), summed over the block's steps in step order)."""
    n_blocks = blocks.shape[0]
    n_mov, lanes = saved_r.shape[1], saved_r.shape[3]
    n_springs = si.shape[0]
    dtype = saved_r.dtype
    dt, h, half_dt, drag = coef[0], coef[1], coef[2], coef[4]
    zero = coef[7]
    # one block's recomputed trajectory: positions after each step, the velocity each step started from, lengths
    traj_r = np.empty((tau, n_mov, 2, lanes), dtype=dtype)
    traj_v = np.empty((tau + 1, n_mov, 2, lanes), dtype=dtype)
    traj_a = np.empty((tau + 1, n_mov, 2, lanes), dtype=dtype)
    traj_len = np.empty((tau, n_springs, lanes), dtype=dtype)
    g_force = np.empty((tau, n_mov, 2, lanes), dtype=dtype)  # per step: the block's force gradient, summed after
    force = np.empty((n_mov, 2, lanes), dtype=dtype)
    tmp = np.empty((4, lanes), dtype=dtype)
    r_prev = np.empty((n_mov, 2, lanes), dtype=dtype)
    gr = np.zeros((n_mov, 2, lanes), dtype=dtype)  # λ_r, λ_v, λ_a carried backwards
    gv = np.zeros((n_mov, 2, lanes), dtype=dtype)
    ga = np.zeros((n_mov, 2, lanes), dtype=dtype)
    gr_p = np.empty((n_mov, 2, lanes), dtype=dtype)
    gv_p = np.empty((n_mov, 2, lanes), dtype=dtype)
    p0s, p1s = tmp[0], tmp[1]
    for e in range(n_springs):
        for p in range(lanes):
            g_k[e, p] = zero
            g_d[e, p] = zero
            g_l[e, p] = zero
    for b in range(n_blocks - 1, -1, -1):
        ext = blocks[b]
        r_prev[...] = saved_r[b]
        traj_v[0] = saved_v[b]
        traj_a[0] = saved_a[b]
        for s in range(tau):
            _step(r_prev if s == 0 else traj_r[s - 1], traj_v[s], traj_a[s], traj_r[s], traj_v[s + 1],
                  traj_a[s + 1], traj_len[s], force, tmp, k, d, l, ext, si, sj, offset, mass, coef, verlet)
        for s in range(tau - 1, -1, -1):
            rn, vc, lens, gf = traj_r[s], traj_v[s], traj_len[s], g_force[s]
            for m in range(n_mov):
                for c in range(2):
                    for p in range(lanes):
                        gfv = (ga[m, c, p] + half_dt * gv[m, c, p]) / mass[m]  # Ḡ of the force at this step
                        gf[m, c, p] = gfv
                        gr_p[m, c, p] = gr[m, c, p]
                        gv_p[m, c, p] = gv[m, c, p] - drag * gfv
                        ga[m, c, p] = half_dt * gv[m, c, p] if verlet else zero
            if s == tau - 1:
                for p in range(lanes):
                    gr_p[row, coord, p] = gr_p[row, coord, p] + g_y[b, p]
            for e in range(n_springs):
                i, j = si[e], sj[e]
                for p in range(lanes):
                    p0s[p] = zero  # Ḡf = −(ḠF_i − ḠF_j)
                    p1s[p] = zero
                if i >= 0:
                    for p in range(lanes):
                        p0s[p] -= gf[i, 0, p]
                        p1s[p] -= gf[i, 1, p]
                if j >= 0:
                    for p in range(lanes):
                        p0s[p] += gf[j, 0, p]
                        p1s[p] += gf[j, 1, p]
                for p in range(lanes):
                    x0, x1 = offset[e, 0], offset[e, 1]
                    w0 = zero
                    w1 = zero
                    if i >= 0:
                        x0 += rn[i, 0, p]
                        x1 += rn[i, 1, p]
                        w0 += vc[i, 0, p]
                        w1 += vc[i, 1, p]
                    if j >= 0:
                        x0 -= rn[j, 0, p]
                        x1 -= rn[j, 1, p]
                        w0 -= vc[j, 0, p]
                        w1 -= vc[j, 1, p]
                    p0, p1 = p0s[p], p1s[p]
                    length = lens[e, p]
                    rest_e = l[e, p]
                    ke = k[e, p]
                    xg = x0 * p0 + x1 * p1
                    xg_over_l = xg / length
                    rest_over_l = rest_e / length
                    q = (length - rest_e) / length  # 1 − l/L
                    g_k[e, p] += q * xg
                    g_d[e, p] += w0 * p0 + w1 * p1
                    g_l[e, p] += -(xg_over_l * ke)
                    kq = ke * q
                    cx = (ke * rest_over_l) * xg_over_l / length
                    p0s[p] = kq * p0 + cx * x0  # now the position gradient of i (minus it for j) ...
                    p1s[p] = kq * p1 + cx * x1
                    tmp[2, p] = d[e, p] * p0  # ... and the velocity gradient
                    tmp[3, p] = d[e, p] * p1
                if i >= 0:
                    for p in range(lanes):
                        gr_p[i, 0, p] += p0s[p]
                        gr_p[i, 1, p] += p1s[p]
                        gv_p[i, 0, p] += tmp[2, p]
                        gv_p[i, 1, p] += tmp[3, p]
                if j >= 0:
                    for p in range(lanes):
                        gr_p[j, 0, p] -= p0s[p]
                        gr_p[j, 1, p] -= p1s[p]
                        gv_p[j, 0, p] -= tmp[2, p]
                        gv_p[j, 1, p] -= tmp[3, p]
            for m in range(n_mov):
                for c in range(2):
                    for p in range(lanes):
                        gr[m, c, p] = gr_p[m, c, p]
                        gv[m, c, p] = gv_p[m, c, p] + dt * gr_p[m, c, p]
                        if verlet:
                            ga[m, c, p] = ga[m, c, p] + h * gr_p[m, c, p]
        gb = g_blocks[b]
        gb[...] = g_force[0]
        for s in range(1, tau):
            gb += g_force[s]
    lam_r[...] = gr
    lam_v[...] = gv
    lam_a[...] = ga


#: what the first call with a cold cache takes [s] (both kernels), for :mod:`bptsb_ros.body.compile_notice`
COMPILE_S = 10.0


def forward(r0, v0, a0, k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet):
    """Run a window of P lanes (see the module docstring). Returns ``(y (K, P), saved (r, v, a), end (r, v, a,
    lengths))``; ``saved`` is what :func:`adjoint` needs."""
    n_blocks, n_mov, _, lanes = blocks.shape
    dtype = r0.dtype
    saved = tuple(np.empty((n_blocks, n_mov, 2, lanes), dtype=dtype) for _ in range(3))
    y = np.empty((n_blocks, lanes), dtype=dtype)
    end = tuple(np.empty((n_mov, 2, lanes), dtype=dtype) for _ in range(3)) + (
        np.empty((si.shape[0], lanes), dtype=dtype),)
    args = (r0, v0, a0, k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet, *saved, y, *end)
    if not _forward.overloads:
        compile_notice.announce_if_cold(_forward, args, COMPILE_S)
    _forward(*args)
    return y, saved, end


def adjoint(k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet, saved, g_y):
    """Gradients of a window run by :func:`forward` for ``g_y`` (K, P): ``(lam_r, lam_v, lam_a)`` (M, 2, P),
    ``g_k, g_d, g_l`` (E, P) and ``g_blocks`` (K, M, 2, P)."""
    n_blocks, n_mov, _, lanes = blocks.shape
    dtype = k.dtype
    lam = tuple(np.empty((n_mov, 2, lanes), dtype=dtype) for _ in range(3))
    grads = tuple(np.empty((si.shape[0], lanes), dtype=dtype) for _ in range(3))
    g_blocks = np.empty_like(blocks)
    args = (k, d, l, blocks, tau, row, coord, si, sj, offset, mass, coef, verlet, *saved, g_y, *lam, *grads,
            g_blocks)
    if not _adjoint.overloads:
        compile_notice.announce_if_cold(_adjoint, args, COMPILE_S)
    _adjoint(*args)
    return lam, grads, g_blocks
