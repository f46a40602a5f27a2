"""Forces on the masses: the spring-damper force of the paper's Eq. (1) and the locomotion environment.

Every function is vectorised over a leading batch dimension B, the springs E and the movable
masses M; there is no Python loop over masses or springs. Units: metres, seconds, kg (all masses 1).
"""

from __future__ import annotations

import torch


def incidence_operators(incidence: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Kronecker-expanded incidence for both coordinates, as two 2-D matrices.

    With r flattened to (B, 2M) (x, y interleaved, a free view of (B, M, 2)), spring vectors are
    ``r_flat @ gather`` (B, 2E) and net spring forces ``f_flat @ scatter`` (B, 2M): one plain GEMM
    each, much cheaper than a broadcast batched matmul for small bodies.

    Args:
        incidence: (E, M) with +1 at column i and −1 at column j of spring (i, j).

    Returns:
        gather: (2M, 2E) = (D ⊗ I₂)ᵀ; scatter: (2E, 2M) = D ⊗ I₂.
    """
    kron = torch.kron(incidence, torch.eye(2, dtype=incidence.dtype, device=incidence.device))
    return kron.transpose(0, 1).contiguous(), kron.contiguous()


def spring_forces(
    r: torch.Tensor,
    v: torch.Tensor,
    gather: torch.Tensor,
    scatter: torch.Tensor,
    fixed_offset: torch.Tensor,
    k: torch.Tensor,
    d: torch.Tensor,
    rest_length: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Net spring-damper force on each movable mass, and the spring lengths.

    For a spring (i, j): F_ij = −k (r_i − r_j)/|r_i − r_j| (|r_i − r_j| − l) − d (v_i − v_j) acts on
    i, and −F_ij on j (paper, Eq. (1)). Damping acts on the full relative velocity vector.

    Args:
        r: (B, M, 2) movable positions [m].  v: (B, M, 2) movable velocities [m/s].
        gather: incidence operator from ``incidence_operators`` (movable columns only).
        scatter: incidence operator from ``incidence_operators`` (movable columns only).
        fixed_offset: (E, 2) contribution of the fixed masses to r_i − r_j (constant: they never move).
        k: (E,) or (B, E) spring constants [N/m].  d: (E,) or (B, E) damping coefficients [N·s/m].
        rest_length: (E,) or (B, E) rest length in force [m].

    Returns:
        force: (B, M, 2) [N]; length: (B, E) spring lengths [m].
    """
    batch, n_movable = r.shape[0], r.shape[1]
    n_springs = fixed_offset.shape[0]
    diff = torch.mm(r.reshape(batch, 2 * n_movable), gather).view(batch, n_springs, 2) + fixed_offset
    dv = torch.mm(v.reshape(batch, 2 * n_movable), gather).view(batch, n_springs, 2)
    length = torch.linalg.vector_norm(diff, dim=-1)
    coef = k * (length - rest_length) / length  # (B, E): k (L - l) / L
    f = torch.addcmul(coef.unsqueeze(-1) * diff, d.unsqueeze(-1), dv)  # force on j, minus force on i
    force = torch.mm(f.view(batch, 2 * n_springs), scatter).view(batch, n_movable, 2)
    return force.neg_(), length


def environment_forces(
    r: torch.Tensor, v: torch.Tensor, air_drag: float, ground_c: float
) -> torch.Tensor | None:
    """Velocity- and position-dependent environment forces of the locomotion task.

    Air drag −a·v and the soft ground [0, c·exp(−c·y)] (paper, Methods). Returns (B, M, 2) [N], or
    None when both are off (double-circle tasks), so the caller skips the additions.
    """
    out: torch.Tensor | None = None
    if air_drag:
        out = -air_drag * v
    if ground_c:
        y = r[..., 1]
        ground = torch.stack([torch.zeros_like(y), ground_c * torch.exp(-ground_c * y)], dim=-1)
        out = ground if out is None else out + ground
    return out
