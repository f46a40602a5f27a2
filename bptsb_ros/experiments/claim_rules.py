"""Thresholds and comparisons shared by the claims of the SWG experiments (Lissajous and locomotion).

Each experiment turns its measured numbers into :class:`~bptsb_ros.experiments.result.Claim` objects with a pure
function ``claims(numbers)``, so that every verdict can be tested on planted numbers. The helpers here keep the
boundaries of those verdicts the same everywhere: a bound the paper states as inclusive ("0.7 or more", "within")
is met at the bound itself even when the number was computed in floating point (0.8 − 0.6 = 0.20000000000000007).
"""

from __future__ import annotations

import math

import numpy as np

from bptsb_ros.analysis.replay_lissajous import DRAWS_NMSE

#: absolute slack of an inclusive comparison of O(1) numbers (rates, ratios, frequencies in Hz)
EPS = 1e-9


def at_most(x: float, bound: float) -> bool:
    """x ≤ bound, counting a floating-point excess below :data:`EPS` as equal; False for NaN."""
    return bool(x <= bound + EPS)


def draws(nmse: float) -> bool:
    """The curve is drawn: error / target mean square < :data:`DRAWS_NMSE` (strict; NaN, a blow-up, is not)."""
    return bool(nmse < DRAWS_NMSE)


#: two return-rate curves (open and closed loop) are "almost the same" when they differ by at most this at every σ
SAME_RATE = 0.2


def almost_same_rates(rate_a: np.ndarray, rate_b: np.ndarray) -> tuple[bool, float, int]:
    """The paper's "the return rates of the sinusoidal drive and closed-loop control were almost the same" (Fig.
    4(c), Lissajous and locomotion): the two curves over σ differ by at most :data:`SAME_RATE` at every σ
    (inclusive). Returns (holds, the largest |difference|, the index of the σ where it is).

    One rule for both tasks, pointwise rather than on average: the sentence compares two curves, and two curves
    that agree everywhere but one σ, where they differ by 0.5, are not "almost the same" (a mean over 11 σ would
    call that gap 0.05). 0.2 leaves room for the sampling noise of a rate of 100 trials: the difference of two
    independent rates of 100 has a standard deviation of at most 0.071, so 0.2 is 2.8 of them, and two loops of
    equal robustness pass at all 11 σ in about 95 % of draws even at rates near ½. NaN (no rate) fails."""
    diff = np.abs(np.asarray(rate_a, dtype=float) - np.asarray(rate_b, dtype=float))
    if diff.size == 0 or np.isnan(diff).any():
        return False, float("nan"), -1
    worst = int(np.argmax(diff))
    return at_most(float(diff[worst]), SAME_RATE), float(diff[worst]), worst


def longest_run(mask: np.ndarray) -> tuple[int, int, int]:
    """Longest run of True in a 1-D mask: (length, first index, last index); (0, −1, −1) if none."""
    best, cur, start, out = 0, 0, 0, (0, -1, -1)
    for i, v in enumerate(np.asarray(mask, dtype=bool)):
        cur = cur + 1 if v else 0
        if cur == 1:
            start = i
        if cur > best:
            best, out = cur, (cur, start, i)
    return out


def fmt(x: float) -> str:
    """A number for evidence text: 3 significant digits; 'nan' / 'inf' spelled out."""
    return f"{x:.3g}" if math.isfinite(x) else str(x)


def fmt_pair(a: float, b: float) -> tuple[str, str]:
    """Two numbers compared in evidence text: :func:`fmt`'s 3 significant digits, or as many more (up to 12) as
    it takes to tell them apart (a strict comparison of 0.27228 with 0.27247 must not read "0.272 vs 0.272")."""
    if not (math.isfinite(a) and math.isfinite(b)) or a == b:
        return fmt(a), fmt(b)
    digits = next((d for d in range(3, 13) if f"{a:.{d}g}" != f"{b:.{d}g}"), 12)
    return f"{a:.{digits}g}", f"{b:.{digits}g}"


# ------------------------------------------------------------------------------------ verdicts over seeds
#: the four verdicts of a claim over seeds (an aggregate result.json's ``claims[].verdict``)
VERDICTS = ("holds", "fails", "split", "not_testable")
#: the normal quantile of the two-sided 95 % Wilson interval
WILSON_Z = 1.959963984540054


def wilson_interval(k: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``k`` of ``n`` (two-sided; 95 % at the default ``z``).

    Wilson, not the normal-approximation (Wald) interval: with 3–10 seeds and k at or near 0 or n, Wald's interval
    collapses to a point (10 of 10 would be "certain"), while Wilson's keeps the uncertainty of a small sample
    (10 of 10: 0.72–1). Raises ValueError unless 0 ≤ k ≤ n and n ≥ 1."""
    if isinstance(k, bool) or isinstance(n, bool) or not (0 <= k <= n) or n < 1:
        raise ValueError(f"a proportion needs 0 <= k <= n and n >= 1, got k={k!r}, n={n!r}")
    p = k / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def verdict_over_seeds(holds: int, testable: int, seeds: int) -> str:
    """The verdict of a claim over ``seeds`` runs, ``testable`` of which could test it and ``holds`` of those found
    it to hold: ``"not_testable"`` when fewer than half the seeds could test it; else ``"holds"`` when the 95 %
    Wilson interval of holds/testable lies wholly above ½, ``"fails"`` when it lies wholly below ½, ``"split"``
    otherwise (the seeds do not settle it)."""
    if not (0 <= holds <= testable <= seeds) or seeds < 1:
        raise ValueError(f"need 0 <= holds <= testable <= seeds, seeds >= 1; got {holds}, {testable}, {seeds}")
    if 2 * testable < seeds or testable == 0:
        return "not_testable"
    lo, hi = wilson_interval(holds, testable)
    if lo > 0.5:
        return "holds"
    if hi < 0.5:
        return "fails"
    return "split"
