"""Finite differences against autograd, shared by the gradient tests of the body (``test_gradients.py``) and of
the MNIST drawing (``test_mnist_drawing.py``)."""

from __future__ import annotations

from collections.abc import Callable

import torch

F64 = torch.float64


def fd_relative_error(loss_fn: Callable[[], torch.Tensor], param: torch.nn.Parameter, *,
                      coordinates: int = 6, directions: int = 2, seed: int = 0) -> tuple[float, float]:
    """(relative error, norm of the compared derivatives) of autograd vs central differences for ``param``.

    Compares ``coordinates`` randomly chosen partial derivatives (all of them if the parameter is
    smaller) and the directional derivatives along ``directions`` random unit vectors (g·u).
    """
    param.grad = None
    loss_fn().backward()
    grad = param.grad.detach().clone().view(-1)
    flat = param.data.view(-1)
    g = torch.Generator().manual_seed(seed)
    n = flat.numel()
    picked = torch.randperm(n, generator=g)[: min(coordinates, n)]
    random_dirs = torch.randn(directions, n, generator=g, dtype=F64)
    unit = torch.zeros(len(picked), n, dtype=F64)
    unit[torch.arange(len(picked)), picked] = 1.0
    basis = torch.cat([unit, random_dirs / random_dirs.norm(dim=1, keepdim=True)])
    exact = basis @ grad
    scale = 1e-6 * max(1.0, float(flat.abs().max()))
    estimate = torch.zeros_like(exact)
    saved = flat.clone()
    with torch.no_grad():
        for n, u in enumerate(basis):
            flat.copy_(saved + scale * u)
            up = float(loss_fn())
            flat.copy_(saved - scale * u)
            down = float(loss_fn())
            estimate[n] = (up - down) / (2 * scale)
        flat.copy_(saved)
    norm = float(exact.norm())
    return float((estimate - exact).norm()) / norm, norm
