"""What drives a simulation from outside: the NARMA input series and the brain's input made from it, and the
wind schedules (the periodic headwind of locomotion, the random switching schedule of the Lissajous switching task).

The trainings (:mod:`bptsb_ros.tasks`), the offline runs (:mod:`bptsb_ros.sim`) and the live input nodes all read
these, so the same seed gives the same inputs everywhere.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
import torch


def brain_input(u, narma_cfg: Any):
    """The brain's input for task inputs u in [0, 1] (array or tensor): ``input_scale × u`` (``brain_input:
    unit``, the paper's text) or ``input_scale × (2u − 1)`` (``symmetric``, the published code). A zero-bias ReLU
    MLP is positively homogeneous, hence exactly linear on a non-negative input: only the symmetric input lets
    an untrained MLP brain be nonlinear. ``narma_cfg``: the config's ``narma`` section (object or dict)."""
    get = narma_cfg.get if isinstance(narma_cfg, dict) else lambda k, d=None: getattr(narma_cfg, k, d)
    scale = float(get("input_scale", 20.0))
    return scale * (2 * u - 1) if get("brain_input", "unit") == "symmetric" else scale * u


def narma_inputs(seed: int, count: int) -> np.ndarray:
    """(count,) inputs u ~ U(0, 1) from ``seed``; a longer series from the same seed extends a shorter one.

    The held-out evaluation sequence is ``narma_inputs(narma.eval_seed, narma.n_inputs)``; the live
    ``task_input`` node streams the same series.
    """
    return np.random.default_rng(seed).uniform(0.0, 1.0, count)


def wind_blowing(steps: np.ndarray | torch.Tensor, dt: float, period: float) -> np.ndarray:
    """Whether the periodic wind blows at the given steps: calm for the first half of every ``period`` [s],
    blowing for the second half (t = step·dt); ``period`` 0: always blowing."""
    t = np.asarray(steps, dtype=np.float64) * dt
    if period <= 0:
        return np.ones(t.shape, dtype=bool)
    # a half-step margin keeps the switch on the intended step despite rounding of t / period
    return np.mod(t + 0.5 * dt, period) >= 0.5 * period


def wind_schedule(steps: int, period: int, rng: np.random.Generator, *, hold_periods: tuple[int, int] = (3, 8),
                  timing: Literal["random", "fixed"] | int = "random", start_on: bool = False) -> np.ndarray:
    """Binary wind (steps + 1,) in force at steps 0..steps: segments of whole periods (uniform in
    ``hold_periods``, inclusive) plus a switch phase n/100 of a period (random n, n = 0, or a given n)."""
    lo, hi = hold_periods
    if not 1 <= lo <= hi:
        raise ValueError(f"hold_periods must satisfy 1 <= lo <= hi, got {hold_periods}")
    out = np.zeros(steps + 1)
    on = start_on
    k = 0
    while k <= steps:
        n = rng.integers(0, 100) if timing == "random" else (0 if timing == "fixed" else int(timing))
        end = (k // period + int(rng.integers(lo, hi + 1))) * period + int(round(period * n / 100))
        out[k:end] = float(on)
        k, on = max(end, k + 1), not on
    return out
