"""Feed-forward brains: linear input layer (LIL) and multilayer perceptron (MLP).

Both map a task input u (…, n_in) to an output (…, n_out), typically external forces on the
movable masses (reshaped to (…, M, 2) by the task) or initial displacements (MNIST).
"""

from __future__ import annotations

import torch
from torch import nn


class LinearInputLayer(nn.Module):
    """y = W u + b with W, b ~ N(0, 1) (paper, Methods)."""

    def __init__(self, n_in: int, n_out: int, *, generator: torch.Generator | None = None,
                 dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.randn(n_out, n_in, generator=generator, dtype=torch.float64).to(dtype))
        self.bias = nn.Parameter(torch.randn(n_out, generator=generator, dtype=torch.float64).to(dtype))

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        return torch.nn.functional.linear(u, self.weight, self.bias)


class MLPBrain(nn.Module):
    """Three linear layers n_in → hidden → hidden → n_out with ReLU, Xavier-normal weights, zero bias.

    ``gain`` scales the Xavier init (the published NARMA runs used 2.7; default 1).
    """

    def __init__(self, n_in: int, n_out: int, *, hidden: int = 128, gain: float = 1.0,
                 generator: torch.Generator | None = None, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            [nn.Linear(n_in, hidden, dtype=dtype), nn.Linear(hidden, hidden, dtype=dtype),
             nn.Linear(hidden, n_out, dtype=dtype)]
        )
        for layer in self.layers:
            fan_in, fan_out = layer.weight.shape[1], layer.weight.shape[0]
            std = gain * (2.0 / (fan_in + fan_out)) ** 0.5
            with torch.no_grad():
                layer.weight.copy_(torch.randn(layer.weight.shape, generator=generator, dtype=torch.float64) * std)
                layer.bias.zero_()

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        h = torch.relu(self.layers[0](u))
        h = torch.relu(self.layers[1](h))
        return self.layers[2](h)
