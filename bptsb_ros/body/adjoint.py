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
"""

from __future__ import annotations

from dataclasses import dataclass

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
    """
    n_steps = rest_lengths.shape[0]
    if external_forces is not None and external_forces.shape[0] != n_steps:
        raise ValueError(
            f"external_forces has {external_forces.shape[0]} steps but rest_lengths has {n_steps}"
        )
    if not adjoint or not torch.is_grad_enabled():
        return _rollout_autograd(body, state, rest_lengths, external_forces)
    ext = external_forces if external_forces is not None else rest_lengths.new_zeros(0)
    r, v, a, length = _WindowFunction.apply(
        state.r, state.v, state.a, body.k, body.d, rest_lengths, ext, body
    )
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
        ctx.save_for_backward(r0, v0, a0, k, d, rest_lengths, r_out, v_out, a_out)
        return r_out, v_out, a_out, len_out

    @staticmethod
    def backward(ctx, g_r, g_v, g_a, g_len):  # type: ignore[override]
        body: MSDN = ctx.body
        r0, v0, a0, k, d, rest_lengths, r_out, v_out, a_out = ctx.saved_tensors
        dt = body.dt
        half_dt, h = 0.5 * dt, 0.5 * dt * dt
        verlet = body.integrator == "verlet"
        env = body.environment
        gather, scatter = body.gather, body.scatter  # r_flat @ gather = D r;  f_flat @ scatter = Dᵀ f
        c = body.fixed_offset
        batch, n_mov = r0.shape[0], r0.shape[1]
        n_springs = k.shape[0]

        def D(y: torch.Tensor) -> torch.Tensor:  # (B, M, 2) -> (B, E, 2)
            return torch.mm(y.reshape(batch, 2 * n_mov), gather).view(batch, n_springs, 2)

        def Dt(y: torch.Tensor) -> torch.Tensor:  # (B, E, 2) -> (B, M, 2)
            return torch.mm(y.reshape(batch, 2 * n_springs), scatter).view(batch, n_mov, 2)

        inv_m = (1.0 / body.mass).unsqueeze(-1)  # (M, 1)
        kk, dd = k.unsqueeze(-1), d.unsqueeze(-1)  # (E, 1)
        n_steps = rest_lengths.shape[0]
        per_batch_l = rest_lengths.dim() == 3

        lam_r = torch.zeros_like(r0)
        lam_v = torch.zeros_like(r0)
        lam_a = torch.zeros_like(r0)
        acc_k = r0.new_zeros(r0.shape[0], k.shape[0])
        acc_d = r0.new_zeros(r0.shape[0], k.shape[0])
        g_rest = torch.zeros_like(rest_lengths)
        g_ext = r0.new_zeros((n_steps, *r0.shape)) if ctx.has_ext else None

        for i in range(n_steps - 1, -1, -1):
            if i > 0:
                r, v, a = r_out[i - 1], v_out[i - 1], a_out[i - 1]
            else:
                r, v, a = r0, v0, a0
            gr_new = g_r[i] + lam_r
            gv_new = g_v[i] + lam_v
            ga_new = g_a[i] + lam_a
            r_new = torch.add(r, v, alpha=dt)  # positions the forces saw (before any ground clamp)
            if verlet:
                r_new.add_(a, alpha=h)
            if env.ground_clamp:
                below = (r_new[..., 1] < 0).unsqueeze(-1)
                gr_new = torch.where(below, gr_new * gr_new.new_tensor([1.0, 0.0]), gr_new)
                gv_new = torch.where(below, torch.zeros_like(gv_new), gv_new)
            # v' = v + Δt/2 (a + a')  (published: v' = v + Δt/2 a')
            ga_tot = torch.add(ga_new, gv_new, alpha=half_dt)
            gF = ga_tot * inv_m
            if g_ext is not None:
                g_ext[i] = gF
            gv = gv_new - env.air_drag * gF if env.air_drag else gv_new.clone()
            ga = gv_new * half_dt if verlet else torch.zeros_like(gv_new)
            x = D(r_new) + c  # (B, E, 2)
            length = torch.linalg.vector_norm(x, dim=-1, keepdim=True)  # (B, E, 1)
            rest = rest_lengths[i].unsqueeze(-1)
            gf = D(gF).neg_()  # (B, E, 2)
            xg = (x * gf).sum(-1, keepdim=True)  # (B, E, 1)
            q = 1 - rest / length
            acc_k += (q * xg).squeeze(-1)
            acc_d += (D(v) * gf).sum(-1)
            gl = (-kk * xg / length).squeeze(-1)  # (B, E)
            g_rest[i] = gl if per_batch_l else gl.sum(0)
            gx = kk * (q * gf + (rest / length**3) * xg * x) + (g_len[i].unsqueeze(-1) / length) * x
            gr_prime = gr_new + Dt(gx)
            if env.ground_c:
                cg = env.ground_c
                gy = -cg * cg * torch.exp(-cg * r_new[..., 1]) * gF[..., 1]
                gr_prime = gr_prime + torch.stack([torch.zeros_like(gy), gy], dim=-1)
            gv = gv + Dt(dd * gf)
            lam_r = gr_prime
            lam_v = gv.add_(gr_prime, alpha=dt)
            lam_a = ga.add_(gr_prime, alpha=h) if verlet else ga

        g_k = acc_k.sum(0)
        g_d = acc_d.sum(0)
        if g_ext is not None and len(ctx.ext_shape) == 3:  # ext given as (W, M, 2): broadcast over batch
            g_ext = g_ext.sum(1)
        return lam_r, lam_v, lam_a, g_k, g_d, g_rest, g_ext, None
