"""Rules shared by the claims of the MNIST experiments (drawing, PCA, label maps, specific 100, readout).

Each experiment turns its measured numbers into :class:`~bptsb_ros.experiments.result.Claim` objects with a pure
function ``claims(numbers)`` (its docstring quotes the paper's sentence), so that every verdict can be tested on
planted numbers. What they share:

* the premise of every statement about a *trained* system: it learned, i.e. it labels its inputs right more often
  than chance by a margin no sampling luck explains (:func:`learned`). For a drawing system "right" is a drawing
  nearest to its own label's target (the label maps' rule, paper Methods); for a readout, its predicted class;
  for an output in the PCA plane, a held-out linear probe's answer;
* claims over several comparisons (MLP < LIL "for both bodies"): :func:`all_of`, a three-valued AND: one
  comparison that fails refutes the claim; otherwise one whose premise failed leaves it not testable;
* the label separation of one output in the 2-D PCA plane (:class:`Separation`);
* the numbers a claim function read in each seed of a multi-seed run, for the across-seed figures
  (:func:`over_seeds`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import at_most, fmt
from bptsb_ros.experiments.result import Claim

#: a system learned when its accuracy exceeds chance by more than this many binomial standard errors of chance
#: (3: a system that ignores its input passes with probability ≈ 0.1 %)
LEARNED_Z = 3.0


@dataclass(frozen=True)
class Skill:
    """How often a trained system labels its inputs right.

    accuracy: share in [0, 1] of ``n`` scored samples labelled right (NaN: not measured); chance: the share of the
    most common label among those samples, what always answering that label scores."""

    accuracy: float
    n: int
    chance: float

    @classmethod
    def of(cls, accuracy: float, labels: np.ndarray) -> Skill:
        """The skill ``accuracy`` measured on samples with these ``labels`` (ints ≥ 0)."""
        labels = np.asarray(labels, dtype=np.int64)
        if labels.size == 0:
            return cls(float(accuracy), 0, float("nan"))
        return cls(float(accuracy), int(labels.size), float(np.bincount(labels).max() / labels.size))

    @property
    def bound(self) -> float:
        """The accuracy it must exceed to count as learned: chance + :data:`LEARNED_Z` · √(chance(1 − chance)/n)."""
        if self.n <= 0:
            return float("nan")
        return self.chance + LEARNED_Z * math.sqrt(self.chance * (1.0 - self.chance) / self.n)

    def text(self, name: str) -> str:
        """``name: 51.5 % of 2000 right (chance 11.4 %, learned above 13.5 %)``."""
        return (f"{name}: {fmt(100 * self.accuracy)} % of {self.n} right (chance {fmt(100 * self.chance)} %, "
                f"learned above {fmt(100 * self.bound)} %)")


def learned(s: Skill) -> bool:
    """The system learned: accuracy > :attr:`Skill.bound`, strictly (a floating-point excess below
    :data:`~bptsb_ros.experiments.claim_rules.EPS` is equality); False for no samples or a NaN accuracy."""
    return bool(s.n > 0 and math.isfinite(s.accuracy) and not at_most(s.accuracy, s.bound))


def not_learned(skills: dict[str, Skill], what: str = "did not learn") -> str | None:
    """The failed premise "every one of these systems learned" in words (None: all learned)."""
    bad = [s.text(name) for name, s in skills.items() if not learned(s)]
    return f"{what}: " + "; ".join(bad) if bad else None


@dataclass(frozen=True)
class Check:
    """One comparison inside a claim: ``holds`` its verdict on the numbers ``text``; ``premise`` the premise that
    failed, in words (None: the comparison is testable)."""

    text: str
    holds: bool
    premise: str | None = None


def all_of(claim: str, checks: list[Check]) -> Claim:
    """A claim that every one of ``checks`` holds (three-valued AND): False when a testable check fails (the
    untestable ones are named too), else not testable when some check's premise failed, else True."""
    if not checks:
        raise ValueError(f"claim {claim!r}: no comparison to test")
    tested = [c for c in checks if c.premise is None]
    open_ = [f"{c.text}: not testable, {c.premise}" for c in checks if c.premise is not None]
    if any(not c.holds for c in tested):
        return Claim(claim, False, "; ".join([c.text for c in tested] + open_))
    if open_:
        return Claim.not_testable(claim, "; ".join(open_ + [c.text for c in tested]))
    return Claim(claim, True, "; ".join(c.text for c in tested))


@dataclass(frozen=True)
class Separation:
    """How one output (the brain's initial positions or the body's CMP trajectory) separates the labels in the 2-D
    PCA plane the paper's figures show.

    silhouette: mean silhouette coefficient of the labels in that plane, in [−1, 1] (NaN: fewer than two labels);
    per_label: (10,) mean silhouette of each digit's points (NaN: digit absent); probe: a linear probe fitted on
    one half of the plane's points and scored on the other (:class:`Skill`)."""

    silhouette: float
    per_label: tuple[float, ...]
    probe: Skill

    @classmethod
    def from_scores(cls, scores: dict[str, Any]) -> Separation:
        """From :func:`bptsb_ros.analysis.separation.separation_scores`' 2-D entries."""
        return cls(float(scores["silhouette_2d"]), tuple(float(v) for v in scores["per_label_2d"]),
                   Skill(float(scores["probe_2d"]), int(scores["probe_n"]), float(scores["probe_chance"])))


def more_separated(brain: Separation, body: Separation) -> Check:
    """Body silhouette (2-D PCA) > brain silhouette, strictly; not testable when either is undefined."""
    text = f"silhouette (2-D PCA): body {fmt(body.silhouette)} vs brain {fmt(brain.silhouette)}"
    if not (math.isfinite(body.silhouette) and math.isfinite(brain.silhouette)):
        return Check(text, False, "a silhouette is undefined (fewer than two labels)")
    return Check(text, body.silhouette > brain.silhouette)


def classifies(name: str, sep: Separation) -> Check:
    """The output classifies the labels: its 2-D linear probe :func:`learned` (beats chance by the margin)."""
    return Check(sep.probe.text(f"{name} (linear probe in the 2-D PCA plane, held-out half)"), learned(sep.probe))


def over_seeds(per_seed: Sequence[Mapping[str, Any]], fn: Callable[..., list[Claim]],
               pick: Callable[[Any], Sequence[float]]) -> np.ndarray:
    """(seeds, k): ``pick(numbers)`` (k values) of the numbers the claim function ``fn`` was called with (its first
    argument, as stored in each seed's result.json and decoded by
    :func:`~bptsb_ros.experiments.measured.stored_calls`; its first call); a row of NaN for a seed whose result
    stored no such call (k from the seeds that did; (seeds, 0) when none did)."""
    from bptsb_ros.experiments.measured import stored_calls

    rows: list[np.ndarray | None] = []
    for result in per_seed:
        calls = stored_calls(result, fn)
        rows.append(np.asarray(pick(calls[0][1][0]), dtype=float).ravel() if calls and calls[0][1] else None)
    width = next((len(r) for r in rows if r is not None), 0)
    out = np.full((len(per_seed), width), np.nan)
    for i, r in enumerate(rows):
        if r is not None and len(r) == width:
            out[i] = r
    return out
