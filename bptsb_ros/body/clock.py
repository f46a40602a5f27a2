"""The simulation clock in exact arithmetic: the SWG phase ω·k·Δt and step times k·Δt from the integer step k.

Why: the model runs in float32, and a float32 t = k·Δt (ulp 2⁻⁸ s beyond 2¹⁵ s) and ω·t (ulp 2⁻⁶ rad beyond
2¹⁷ rad) put a float32 SWG about 2 % of its amplitude off after 3·10⁶ steps of 0.01 s (30,000 s), growing with
t; its drive then is no longer periodic in the SWG period. So the clock never passes through the model dtype:

* :func:`clock_phase` reduces the step itself. When the SWG period 2π/ω is a whole number N of steps (the
  paper's ω = 2π rad/s at Δt = 0.01 s: N = 100), it takes k mod N in integer arithmetic and forms
  2π·(k mod N)/N in float64: exact up to one float64 rounding (≤ 4.5·10⁻¹⁶ rad) at every k, and the drive
  repeats bit for bit every N steps. A period within 10⁻¹² (relative) of an integer counts as one: that is
  far above the float64 rounding of 2π, ω and Δt (a few 10⁻¹⁶) and far below anything physical (the drift it
  absorbs is under 10⁻¹² of the phase). Otherwise the cycles per step c = ωΔt/2π are a float64 number and
  the phase is 2π·frac(k·c) in float64: its error is a few float64 roundings of the accumulated cycles
  k·c (of c, then of k·c), ≲ 2π·k·c·5·10⁻¹⁶ rad (3·10⁻¹⁰ rad after 10⁷ steps at c ≈ 0.01).
* :func:`step_times` gives k·Δt in float64 (relative error 1.1·10⁻¹⁶) for targets that are functions of t.

The model dtype enters only after the transcendental functions: callers cast sin/cos of the phase.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

#: a period of 2π/(ωΔt) steps within this relative distance of an integer N is taken as exactly N steps
INTEGER_PERIOD_RTOL = 1e-12


def steps_per_period(omega: float, dt: float) -> int | None:
    """The SWG period 2π/ω in steps if it is a whole number of steps Δt [s] (within 10⁻¹²), else None."""
    if not (math.isfinite(omega) and math.isfinite(dt) and omega > 0 and dt > 0):
        raise ValueError(f"the SWG clock needs finite ω > 0 and Δt > 0, got ω = {omega}, Δt = {dt}")
    steps = 2 * math.pi / (omega * dt)
    n = round(steps)
    if n >= 1 and abs(steps - n) <= INTEGER_PERIOD_RTOL * n:
        return n
    return None


def _as_steps(steps: torch.Tensor | Sequence[int] | int, device: torch.device | None) -> torch.Tensor:
    k = torch.as_tensor(steps, device=device)
    if k.dtype.is_floating_point or k.dtype.is_complex or k.dtype == torch.bool:
        raise TypeError(f"clock steps must be integers, got {k.dtype}")
    return k.to(torch.int64)


def clock_phase(steps: torch.Tensor | Sequence[int] | int, dt: float, omega: float,
                device: torch.device | None = None) -> torch.Tensor:
    """ω·k·Δt reduced to [0, 2π), float64 [rad], for integer steps k (any shape; same shape out).

    dt: the step Δt [s]; omega: ω [rad/s]. Exact (one float64 rounding) when the period is a whole number
    of steps, else float64-accurate (module docstring). ``device``: where the result lives (default: the
    steps' device).
    """
    k = _as_steps(steps, device)
    n = steps_per_period(omega, dt)
    if n is not None:
        return torch.remainder(k, n).to(torch.float64) * (2 * math.pi / n)
    cycles = k.to(torch.float64) * (omega * dt / (2 * math.pi))
    return (cycles - torch.floor(cycles)) * (2 * math.pi)


def step_times(first_step: int, count: int, dt: float, device: torch.device | None = None) -> torch.Tensor:
    """(count,) float64 times k·Δt [s] of the steps first_step .. first_step+count-1."""
    return torch.arange(first_step, first_step + count, dtype=torch.float64, device=device) * dt
