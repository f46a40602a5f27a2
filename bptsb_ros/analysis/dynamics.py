"""Descriptors of a trajectory's dynamics: dominant frequency (FFT), local maxima (bifurcation diagrams),
period detection. Plain NumPy, vectorised over the batch (all series along axis 0)."""

from __future__ import annotations

import numpy as np


def dominant_frequency(x: np.ndarray, dt: float) -> np.ndarray:
    """Frequency [Hz] of the largest non-DC FFT peak of each series.

    x: (T, ...) samples every ``dt`` seconds; the mean is removed and a Hann window applied; the peak is
    refined by parabolic interpolation of the log-magnitude, so the error is well below the bin width
    1/(T·dt). Returns shape x.shape[1:].
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    if n < 8:
        raise ValueError(f"dominant_frequency needs at least 8 samples, got {n}")
    win = np.hanning(n).reshape((n,) + (1,) * (x.ndim - 1))
    spec = np.abs(np.fft.rfft((x - x.mean(0)) * win, axis=0))
    spec[0] = 0.0
    k = np.clip(spec.argmax(0), 1, spec.shape[0] - 2)
    take = lambda off: np.take_along_axis(spec, np.expand_dims(k + off, 0), 0)[0]  # noqa: E731
    lo, mid, hi = (np.log(take(o) + 1e-300) for o in (-1, 0, 1))
    denom = lo - 2 * mid + hi
    with np.errstate(invalid="ignore", divide="ignore"):
        offset = np.where(np.abs(denom) > 1e-12, 0.5 * (lo - hi) / denom, 0.0)
    return (k + np.clip(offset, -0.5, 0.5)) / (n * dt)


def local_maxima(x: np.ndarray) -> list[np.ndarray]:
    """Values of the strict interior local maxima of each column of x (T, B): the points of a bifurcation
    diagram. Returns B arrays (in time order)."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    peak = (x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])
    return [x[1:-1, b][peak[:, b]] for b in range(x.shape[1])]


def periodicity(traj: np.ndarray, period: int, max_multiple: int = 8, rtol: float = 1e-3) -> np.ndarray:
    """Smallest m ≤ max_multiple such that traj(t + m·period) ≈ traj(t) over the record, else 0 (aperiodic on
    this record: chaotic or quasi-periodic).

    traj: (T, B, D), needs T > max_multiple·period; "≈": RMS of the difference < rtol × the RMS deviation of
    the trajectory from its mean (a body at rest, with no deviation, counts as period 1).
    """
    traj = np.asarray(traj, dtype=np.float64)
    n = traj.shape[0]
    if n <= max_multiple * period:
        raise ValueError(f"periodicity needs more than {max_multiple * period} rows, got {n}")
    scale = np.sqrt(((traj - traj.mean(0)) ** 2).sum(-1).mean(0))  # (B,)
    out = np.zeros(traj.shape[1], dtype=np.int64)
    for m in range(max_multiple, 0, -1):
        lag = m * period
        diff = np.sqrt(((traj[lag:] - traj[:-lag]) ** 2).sum(-1).mean(0))
        out = np.where(diff <= rtol * np.maximum(scale, 1e-12), m, out)
    return out
