"""Fast BPTSB through a window of steps: the forward pass is ``MSDN.step`` itself (run without
autograd), the backward pass a hand-derived adjoint of that step.

Plain autograd records ~20 tiny ops per step; for the paper's small bodies the per-op bookkeeping,
not arithmetic, dominates. Running the forward without a tape and the reverse sweep by hand is
~2-3× faster and stores only the states. The adjoint is checked against autograd through
``MSDN.step`` and against finite differences in the tests.

Adjoint of one step (verlet; m = mass, h = Δt²/2, x = D r' + c spring vectors, L = |x|, q = 1 − l/L,
f = k q x + d D v, F = −Dᵀ f + f_env + f_ext, a' = F/m, v' = v + Δt(a + a')/2):

    Ḡa' += Δt/2 · Ḡv'          Ḡv = Ḡv'         Ḡa = Δt/2 · Ḡv'
    ḠF = Ḡa'/m                  Ḡf_ext = ḠF      Ḡf = −D ḠF
    Ḡk += q (x·Ḡf)              Ḡl = −k (x·Ḡf)/L                   Ḡd += (D v)·Ḡf
    Ḡx = k q Ḡf + k l/L³ x (x·Ḡf) + Ḡ_L x/L                        Ḡr' += Dᵀ Ḡx
    Ḡv += Dᵀ(d Ḡf) − a_drag ḠF     Ḡr'_y += −c² e^{−c r'_y} ḠF_y
    Ḡr = Ḡr'   Ḡv += Δt Ḡr'   Ḡa += h Ḡr'

With the ground clamp (applied to r' and v before the forces, the published order) the forces see the
clamped r' and v; before the last line Ḡr'_y and Ḡv of every clamped mass are zeroed (their values
were set, not computed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from bptsb_ros.body.msdn import MSDN, BodyState


@dataclass
class Window:
    """Trajectory of one window of W steps (states 1..W after the start state).

    r, v, a: (W, B, M, 2); length: (W, B, E); final: the state after the last step.
    """

    r: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    length: torch.Tensor
    final: BodyState


def rollout_window(
    body: MSDN,
    state: BodyState,
    rest_lengths: torch.Tensor,
    external_forces: torch.Tensor | None = None,
    *,
    adjoint: bool = True,
) -> Window:
    """Run W steps with the given per-step commands, differentiably.

    Args:
        body: the MSDN (its k, d receive gradients; l only through ``rest_lengths``).
        state: start state (its r, v, a may carry gradients, e.g. from a brain that sets them).
        rest_lengths: (W, E) or (W, B, E) rest length in force at steps 1..W [m].
        external_forces: (W, B, M, 2) or (W, M, 2) external force at steps 1..W [N], or None.
        adjoint: use the hand-derived backward (default); False records every step with autograd.

    With ``body.backend == "numba"`` (CPU) the window is one compiled call forward and one backward
    (``body/kernel.py``); with ``torch`` the forward is ``MSDN.step`` and the backward the torch adjoint
    below. Both are the same equations; tests/body/test_kernel.py holds them equal.
    """
    n_steps = rest_lengths.shape[0]
    if external_forces is not None and external_forces.shape[0] != n_steps:
        raise ValueError(
            f"external_forces has {external_forces.shape[0]} steps but rest_lengths has {n_steps}"
        )
    ext = external_forces if external_forces is not None else rest_lengths.new_zeros(0)
    if body.uses_kernel(state.r, state.v, state.a, rest_lengths, external_forces):  # nothing to differentiate
        r, v, a, length = body.kernel_window(state.r, state.v, state.a, rest_lengths, external_forces)
    elif body.backend == "numba" and body.k.device.type == "cpu" and adjoint:
        r, v, a, length = _KernelWindowFunction.apply(state.r, state.v, state.a, body.k, body.d, rest_lengths, ext,
                                                      body)
    elif not adjoint or not torch.is_grad_enabled():
        return _rollout_autograd(body, state, rest_lengths, external_forces)
    else:
        r, v, a, length = _WindowFunction.apply(state.r, state.v, state.a, body.k, body.d, rest_lengths, ext, body)
    final = BodyState(r[-1], v[-1], a[-1], length[-1], state.step + n_steps)
    return Window(r, v, a, length, final)


def _rollout_autograd(
    body: MSDN, state: BodyState, rest_lengths: torch.Tensor, external_forces: torch.Tensor | None
) -> Window:
    rs, vs, as_, ls = [], [], [], []
    for i in range(rest_lengths.shape[0]):
        state = body.step(state, rest_lengths[i], None if external_forces is None else external_forces[i])
        rs.append(state.r)
        vs.append(state.v)
        as_.append(state.a)
        ls.append(state.length)
    return Window(torch.stack(rs), torch.stack(vs), torch.stack(as_), torch.stack(ls), state)


class _WindowFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, r0, v0, a0, k, d, rest_lengths, ext, body: MSDN):  # type: ignore[override]
        n_steps = rest_lengths.shape[0]
        has_ext = ext.numel() > 0
        batch = r0.shape[0]
        shape = (n_steps, batch, *r0.shape[1:])
        r_out, v_out, a_out = (r0.new_empty(shape) for _ in range(3))
        len_out = r0.new_empty((n_steps, batch, k.shape[0]))
        state = BodyState(r0, v0, a0, r0.new_empty(0), 0)
        for i in range(n_steps):
            state = body.step(state, rest_lengths[i], ext[i] if has_ext else None)
            r_out[i], v_out[i], a_out[i], len_out[i] = state.r, state.v, state.a, state.length
        ctx.body = body
        ctx.has_ext = has_ext
        ctx.ext_shape = ext.shape
        ctx.save_for_backward(r0, v0, a0, k, d, rest_lengths, r_out, v_out, a_out, len_out)
        return r_out, v_out, a_out, len_out

    @staticmethod
    def backward(ctx, g_r, g_v, g_a, g_len):  # type: ignore[override]
        body: MSDN = ctx.body
        r0, v0, a0, k, d, rest_lengths, r_out, v_out, a_out, len_out = ctx.saved_tensors
        dt = body.dt
        half_dt, h = 0.5 * dt, 0.5 * dt * dt
        verlet = body.integrator == "verlet"
        env = body.environment
        batch, n_mov = r0.shape[0], r0.shape[1]
        n_springs = k.shape[0]
        fm, fe = 2 * n_mov, 2 * n_springs  # flat widths: (B, 2M) masses, (B, 2E) springs
        gather, scatter = body.gather, body.scatter  # r_flat @ gather = D r;  f_flat @ scatter = Dᵀ f
        neg_gather = -gather
        c = body.fixed_offset
        inv_m = (1.0 / body.mass).repeat_interleave(2)  # per flat coordinate (x, y of each mass)
        kk, dd = k.unsqueeze(-1), d.unsqueeze(-1)  # (E, 1)
        n_steps = rest_lengths.shape[0]
        per_batch_l = rest_lengths.dim() == 3
        # Output gradients that are identically zero (e.g. a loss on positions only) are skipped.
        g_r_steps = g_r.reshape(n_steps, batch, fm).unbind(0) if bool(g_r.any()) else None
        g_v_steps = g_v.reshape(n_steps, batch, fm).unbind(0) if bool(g_v.any()) else None
        g_a_steps = g_a.reshape(n_steps, batch, fm).unbind(0) if bool(g_a.any()) else None
        g_len_steps = g_len.unsqueeze(-1).unbind(0) if bool(g_len.any()) else None
        r_prev = [r0.reshape(batch, fm), *r_out.reshape(n_steps, batch, fm).unbind(0)]
        v_prev = [v0.reshape(batch, fm), *v_out.reshape(n_steps, batch, fm).unbind(0)]
        a_prev = [a0.reshape(batch, fm), *a_out.reshape(n_steps, batch, fm).unbind(0)]
        lengths = len_out.unsqueeze(-1).unbind(0)  # (B, E, 1) each
        rests = rest_lengths.unsqueeze(-1).unbind(0)

        y_only = torch.tensor([False, True])  # the clamp overwrites y, not x
        lam_r = r0.new_zeros(batch, fm)
        lam_v = r0.new_zeros(batch, fm)
        lam_a = r0.new_zeros(batch, fm)
        acc_k = r0.new_zeros(batch, n_springs, 1)
        acc_d = r0.new_zeros(batch, n_springs, 2)
        g_rest = torch.empty_like(rest_lengths)
        g_ext = r0.new_empty((n_steps, batch, fm)) if ctx.has_ext else None

        for i in range(n_steps - 1, -1, -1):
            gr_new = lam_r if g_r_steps is None else lam_r + g_r_steps[i]
            gv_new = lam_v if g_v_steps is None else lam_v + g_v_steps[i]
            ga_new = lam_a if g_a_steps is None else lam_a + g_a_steps[i]
            r, v = r_prev[i], v_prev[i]
            r_new = r_prev[i + 1]  # the forces saw the clamped positions
            below = None
            if env.ground_clamp:  # which masses the clamp moved: rebuild the unclamped update
                r_free = torch.add(r, v, alpha=dt)
                if verlet:
                    r_free.add_(a_prev[i], alpha=h)
                below = r_free.view(batch, n_mov, 2)[..., 1:] < 0  # (B, M, 1)
                v = v.view(batch, n_mov, 2).masked_fill(below, 0.0).view(batch, fm)  # the forces saw v clamped
            # v' = v + Δt/2 (a + a')  (published: v' = v + Δt/2 a')
            gF = torch.add(ga_new, gv_new, alpha=half_dt).mul_(inv_m)
            if g_ext is not None:
                g_ext[i] = gF
            ga = gv_new * half_dt if verlet else None
            gv = gv_new if not env.air_drag else torch.add(gv_new, gF, alpha=-env.air_drag)
            x = torch.mm(r_new, gather).view(batch, n_springs, 2).add_(c)
            length, rest = lengths[i], rests[i]
            gf = torch.mm(gF, neg_gather).view(batch, n_springs, 2)
            xg = (x * gf).sum(-1, keepdim=True)  # (B, E, 1)
            xg_over_l = xg / length
            rest_over_l = rest / length
            q = 1 - rest_over_l
            acc_k.addcmul_(q, xg)
            acc_d.addcmul_(torch.mm(v, gather).view(batch, n_springs, 2), gf)
            gl = (xg_over_l * kk).neg_().squeeze(-1)  # (B, E)
            g_rest[i] = gl if per_batch_l else gl.sum(0)
            gx = (kk * q) * gf
            coef = (kk * rest_over_l) * xg_over_l / length
            if g_len_steps is not None:
                coef = coef + g_len_steps[i] / length
            gx.addcmul_(coef, x)
            gr_prime = torch.addmm(gr_new, gx.view(batch, fe), scatter)
            if env.ground_c:
                cg = env.ground_c
                y = r_new.view(batch, n_mov, 2)[..., 1]
                gy = (-cg * cg) * torch.exp(-cg * y) * gF.view(batch, n_mov, 2)[..., 1]
                gr_prime = gr_prime + torch.stack([torch.zeros_like(gy), gy], dim=-1).view(batch, fm)
            gv = torch.addmm(gv, (dd * gf).view(batch, fe), scatter)  # adjoint of the clamped v
            if below is not None:  # through the clamp: y and v of a clamped mass do not depend on the step's inputs
                gr_prime = gr_prime.view(batch, n_mov, 2).masked_fill(below & y_only, 0.0).view(batch, fm)
                gv = gv.view(batch, n_mov, 2).masked_fill(below, 0.0).view(batch, fm)
            lam_v = gv.add_(gr_prime, alpha=dt)
            lam_a = ga.add_(gr_prime, alpha=h) if verlet else torch.zeros_like(gr_prime)
            lam_r = gr_prime

        g_k = acc_k.sum((0, 2))
        g_d = acc_d.sum((0, 2))
        if g_ext is not None:
            g_ext = g_ext.view(n_steps, batch, n_mov, 2)
            if len(ctx.ext_shape) == 3:  # ext given as (W, M, 2): broadcast over batch
                g_ext = g_ext.sum(1)
        shape = r0.shape
        return lam_r.view(shape), lam_v.view(shape), lam_a.view(shape), g_k, g_d, g_rest, g_ext, None


class _KernelWindowFunction(torch.autograd.Function):
    """The window as one numba call forward (``MSDN.kernel_window``) and one backward (``kernel.adjoint``)."""

    @staticmethod
    def forward(ctx, r0, v0, a0, k, d, rest_lengths, ext, body: MSDN):  # type: ignore[override]
        has_ext = ext.numel() > 0
        r_out, v_out, a_out, len_out = body.kernel_window(r0, v0, a0, rest_lengths, ext if has_ext else None)
        ctx.body = body
        ctx.rest_shape = rest_lengths.shape
        ctx.ext_shape = ext.shape if has_ext else None
        ctx.save_for_backward(r0, v0, a0, rest_lengths, r_out, v_out, a_out, len_out)
        ctx.set_materialize_grads(False)  # an output the loss does not read costs nothing in the backward
        return r_out, v_out, a_out, len_out

    @staticmethod
    def backward(ctx, g_r, g_v, g_a, g_len):  # type: ignore[override]
        from bptsb_ros.body import kernel
        from bptsb_ros.body.msdn import _as_numpy

        body: MSDN = ctx.body
        r0, v0, a0, rest_lengths, r_out, v_out, a_out, len_out = ctx.saved_tensors
        dtype = r0.dtype
        n_steps, batch, n_mov = r_out.shape[0], r_out.shape[1], r_out.shape[2]
        n_springs = len_out.shape[2]
        rest = rest_lengths if rest_lengths.dim() == 3 else rest_lengths.unsqueeze(1)
        n_ext = 0 if ctx.ext_shape is None else 1
        # contiguous outputs (strided views cost the kernel ~2× in indexing): λ_r, λ_v, λ_a (B, M, 2), Ḡk, Ḡd
        # (B, E) per body, Ḡl (W, B, E) and Ḡf_ext (W, B, M, 2) per body and step
        lam_r, lam_v, lam_a = (torch.empty((batch, n_mov, 2), dtype=dtype) for _ in range(3))
        g_k, g_d = torch.empty((batch, n_springs), dtype=dtype), torch.empty((batch, n_springs), dtype=dtype)
        g_rest = torch.empty((n_steps, batch, n_springs), dtype=dtype)
        g_ext = torch.empty((n_steps, batch if n_ext else 0, n_mov, 2), dtype=dtype)
        k, d, offset, mass, coef = body.kernel_constants(dtype)

        # an output the loss does not read has no gradient: the kernel takes a 0-step array for it
        empty = {3: np.empty((0, 0, 0), dtype=k.dtype), 4: np.empty((0, 0, 0, 0), dtype=k.dtype)}
        kernel.adjoint(_as_numpy(r0, dtype), _as_numpy(v0, dtype), _as_numpy(a0, dtype), k, d, _as_numpy(rest, dtype),
                       n_ext, body.spring_i, body.spring_j, offset, mass, coef, body.integrator == "verlet",
                       bool(body.environment.ground_clamp), r_out.numpy(), v_out.numpy(), a_out.numpy(),
                       len_out.numpy(), *(empty[4] if g is None else _as_numpy(g, dtype) for g in (g_r, g_v, g_a)),
                       empty[3] if g_len is None else _as_numpy(g_len, dtype), lam_r.numpy(), lam_v.numpy(),
                       lam_a.numpy(), g_k.numpy(), g_d.numpy(), g_rest.numpy(), g_ext.numpy())
        grad_rest = _reduce_to(g_rest, ctx.rest_shape if len(ctx.rest_shape) == 3 else (n_steps, 1, n_springs))
        grad_ext = None
        if ctx.ext_shape is not None:
            shape = ctx.ext_shape if len(ctx.ext_shape) == 4 else (n_steps, 1, n_mov, 2)
            grad_ext = _reduce_to(g_ext, shape).reshape(ctx.ext_shape)
        return (lam_r, lam_v, lam_a, g_k.sum(0), g_d.sum(0),
                grad_rest.reshape(ctx.rest_shape), grad_ext, None)


def _reduce_to(grad: torch.Tensor, shape: tuple[int, ...]) -> torch.Tensor:
    """Sum a per-body gradient (W, B, ...) over the batch axis where the input was shared (size 1)."""
    return grad.sum(1, keepdim=True) if shape[1] == 1 and grad.shape[1] != 1 else grad
