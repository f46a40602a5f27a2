"""Sine-wave generator (SWG): rest-length modulation l·(1 + A·sin(ωt + φ)) per driven spring."""

from __future__ import annotations

import math

import torch
from torch import nn


class SineWaveGenerator(nn.Module):
    """Trainable amplitude A and phase φ per spring; ω = 2π rad/s fixed (paper, Methods).

    ``driven`` is a bool mask (E,) of springs the SWG modulates (the paper's ``generatorDist``); the
    others keep their rest length (signal 0).
    """

    def __init__(
        self,
        n_springs: int,
        *,
        amplitude: float = 0.5,
        omega: float = 2 * math.pi,
        driven: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__()
        self.omega = float(omega)
        self.amplitude = nn.Parameter(torch.full((n_springs,), float(amplitude), dtype=dtype))
        phase = torch.rand(n_springs, generator=generator, dtype=torch.float64) * 2 * math.pi
        self.phase = nn.Parameter(phase.to(dtype))
        mask = torch.ones(n_springs, dtype=torch.bool) if driven is None else driven.to(torch.bool)
        if mask.shape != (n_springs,):
            raise ValueError(f"driven mask must have shape ({n_springs},), got {tuple(mask.shape)}")
        self.register_buffer("driven", mask)

    def signal(self, t: torch.Tensor) -> torch.Tensor:
        """Control signal A·sin(ωt + φ): t (T,) seconds → (T, E) dimensionless; 0 on undriven springs."""
        s = self.amplitude * torch.sin(self.omega * t.unsqueeze(-1) + self.phase)
        return s * self.driven

    def rest_length(self, base: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Modulated rest length l·(1 + signal): base (E,), t (T,) → (T, E) [m]."""
        return base * (1 + self.signal(t))
