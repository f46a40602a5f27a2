"""One SWG training window as one compiled call, and the SGD update of every group as another (numba).

The fused path of ``training.backend: fused`` (:mod:`bptsb_ros.training.fused`). Per window it does, without
torch or autograd, what the numba path does through ~40 torch calls and the autograd engine:

1. the SWG clock θ_t = ω·k_t·Δt from the integer step k_t (exactly :func:`bptsb_ros.body.clock.clock_phase`:
   k mod N times 2π/N in float64 when the period is N whole steps, else 2π·frac(k·c) in float64), sin θ and
   cos θ cast to the model dtype;
2. the rest lengths l_te = l_e·(1 + m_e·A_e·(sin θ_t cos φ_e + cos θ_t sin φ_e)) (``SineWaveGenerator``,
   m: the driven mask), in the model dtype;
3. the body over the window (``kernel._forward_serial``, the numba path's own forward);
4. the task's loss and its gradient w.r.t. the trajectory: Lissajous, L = mean over steps and x, y of
   (CMP − target)², the target x = X cos(αω t), y = Y sin(βω t + δ) at t = k_t·Δt in float64 cast to the model
   dtype (``tasks/lissajous.py``), ∂L/∂r = (1/2W)·2(CMP − target) on the CMP rows; locomotion
   (``tasks/locomotion.py``), L = mean over blocks of (block-mean of the mean x-velocity − target)², ∂L/∂v' on
   the x rows (with the periodic headwind written into the external forces before step 3);
5. the body's adjoint (``kernel._adjoint_serial``) → ∂L/∂k, ∂L/∂d and ∂L/∂l_te, and through step 2
   ∂L/∂l_e = Σ_t ∂L/∂l_te (1 + s_te), ∂L/∂A_e = Σ_t g_te u_te, ∂L/∂φ_e = −sin φ_e Σ_t g_te A_e sin θ_t +
   cos φ_e Σ_t g_te A_e cos θ_t with g_te = ∂L/∂l_te · l_e · m_e, u_te = sin θ_t cos φ_e + cos θ_t sin φ_e.

Shapes (numpy, one float dtype throughout, C-contiguous; a batch of one body; W steps, M movable masses,
E springs): r0, v0, a0 (1, M, 2); k, d, l, amplitude, phase (E,); driven (E,) bool; the work arrays
of :class:`bptsb_ros.training.fused.FusedSwgWindow`. The parameter order of ``grads`` and of the update is
:data:`PARAMETERS`.

numba caches a function by its own source file only: a caller of the cached ``kernel`` functions would not
notice a change of ``body/kernel.py``. The compiled functions here are therefore named after a digest of
``kernel.py`` (``_renamed``), so an edited kernel compiles them afresh.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
from numba import njit

from bptsb_ros.body import kernel
from bptsb_ros.body.kernel import _JIT, _renamed

#: the trained parameters, in the order of ``grads`` rows and of the SGD rates
PARAMETERS = ("k", "d", "l", "amplitude", "phase")
#: the losses: ``kind`` 0 Lissajous, 1 locomotion, 2 the CMP against a target the caller writes into ``tgt``
#: (Lissajous switching; its wind forces, too, are the caller's, in ``ext``)
LISSAJOUS, LOCOMOTION, GIVEN_TARGET = 0, 1, 2
#: ``clock``: [N (0: the period is no whole number of steps), 2π/N, cycles per step ωΔt/2π]
#: ``target``, Lissajous: [X, Y, αω, βω, δ, Δt]; locomotion: [block, training's first step, slope, Δt, constant
#: target speed (NaN: the ramp), 1 if the loss reads each step's velocity before its update, wind force, wind period]
#: ``out`` after a window: [loss, state finite, grads finite]
OUT_LOSS, OUT_STATE_OK, OUT_GRADS_OK = 0, 1, 2
#: the divergence limit of ``MSDN.check_finite`` [m]
POSITION_LIMIT = 1e6
#: the first fused window with a cold cache [s] (``swg_window`` with the body kernels it calls, and the losses):
#: 11.9 s measured on 2 busy cores (load 4-5), as ``kernel.COMPILE_S``
COMPILE_S = 12.0


def _swg_window_impl(r0, v0, a0, k, d, l, amp, phase, driven, first_step, kind, clock, target, cmp, coef, unit,
                     verlet, clamp, si, sj, offset, mass, rest, ext, r_out, v_out, a_out, len_out,
                     g_r, g_v, g_none4, g_none3, lam_r, lam_v, lam_a, g_kb, g_db, g_rest, g_ext,
                     sin_t, cos_t, cph, sph, tgt, grads, out):  # pragma: no cover - compiled
    """One window: rest lengths, (wind,) body, loss, gradients. ``g_r`` (Lissajous) or ``g_v`` (locomotion) is the
    (W, 1, M, 2) loss gradient buffer, the other a 0-step array; ``ext`` (W, 1, M, 2) is filled with the wind when
    it has a batch axis of 1 (locomotion with wind), else (W, 0, M, 2)."""
    n_steps, n_springs, n_mov = rest.shape[0], k.shape[0], r0.shape[1]
    zero, one, two, inv_n = unit[0], unit[1], unit[2], unit[3]
    period, step_angle, cycles_per_step = clock[0], clock[1], clock[2]
    n_period = np.int64(period)
    # 1-2: clock, SWG signal, rest lengths
    for e in range(n_springs):
        cph[e] = math.cos(phase[e])
        sph[e] = math.sin(phase[e])
    for t in range(n_steps):
        step = first_step + 1 + t
        if n_period > 0:
            theta = np.float64(step % n_period) * step_angle
        else:
            cycles = np.float64(step) * cycles_per_step
            theta = (cycles - math.floor(cycles)) * (2 * math.pi)
        sin_t[t] = math.sin(theta)
        cos_t[t] = math.cos(theta)
        row = rest[t, 0]
        for e in range(n_springs):
            s = amp[e] * (sin_t[t] * cph[e] + cos_t[t] * sph[e])
            row[e] = l[e] * (one + s * (one if driven[e] else zero))
    if kind == LOCOMOTION and ext.shape[1] > 0:  # sim.inputs.wind_blowing: calm, then blowing, per period
        dt, wind, wind_period = target[3], target[6], target[7]
        for t in range(n_steps):
            tt = np.float64(first_step + 1 + t) * dt
            on = wind_period <= 0 or (tt + 0.5 * dt) % wind_period >= 0.5 * wind_period
            for m in range(n_mov):
                ext[t, 0, m, 0] = wind if on else 0.0
                ext[t, 0, m, 1] = 0.0
    # 3: the body
    kernel._forward_serial(r0, v0, a0, k, d, rest, ext, si, sj, offset, mass, coef, verlet, clamp,
                           r_out, v_out, a_out, len_out)
    last = n_steps - 1
    state_ok = True
    for m in range(n_mov):
        for c in range(2):
            x = r_out[last, 0, m, c]
            if not (math.isfinite(x) and math.isfinite(v_out[last, 0, m, c]) and math.isfinite(a_out[last, 0, m, c])
                    and abs(x) <= POSITION_LIMIT):
                state_ok = False
    out[OUT_STATE_OK] = 1.0 if state_ok else 0.0
    # 4: loss and its gradient (the rows of g_r / g_v the loss does not read stay zero)
    if kind == LOCOMOTION:
        out[OUT_LOSS] = _locomotion_loss(v0, v_out, first_step, target, unit, tgt, g_v)
    else:
        out[OUT_LOSS] = _lissajous_loss(r_out, first_step, target, cmp, inv_n, two, kind == GIVEN_TARGET, tgt, g_r)
    if not state_ok:  # the caller reports the divergence; no gradients
        out[OUT_GRADS_OK] = 0.0
        return
    # 5: the body's adjoint, then through the SWG
    kernel._adjoint_serial(r0, v0, a0, k, d, rest, ext.shape[1], si, sj, offset, mass, coef, verlet, clamp,
                           r_out, v_out, a_out, len_out, g_r, g_v, g_none4, g_none3,
                           lam_r, lam_v, lam_a, g_kb, g_db, g_rest, g_ext)
    ok = True
    for e in range(n_springs):
        mask = one if driven[e] else zero  # SineWaveGenerator: signal × driven (a bool mask as 1, 0)
        g_l = zero
        g_amp = zero
        acc_sin = zero
        acc_cos = zero
        for t in range(n_steps):
            g = g_rest[t, 0, e]
            u = sin_t[t] * cph[e] + cos_t[t] * sph[e]
            g_l += g * (one + (amp[e] * u) * mask)
            gs = g * l[e] * mask
            g_amp += gs * u
            gu = gs * amp[e]
            acc_sin += gu * sin_t[t]
            acc_cos += gu * cos_t[t]
        grads[0, e] = g_kb[0, e]
        grads[1, e] = g_db[0, e]
        grads[2, e] = g_l
        grads[3, e] = g_amp
        grads[4, e] = acc_cos * cph[e] - acc_sin * sph[e]
        for p in range(5):
            if not math.isfinite(grads[p, e]):
                ok = False
    out[OUT_GRADS_OK] = 1.0 if ok else 0.0


def _lissajous_loss_impl(r_out, first_step, target, cmp, inv_n, two, given, tgt, g_r):  # pragma: no cover - compiled
    """mean over steps and x, y of (CMP − target)² (returned, accumulated in float64); writes ∂L/∂r on the CMP rows.
    ``given``: the caller wrote the target into ``tgt`` (W, 2), else the Lissajous curve of ``target``."""
    n_steps = r_out.shape[0]
    x_amp, y_amp, ax, by, delta, dt = target[0], target[1], target[2], target[3], target[4], target[5]
    total = 0.0
    for t in range(n_steps):
        if not given:
            tt = np.float64(first_step + 1 + t) * dt
            tgt[t, 0] = x_amp * math.cos(ax * tt)
            tgt[t, 1] = y_amp * math.sin(by * tt + delta)
        for c in range(2):
            diff = r_out[t, 0, cmp, c] - tgt[t, c]
            total += np.float64(diff) * np.float64(diff)
            g_r[t, 0, cmp, c] = inv_n * (two * diff)
    return total / (2 * n_steps)


def _locomotion_loss_impl(v0, v_out, first_step, target, unit, tgt, g_v):  # pragma: no cover - compiled
    """``LocomotionTask``'s loss: mean over blocks of (block-mean of the mean x-velocity − target)² (returned, in
    float64); writes ∂L/∂v' on the x rows. ``unit``: [0, 1, 2, 1/blocks, block, M] in the model dtype."""
    n_steps, n_mov = v_out.shape[0], v_out.shape[2]
    zero, two, inv_blocks, block_f, n_mov_f = unit[0], unit[2], unit[3], unit[4], unit[5]
    block = np.int64(target[0])
    start, slope, dt, constant, before = target[1], target[2], target[3], target[4], target[5] > 0
    total = 0.0
    for b in range(n_steps // block):
        speed = zero
        for t in range(b * block, (b + 1) * block):
            s = zero
            for m in range(n_mov):
                if before:
                    s += v0[0, m, 0] if t == 0 else v_out[t - 1, 0, m, 0]
                else:
                    s += v_out[t, 0, m, 0]
            speed += s / n_mov_f
        speed = speed / block_f
        if math.isnan(constant):  # the ramp: slope × (block end − training's first step) × Δt
            tgt[b, 0] = slope * (np.float64(first_step + block * (b + 1)) - start) * dt
        else:
            tgt[b, 0] = constant
        diff = speed - tgt[b, 0]
        total += np.float64(diff) * np.float64(diff)
        g_step = inv_blocks * (two * diff) / block_f / n_mov_f
        for t in range(b * block, (b + 1) * block):
            row = t - 1 if before else t
            if row >= 0:
                for m in range(n_mov):
                    g_v[row, 0, m, 0] = g_step
    return total / (n_steps // block)


def _sgd_impl(k, d, l, amp, phase, grads, lr, active):  # pragma: no cover - compiled
    """p ← p − lr_p·∂L/∂p for every active parameter (``PARAMETERS`` order), then k, d, l ← max(·, 0) (NaN kept:
    ``torch.clamp_``), in place. ``lr``: (5,) in the parameters' dtype; ``active``: (5,) bool."""
    params = (k, d, l, amp, phase)
    for p in range(5):
        if active[p]:
            x = params[p]
            rate = lr[p]
            for e in range(x.shape[0]):
                x[e] = x[e] - rate * grads[p, e]
    for x in (k, d, l):
        for e in range(x.shape[0]):
            if x[e] < 0:
                x[e] = 0


_TAG = "_" + hashlib.sha256(Path(kernel.__file__).read_bytes()).hexdigest()[:12]
_lissajous_loss = njit(**_JIT)(_lissajous_loss_impl)
_locomotion_loss = njit(**_JIT)(_locomotion_loss_impl)
swg_window = njit(**_JIT)(_renamed(_swg_window_impl, _TAG))
sgd_update = njit(**_JIT)(_renamed(_sgd_impl, _TAG))
