"""Sine-wave generator (SWG): rest-length modulation l·(1 + A·sin(ωt + φ)) per driven spring.

The clock never passes through the model dtype: ω·t is formed in float64 (from the integer step in
:meth:`SineWaveGenerator.signal_at_steps`, see :mod:`bptsb_ros.body.clock`), and only sin(ωt) and cos(ωt)
are cast to the parameters' dtype, in sin(ωt + φ) = sin(ωt)·cos φ + cos(ωt)·sin φ. So the trainable A and φ
get their gradients through the same (model-dtype) graph as before, and a float32 SWG is as accurate at
step 10⁷ as at step 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from bptsb_ros.body.clock import clock_phase


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

    def _signal_from_phase(self, theta: torch.Tensor) -> torch.Tensor:
        """A·sin(θ + φ) for clock phases θ (T,) float64 [rad] → (T, E) in the parameters' dtype."""
        theta = theta.to(self.phase.device).unsqueeze(-1)
        sin_t, cos_t = torch.sin(theta).to(self.phase.dtype), torch.cos(theta).to(self.phase.dtype)
        s = self.amplitude * (sin_t * torch.cos(self.phase) + cos_t * torch.sin(self.phase))
        return s * self.driven

    def signal_at_steps(self, steps: torch.Tensor | Sequence[int], dt: float) -> torch.Tensor:
        """Control signal A·sin(ω k Δt + φ) at integer steps k (T,) of Δt = ``dt`` [s] → (T, E) dimensionless;
        0 on undriven springs. The phase ω k Δt is exact (:func:`bptsb_ros.body.clock.clock_phase`)."""
        return self._signal_from_phase(clock_phase(steps, dt, self.omega))

    def rest_length_at_steps(self, base: torch.Tensor, steps: torch.Tensor | Sequence[int],
                             dt: float) -> torch.Tensor:
        """Modulated rest length l·(1 + signal) at integer steps: base (E,), steps (T,) → (T, E) [m]."""
        return base * (1 + self.signal_at_steps(steps, dt))

    def signal(self, t: torch.Tensor) -> torch.Tensor:
        """Control signal A·sin(ωt + φ): t (T,) seconds → (T, E) dimensionless; 0 on undriven springs.

        ω·t is formed in float64, so a float64 t is good to ~10⁻¹¹ rad at t = 3·10⁴ s; a float32 t is not
        (its own rounding is 2 ms there): a simulation's clock uses :meth:`signal_at_steps`.
        """
        return self._signal_from_phase(self.omega * t.to(torch.float64))

    def rest_length(self, base: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Modulated rest length l·(1 + signal): base (E,), t (T,) [s] → (T, E) [m] (see :meth:`signal`)."""
        return base * (1 + self.signal(t))
