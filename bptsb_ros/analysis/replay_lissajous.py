"""Lissajous metrics of a replayed live run: the paper's perturbation return criterion and the switching run's
per-segment errors (paper: Fig. 4(b,c), Methods "Lissajous curve drawing task"; supplement "Behavioral switching").

Both are computed the same way from the live CMP (read from the bag) and from the offline simulation of the same
agent, wind and perturbations, so ``bptsb replay`` can say whether the live run returned (drew both curves) and
whether the offline run says the same.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

#: phase-locked (or, for a closed loop, minimum-over-shifts) MSE / target mean square below which a curve counts as
#: drawn: the error is a tenth of the figure's own size (a body at rest at the figure's centre scores 1)
DRAWS_NMSE = 0.1

#: periods at most over which the error after a perturbation is measured (the experiment's eval_periods)
EVAL_PERIODS = 10
#: periods skipped at the start of each constant-wind segment of a switching run (the switch transient)
SEGMENT_TRANSIENT_PERIODS = 2


def lissajous_target(config: dict[str, Any]) -> tuple[Callable[[np.ndarray], np.ndarray], int, float, float]:
    """The agent's single-curve target (``tasks.lissajous.target_from_config``): (target(t (T,) [s]) → (T, 2) [m],
    steps per period, amplitude [m], ω [rad/s]). Settings missing from ``config`` (a bag replayed without its
    agent) are the paper's single-curve ones."""
    from bptsb_ros.tasks.lissajous import target_from_config

    full = {"lissajous": {"amplitude_fraction": 0.05, "alpha": 1, "beta": 2, "delta": 0.0,
                          **config.get("lissajous", {})},
            "brain": {"omega": 2 * math.pi, **config.get("brain", {})},
            "body": {"size": 4.0, "dt": 0.01, **config.get("body", {})}}
    target, period = target_from_config(full)
    amp = float(full["lissajous"]["amplitude_fraction"]) * float(full["body"]["size"])
    return target, period, amp, float(full["brain"]["omega"])


def return_metrics(cmp: dict[str, np.ndarray], first_step: int, perturbed_at: int, dt: float,
                   config: dict[str, Any]) -> dict[str, Any]:
    """The paper's return criterion E / E_orig < 2 for a perturbed run.

    Args:
        cmp: CMP trajectories (T, 2) [m] over steps ``first_step`` .. ``first_step + T − 1``: ``live``,
            ``offline`` (the same perturbation offline) and ``unperturbed`` (the same loop without it: E_orig).
        perturbed_at: step of the (last) perturbation.

    E is the closed-loop error (per-period minimum over time shifts, mean over periods) over the last P whole
    periods of the run, P = min(10, half the whole periods after the perturbation) — the same window for all three.
    """
    from bptsb_ros.tasks.lissajous import RETURN_RATIO, returned, windowed_shift_error

    target, period, _, _ = lissajous_target(config)
    n = len(cmp["live"])
    last = first_step + n - 1
    after = (last - perturbed_at) // period
    periods = min(EVAL_PERIODS, after // 2, (n - 1) // period)  # within the run and within the recorded rows
    out: dict[str, Any] = {"perturbed_at_step": int(perturbed_at), "criterion": f"E / E_orig < {RETURN_RATIO:g}"}
    if periods < 1:
        out["problem"] = (f"the run ends {last - perturbed_at} steps after the perturbation; the return criterion "
                          f"needs at least 2 periods ({2 * period} steps)")
        return out
    a = n - periods * period - 1
    t0 = (first_step + a) * dt
    errors = {k: windowed_shift_error(v[a:], target, t0, dt, period) for k, v in cmp.items()}
    out.update(eval_periods=periods, eval_steps=[first_step + a, last], E_orig=errors["unperturbed"],
               E_live=errors["live"], E_offline=errors["offline"],
               returned_live=bool(returned(errors["live"], errors["unperturbed"])),
               returned_offline=bool(returned(errors["offline"], errors["unperturbed"])))
    out["returned_equal"] = out["returned_live"] == out["returned_offline"]
    return out


def blowing(wind: np.ndarray) -> np.ndarray:
    """(T, 2) wind [N] → (T,) bool: the wind blows where its x component is non-zero (F_wind scales the x component
    in the paper's wind (F, 0) and in the published (15·F, 1), whose calm is (0, 1))."""
    return np.asarray(wind)[:, 0] != 0


def wind_segments(wind: np.ndarray) -> list[tuple[int, int, bool]]:
    """Maximal runs of wind on / off (:func:`blowing`) in (T, 2) → [(start row, end row (exclusive), blowing)]."""
    on = blowing(wind)
    change = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    bounds = np.concatenate([[0], change, [len(on)]])
    return [(int(a), int(b), bool(on[a])) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def switching_metrics(cmp: dict[str, np.ndarray], wind: np.ndarray, dt: float, config: dict[str, Any],
                      extra: dict[str, Any]) -> dict[str, Any]:
    """Per constant-wind segment of a switching run from step 0: phase-locked MSE / target mean square of the CMP
    against (1,2,0) without wind and the agent's second curve (``extra['curve_on']``, displaced by
    ``extra['wind_shift_x']``) with wind, after a transient of 2 periods; for each trajectory in ``cmp`` (T, 2).
    Segments shorter than transient + 1 period are left out."""
    from bptsb_ros.tasks.switching import CURVE_1, Curve, switch_targets

    _, period, amp, omega = lissajous_target(config)
    curve_on = Curve(*extra.get("curve_on", (2, 1, math.pi / 2)))
    target = switch_targets(CURVE_1, curve_on, amp, omega, float(extra.get("wind_shift_x", 0.0)))
    n = len(next(iter(cmp.values())))
    t = np.arange(n) * dt
    on = blowing(wind[:n]).astype(np.float64)
    tgt = target(t, on)
    skip = SEGMENT_TRANSIENT_PERIODS * period
    segments = []
    for a, b, on_seg in wind_segments(wind[:n]):
        if b - a - skip < period:
            continue
        lo = a + skip
        ms = float(np.mean((tgt[lo:b] - tgt[lo:b].mean(0)) ** 2))
        seg = {"steps": [lo, b - 1], "wind": on_seg, "curve": str(curve_on if on_seg else CURVE_1)}
        for key, traj in cmp.items():
            seg[f"nmse_{key}"] = float(np.mean((traj[lo:b] - tgt[lo:b]) ** 2)) / ms
        segments.append(seg)
    out: dict[str, Any] = {"segments": segments, "draws_nmse": DRAWS_NMSE,
                           "transient_periods": SEGMENT_TRANSIENT_PERIODS, "_target": tgt}
    for key in cmp:
        drawn = [s[f"nmse_{key}"] < DRAWS_NMSE for s in segments]
        out[f"both_curves_drawn_{key}"] = bool(segments) and all(drawn) and {s["wind"] for s in segments} == {
            True, False}
    return out
