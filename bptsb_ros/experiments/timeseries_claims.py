"""Premises and comparisons shared by the claims of the time-series experiments (NARMA emulation, NARMA IPC, target
IPC, MSDN nonlinearity, memory task).

Each of those experiments turns its measured numbers into :class:`~bptsb_ros.experiments.result.Claim` objects with
a pure function ``claims(numbers)`` in its own module, so that every verdict can be tested on planted numbers. The
rules they share live here:

* a trained system *learned* its task when its NMSE (mean squared error / target variance) is below
  :data:`LEARNED_NMSE` = 1, i.e. it beats the constant prediction of the target's mean; a claim about trained
  systems is *not testable* while one of them did not learn (its NMSE ≥ 1, or its training diverged);
* a claim made "for both bodies" / "for both brains" combines its per-pair verdicts three-valuedly
  (:func:`all_of`): one testable pair that contradicts it is enough to make it false.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from bptsb_ros.experiments.claim_rules import at_most, fmt

#: an NMSE below this (strictly) means the system learned; at or above it the system is no better than the mean
LEARNED_NMSE = 1.0
#: |total − 1| within which (inclusive) a 1-D state's total capacity "reached the rank of one"
RANK_TOL = 0.1

#: an IPC basis function: ((delay, order), ...), delays strictly increasing; ((1, 1),) is F₁(u(t−1))
Term = tuple[tuple[int, int], ...]

__all__ = ["LEARNED_NMSE", "RANK_TOL", "Term", "all_of", "fmt", "learned", "not_learned", "rank_reached",
           "term_name"]


def learned(nmse: float) -> bool:
    """The system learned its task: NMSE < :data:`LEARNED_NMSE` (NaN, a blow-up, did not)."""
    return bool(nmse < LEARNED_NMSE)


def not_learned(nmse: Mapping[str, float], diverged: Mapping[str, str] | None = None) -> str | None:
    """The failed premise "every one of these systems learned", in words, or None when it holds.

    ``nmse``: system name → its NMSE; ``diverged``: system name → why its training diverged (no NMSE then)."""
    diverged = diverged or {}
    failed = [f"{name}: training diverged ({diverged[name]})" if name in diverged else
              f"{name} did not learn (NMSE {fmt(float(e))} ≥ {LEARNED_NMSE:g})"
              for name, e in nmse.items() if name in diverged or not learned(e)]
    return "; ".join(failed) if failed else None


def all_of(verdicts: Iterable[bool | None]) -> bool | None:
    """Three-valued "for all": False if any verdict is False, else None if any is not testable, else True."""
    verdicts = list(verdicts)
    if any(v is False for v in verdicts):
        return False
    return None if any(v is None for v in verdicts) else True


def rank_reached(totals: Mapping[str, float]) -> tuple[bool, str]:
    """Every 1-D state set's total capacity reached the rank of one: |total − 1| ≤ :data:`RANK_TOL` for every bar
    (``totals``: bar label → total capacity). Returns the verdict and its evidence (the farthest bars)."""
    if not totals:
        raise ValueError("rank_reached needs at least one bar")
    gap = {lab: abs(float(t) - 1.0) for lab, t in totals.items()}
    far = [lab for lab, g in gap.items() if not at_most(g, RANK_TOL)]
    worst = max(gap, key=lambda lab: gap[lab] if math.isfinite(gap[lab]) else math.inf)
    text = (f"{len(totals) - len(far)} of {len(totals)} bars within {RANK_TOL:g} of 1; farthest: {worst} "
            f"{fmt(float(totals[worst]))}")
    if far:
        text += "; outside: " + ", ".join(f"{lab} {fmt(float(totals[lab]))}" for lab in far[:8])
        text += f" (+{len(far) - 8} more)" if len(far) > 8 else ""
    return not far, text


def term_name(term: Term) -> str:
    """F₁(u(t−1))-style name of an IPC basis function, for evidence text."""
    return " ".join(f"F{n}(u(t−{d}))" if d else f"F{n}(u(t))" for d, n in term)
