"""Every claim of the SWG experiments (Lissajous and locomotion) on planted numbers: where it holds, where it fails,
at its boundary (the edge and just past it) and where its premise fails (not testable, holds = None).

The expected verdicts are written by hand from the planted numbers and the paper's sentence each claim tests
(quoted in the docstring of each experiment's ``claims`` function); none is computed by the code under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from bptsb_ros.experiments import closed_loop_schemes as schemes
from bptsb_ros.experiments import lissajous_closed_loop as lcl
from bptsb_ros.experiments import lissajous_perturbation as lpert
from bptsb_ros.experiments import lissajous_switching as lsw
from bptsb_ros.experiments import locomotion_closed_loop as locl
from bptsb_ros.experiments import locomotion_headwind as hw
from bptsb_ros.experiments import locomotion_perturbation as lopert
from bptsb_ros.experiments.result import Claim


def verdicts(claims: list[Claim]) -> list[bool | None]:
    assert all(isinstance(c, Claim) and c.evidence.strip() for c in claims)
    return [c.holds for c in claims]


SIG = np.round(np.arange(11) / 10, 1)  # the paper's σ grid, 0.0 … 1.0


# -- lissajous-closed-loop: [larger (premise: both draw), drew (premise: the SWG draws)] -------------------------
def closed_loop(open_err: float, closed_err: float) -> list[bool | None]:
    return verdicts(lcl.claims(lcl.ClosedLoopNumbers(open_err, closed_err, target_mean_square=1.0)))


def test_lissajous_closed_loop_claims():
    assert closed_loop(0.01, 0.02) == [True, True]  # the paper: larger, and still drawn
    assert closed_loop(0.02, 0.01) == [False, True]  # the closed loop is more accurate
    assert closed_loop(0.02, 0.02) == [False, True]  # equal is not larger
    assert closed_loop(0.02, 0.02 * 1.001) == [True, True]
    # drawn: error < 0.1 × target mean square, strictly
    assert closed_loop(0.01, 0.0999) == [True, True]
    assert closed_loop(0.01, 0.1) == [None, False]  # the closed loop draws nothing: "larger" is not testable
    assert closed_loop(0.01, float("nan")) == [None, False]  # blew up
    # premise: the SWG drew the curve (nothing to transfer otherwise)
    assert closed_loop(0.0999, 0.09995) == [True, True]
    assert closed_loop(0.1, 0.05) == [None, None]
    c = lcl.claims(lcl.ClosedLoopNumbers(0.5, 0.05, 1.0))
    assert "SWG" in c[0].evidence and "SWG" in c[1].evidence


# -- lissajous-perturbation: [SWG falls, FL falls, almost the same] --------------------------------------------------
def lperturb(rate_open, rate_closed, open_nmse=0.01, closed_nmse=0.02) -> list[bool | None]:
    return verdicts(lpert.claims(lpert.PerturbationNumbers(SIG, np.asarray(rate_open, float),
                                                           np.asarray(rate_closed, float), open_nmse, closed_nmse)))


def test_lissajous_perturbation_falls():
    falling = 1 - SIG  # 1.0 → 0.0, Pearson r = −1
    flat = np.ones(11)
    assert lperturb(falling, falling) == [True, True, True]
    assert lperturb(flat, falling)[:2] == [False, True]  # never fails to return: no fall
    # falls at the end but does not tend to decrease (alternating): r > −0.5
    zigzag = np.array([1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 0.9])
    assert np.corrcoef(SIG, zigzag)[0, 1] > -0.5
    assert lperturb(zigzag, falling)[:2] == [False, True]
    # tends to decrease (r < −0.5) but ends where it began
    dip = np.array([0.5, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0.5])
    assert np.corrcoef(SIG, dip)[0, 1] < -0.5
    assert lperturb(falling, dip)[:2] == [True, False]
    # premise: the unperturbed loop draws the trained curve (< 0.1 × target mean square)
    assert lperturb(falling, falling, open_nmse=0.1) == [None, True, None]
    assert lperturb(falling, falling, closed_nmse=0.1) == [True, None, None]
    assert lperturb(falling, falling, open_nmse=0.0999, closed_nmse=0.0999) == [True, True, True]


def test_lissajous_perturbation_almost_the_same():
    base = np.array([1, 1, 1, 1, 1, 0.9, 0.8, 0.8, 0.7, 0.6, 0.5])
    other = base.copy()
    other[7] = 0.6  # |0.8 − 0.6| = 0.2: at the bound, inclusive (in floats 0.20000000000000007)
    assert lperturb(base, other)[2] is True
    other[7] = 0.59
    assert lperturb(base, other)[2] is False
    assert lperturb(base, 1 - SIG)[2] is False  # differ by 0.5 at σ = 0.5
    # premise: some σ gives a rate below 1 (otherwise no perturbation tested robustness)
    c = lpert.claims(lpert.PerturbationNumbers(SIG, np.ones(11), np.ones(11), 0.01, 0.02))
    assert verdicts(c) == [False, False, None] and "every σ" in c[2].evidence
    one_fail = np.ones(11)
    one_fail[10] = 0.99
    assert lperturb(np.ones(11), one_fail)[2] is True


def test_almost_same_rates_is_one_rule_for_both_tasks():
    from bptsb_ros.experiments import claim_rules as rules

    base = np.array([1, 1, 1, 1, 1, 0.9, 0.8, 0.8, 0.7, 0.6, 0.5])
    assert rules.SAME_RATE == 0.2
    assert rules.almost_same_rates(base, base) == (True, 0.0, 0)
    holds, gap, at = rules.almost_same_rates(base, np.where(np.arange(11) == 7, 0.6, base))
    assert holds is True and gap == pytest.approx(0.2) and at == 7  # 0.8 − 0.6 = 0.20000000000000007: inclusive
    # pointwise, not on average: one σ off by 0.5 fails although the mean gap is 0.045
    assert rules.almost_same_rates(base, np.where(np.arange(11) == 9, 0.1, base))[:2] == (False, pytest.approx(0.5))
    assert rules.almost_same_rates(base, np.where(np.arange(11) == 3, np.nan, base))[0] is False
    assert rules.almost_same_rates(np.zeros(0), np.zeros(0))[0] is False
    assert lpert.SAME_RATE is rules.SAME_RATE and lopert.SAME_RATE is rules.SAME_RATE  # imported, not redefined


def attractors(e, e_before, *, e_orig=1.0, nmse=0.01, diverged="") -> list[bool | None]:
    return verdicts(lpert.attractor_claims(lpert.AttractorNumbers("closed loop (FL)", np.asarray(e, float),
                                                                  np.asarray(e_before, float), e_orig, nmse,
                                                                  diverged)))


def test_lissajous_runs_that_did_not_return_converged_to_untrained_attractors():
    # E_orig = 1: rows with E < 2 returned; the others did not
    back = [0.5] * 10
    assert attractors(back + [5.0] * 10, back + [5.0] * 10) == [True]  # every lost run settled
    # settled: |E_last − E_before| ≤ 0.2 × E_last (inclusive); 9 of 10 lost runs is enough, 8 is not
    assert attractors(back + [10.0] * 10, back + [8.0] * 10) == [True]  # |10 − 8| = 2 = 0.2 × 10: the edge
    assert attractors(back + [10.0] * 10, back + [7.99] * 10) == [False]
    assert attractors(back + [10.0] * 10, back + [10.0] * 9 + [20.0]) == [True]  # 9 of 10
    assert attractors(back + [10.0] * 10, back + [10.0] * 8 + [20.0, 3.0]) == [False]  # 8 of 10
    # a diverged run converged to nothing
    assert attractors(back + [10.0] * 8 + [np.nan] * 2, back + [10.0] * 8 + [np.nan] * 2) == [False]
    # a run that returned is no part of it, drifting or not; E = 2 × E_orig has not returned
    assert attractors([0.5] * 10 + [10.0] * 10, [5.0] * 10 + [10.0] * 10) == [True]
    assert attractors([2.0] * 10 + [0.5] * 10, [1.0] * 10 + [0.5] * 10) == [False]
    # premises: some run did not return; the loop draws the trained curve unperturbed
    c = lpert.attractor_claims(lpert.AttractorNumbers("SWG (open loop)", np.full((11, 2), 0.5), np.full((11, 2), 9.0),
                                                      1.0, 0.01))
    assert c[0].holds is None and "returned" in c[0].evidence and c[0].claim.startswith("SWG (open loop): ")
    assert attractors([5.0] * 4, [5.0] * 4, nmse=0.1) == [None]
    assert attractors([5.0] * 4, [5.0] * 4, nmse=0.0999) == [True]
    assert attractors(np.zeros((11, 0)), np.zeros((11, 0)), diverged="planted") == [None]


# -- lissajous-switching: [both drawn, frequencies swap, first curve's error grew] ------------------------------------
def segments(nmse=(0.05, 0.05, 0.05), before=(1.0, 2.0), wind=(2.0, 1.0)) -> dict:
    f = {"before (no wind)": before, "wind": wind, "after (no wind)": before}
    return {k: {"nmse": e, "f_x": f[k][0], "f_y": f[k][1]} for k, e in zip(f, nmse, strict=True)}


def switching(pre=0.01, **kw) -> list[bool | None]:
    return verdicts(lsw.switching_claims(lsw.SwitchingNumbers(pre, segments(**kw), transient=5)))


def test_lissajous_switching_claims():
    assert switching() == [True, True, True]
    # drawn: every segment < 0.1 × target mean square; the "grew" claim needs the switching learned
    assert switching(nmse=(0.05, 0.0999, 0.05)) == [True, True, True]
    assert switching(nmse=(0.05, 0.1, 0.05)) == [False, True, None]
    assert switching(nmse=(0.05, 0.05, float("nan"))) == [False, True, None]
    # swap: within 0.1 Hz, inclusive (1.1 − 1.0 = 0.10000000000000009 in floats), and f_x ≠ f_y
    assert switching(wind=(2.0, 1.1))[1] is True
    assert switching(wind=(2.0, 1.11))[1] is False
    assert switching(wind=(1.9, 1.0))[1] is True
    assert switching(wind=(1.89, 1.0))[1] is False
    assert switching(wind=(1.0, 2.0))[1] is False  # no swap: the wind changes nothing
    assert switching(before=(1.5, 1.5), wind=(1.5, 1.5))[1] is False  # equal frequencies "swap" trivially
    assert switching(before=(1.0, 1.5), wind=(1.5, 1.0))[1] is True  # 0.5 Hz apart: different
    assert switching(before=(1.0, 1.45), wind=(1.45, 1.0))[1] is False
    # grew: after > before, strictly
    assert switching(pre=0.05)[2] is False
    assert switching(pre=0.049)[2] is True
    assert switching(pre=0.06)[2] is False
    # premise of all three: the single-curve agent drew (1,2,0) before the additional training
    assert switching(pre=0.1) == [None, None, None]
    assert switching(pre=0.0999, nmse=(0.0999, 0.0999, 0.0999)) == [True, True, False]


def test_lissajous_switching_tag_names_the_variant():
    c = lsw.switching_claims(lsw.SwitchingNumbers(0.01, segments()), " [published wind (15·F, 1)]")
    assert all("[published wind (15·F, 1)]" in x.claim for x in c)
    # the authors' protocol: the same functions, its own second curve named in the claim
    a = lsw.switching_claims(lsw.SwitchingNumbers(0.01, segments(), 5, "(2,1,0.25π)"), " [authors' protocol]")
    assert "(1,2,0) without and (2,1,0.25π) with wind" in a[0].claim and [x.holds for x in a] == [
        x.holds for x in lsw.switching_claims(lsw.SwitchingNumbers(0.01, segments(), 5))]
    t = lsw.timing_claims(lsw.TimingNumbers(np.zeros(100), np.zeros(100), 5, "(1,3,0.5π)"))
    assert "MSE to the (1,3,0.5π) target" in t[0].claim


# -- lissajous-bifurcation: [period 1 at the trained F, stable from −1 to ~0.2, chaotic in (0.2, 0.6), chaotic in
#    (1.2, 2.0), more diverse than trained] ---------------------------------------------------------------------------
WINDS = np.round(np.arange(-1.0, 2.0001, 0.05), 10)


def periods(*spans: tuple[float, float, int]) -> np.ndarray:
    """Period 1 at every F_wind, then each (lo, hi, m) span (both ends included) set to m, in order."""
    period = np.ones(len(WINDS), dtype=int)
    for lo, hi, m in spans:
        period[(WINDS >= lo - 1e-9) & (WINDS <= hi + 1e-9)] = m
    return period


#: the paper's sentence planted: periodic from −1 to 0.2, aperiodic inside (0.2, 0.6) and (1.2, 2.0)
PAPER_LIKE = ((0.25, 0.55, 0), (1.25, 1.95, 0))


def bifurcation(*spans, nmse=(0.05, 0.05), diverged: str = "") -> list[bool | None]:
    return verdicts(lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, periods(*spans), {0.0: nmse[0], 1.0: nmse[1]},
                                                                  diverged=diverged)))


def test_lissajous_bifurcation_paper_like_diagram_holds_and_a_flat_one_does_not():
    assert bifurcation(*PAPER_LIKE) == [True, True, True, True, True]
    # period 1 everywhere: stable to 2.0 (not "to around 0.2"), no chaos, nothing more diverse than trained
    assert bifurcation() == [True, False, False, False, False]


def test_lissajous_bifurcation_stable_from_minus_one_to_around_0_2():
    # the run of periodic values from −1 ends within ±0.1 of 0.2: its last value in [0.1, 0.3]
    assert bifurcation((0.35, 0.55, 0), (1.25, 1.95, 0))[1] is True  # last periodic 0.3: the edge (0.3 − 0.2 in floats)
    assert bifurcation((0.4, 0.55, 0), (1.25, 1.95, 0))[1] is False  # 0.35
    assert bifurcation((0.15, 0.55, 0), (1.25, 1.95, 0))[1] is True  # last periodic 0.1: the edge
    assert bifurcation((0.1, 0.55, 0), (1.25, 1.95, 0))[1] is False  # 0.05
    # stable = periodic, any period: a period-2 orbit inside [−1, 0.2] is a stable one
    assert bifurcation((-0.5, -0.4, 2), *PAPER_LIKE)[1] is True
    # a blow-up or an aperiodic value inside [−1, 0.2] ends the run early
    assert bifurcation((-0.5, -0.5, -1), *PAPER_LIKE)[1] is False
    c = lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, periods((-1.0, -1.0, 0), *PAPER_LIKE), {0.0: 0.05,
                                                                                                      1.0: 0.05}))
    assert c[1].holds is False and "already aperiodic" in c[1].evidence


def test_lissajous_bifurcation_chaotic_in_the_papers_open_intervals():
    # (0.2, 0.6) holds 7 grid values (0.25 … 0.55): 4 aperiodic is at least half, 3 is not
    assert bifurcation((0.25, 0.4, 0), (1.25, 1.95, 0))[2:4] == [True, True]
    assert bifurcation((0.25, 0.35, 0), (1.25, 1.95, 0))[2:4] == [False, True]
    # the ends are not inside: aperiodic at 0.2 and 0.6 do not count (3 of 7 inside)
    assert bifurcation((0.2, 0.2, 0), (0.6, 0.6, 0), (0.3, 0.4, 0), (1.25, 1.95, 0))[2] is False
    # (1.2, 2.0) holds 15 values (1.25 … 1.95): 8 is at least half, 7 is not
    assert bifurcation((0.25, 0.55, 0), (1.25, 1.6, 0))[3] is True
    assert bifurcation((0.25, 0.55, 0), (1.25, 1.55, 0))[3] is False
    assert bifurcation((0.25, 0.55, 0), (1.2, 1.2, 0), (2.0, 2.0, 0), (1.3, 1.55, 0))[3] is False  # 6 inside
    # a diverged orbit is not a chaotic one; a period-m orbit neither
    assert bifurcation((0.25, 0.55, -1), (1.25, 1.95, 0))[2] is False
    assert bifurcation((0.25, 0.55, 3), (1.25, 1.95, 0))[2] is False


def test_lissajous_bifurcation_trained_period_and_more_diverse():
    assert bifurcation((0.5, 0.5, 2))[4] is True  # a period-2 orbit at an untrained value
    assert bifurcation((1.5, 1.5, 0))[4] is True  # an aperiodic one
    assert bifurcation((0.5, 0.5, -1))[4] is False  # a blow-up is not an embedded dynamics
    # period 1 (one SWG period), not any period: the trained values at period 8 do not hold, and then "more
    # diverse than trained" is not testable
    assert bifurcation((0.0, 0.0, 8))[::4] == [False, None]
    assert bifurcation((1.0, 1.0, 2), (0.5, 0.5, 0))[::4] == [False, None]
    assert bifurcation((1.0, 1.0, 0))[::4] == [False, None]


def test_lissajous_bifurcation_premises():
    # the system learned to switch (draws its curve at F = 0 and 1, < 0.1 × target mean square): every claim
    assert bifurcation(*PAPER_LIKE, nmse=(0.1, 0.05)) == [None] * 5
    assert bifurcation(*PAPER_LIKE, nmse=(0.05, float("nan"))) == [None] * 5
    assert bifurcation(*PAPER_LIKE, nmse=(0.0999, 0.0999)) == [True] * 5
    missing = lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, periods(*PAPER_LIKE), {0.0: 0.05}))
    assert verdicts(missing) == [None] * 5
    with pytest.raises(ValueError, match="trained value 1.0"):
        lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS[:40], np.ones(40, int), {0.0: 0.05, 1.0: 0.05}))


def test_a_diverged_variant_keeps_its_claims_not_testable_with_the_reason():
    """A variant whose training diverged judges to the same claims (texts) as a trained one, each ∅ with why."""
    trained = lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, periods(*PAPER_LIKE), {0.0: 0.05, 1.0: 0.05}),
                                     " [authors' protocol]")
    gone = lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, np.full(len(WINDS), -1), {}, "authors' protocol",
                                                         "the switching training diverged (planted)"),
                                  " [authors' protocol]")
    assert [c.claim for c in gone] == [c.claim for c in trained]
    assert all(c.holds is None and c.evidence == "the switching training diverged (planted)" for c in gone)
    sw = lsw.switching_claims(lsw.SwitchingNumbers(0.01, segments(), 5, diverged="planted"))
    assert [c.claim for c in sw] == [c.claim for c in lsw.switching_claims(lsw.SwitchingNumbers(0.01, segments(), 5))]
    assert verdicts(sw) == [None, None, None]
    hw_ok = hw.claims(hw.HeadwindNumbers(1.0, {"calm": 1.0, "windy_early": 0.8, "windy_late": 1.0},
                                         dict(zip(hw.PHASES, (5, 5, 5), strict=True)), HW_WINDS,
                                         np.where(HW_WINDS < -1, 0.2, 1.0)))
    hw_gone = hw.claims(hw.HeadwindNumbers(float("nan"), dict.fromkeys(hw.PHASES, float("nan")),
                                           dict.fromkeys(hw.PHASES, 0), HW_WINDS, np.full(len(HW_WINDS), np.nan),
                                           diverged="the switching training diverged (planted)"))
    assert [c.claim for c in hw_gone] == [c.claim for c in hw_ok] and verdicts(hw_gone) == [None] * 4
    lp_gone = lpert.claims(lpert.PerturbationNumbers(SIG, np.full(11, np.nan), np.full(11, np.nan), np.nan, np.nan,
                                                     diverged="planted"))
    assert verdicts(lp_gone) == [None] * 3 and all(c.evidence == "planted" for c in lp_gone)
    lo_gone = lopert.claims(lopert.PerturbationRates(np.array(lopert.SIGMAS), np.full(11, np.nan),
                                                     np.full(11, np.nan), False, False, diverged="planted"))
    assert [c.claim for c in lo_gone] == [c.claim for c in lopert.claims(lopert.PerturbationRates(
        np.array(lopert.SIGMAS), FALLING, FALLING, True, True))] and verdicts(lo_gone) == [None] * 3


# -- lissajous-timing: [random timing converges for every n, fixed timing fails for the paper's band] --------------
def timing(fixed=(), rand=(), **kw) -> list[bool | None]:
    """Every n draws the target (0.05) except the planted (index or slice, value) pairs."""
    f, r = np.full(100, 0.05), np.full(100, 0.05)
    for arr, planted in ((f, fixed), (r, rand)):
        for where, value in planted:
            arr[where] = value
    return verdicts(lsw.timing_claims(lsw.TimingNumbers(f, r, last=5, **kw)))


def test_lissajous_timing_random_converges_for_every_n():
    assert timing()[0] is True
    assert timing(rand=[(99, 0.0999)])[0] is True
    assert timing(rand=[(99, 0.1)])[0] is False  # one n that does not draw the target
    assert timing(rand=[(50, np.inf)])[0] is False  # diverged
    # compared with the target, not with the n = 0 run: identical runs that all miss the target are not testable
    assert timing(rand=[(slice(None), 0.3)])[0] is None
    assert timing(rand=[(0, 0.1)])[0] is None  # premise: it switches at n = 0 (its n = 0 run draws the target)


PAPER_BAND = slice(22, 70)  # the paper's 22 ≤ n ≤ 69


def test_lissajous_timing_fixed_fails_for_the_papers_band():
    assert timing(fixed=[(PAPER_BAND, 0.5)])[1] is True
    assert timing()[1] is False  # every n converges
    # each end within ±10 of the paper's (both inclusive)
    assert timing(fixed=[(slice(12, 80), 0.5)])[1] is True  # 12…79: both edges
    assert timing(fixed=[(slice(11, 70), 0.5)])[1] is False  # starts at 11
    assert timing(fixed=[(slice(22, 81), 0.5)])[1] is False  # ends at 80
    assert timing(fixed=[(slice(32, 60), 0.5)])[1] is True  # 32…59: both inner edges
    assert timing(fixed=[(slice(33, 70), 0.5)])[1] is False
    assert timing(fixed=[(slice(22, 59), 0.5)])[1] is False  # ends at 58
    assert timing(fixed=[(slice(30, 35), 0.5)])[1] is False  # a short band far from both ends
    # one band: the longest run is the band; a gap makes the longer half the band (45…69 starts too late)
    assert timing(fixed=[(slice(22, 41), 0.5), (slice(45, 70), 0.5)])[1] is False
    # no failing n outside 12…79; beside the band's ends a few may fail
    assert timing(fixed=[(PAPER_BAND, 0.5), (90, 0.5)])[1] is False
    c = lsw.timing_claims(lsw.TimingNumbers(np.where(np.isin(np.arange(100), [*range(22, 70), 5, 6, 7, 95]), 0.5,
                                                     0.05), np.full(100, 0.05), 5))
    assert c[1].holds is False and "n = 5…7, 95" in c[1].evidence
    assert timing(fixed=[(PAPER_BAND, 0.5), (79, 0.5), (12, 0.5)])[1] is True
    assert timing(fixed=[(PAPER_BAND, 0.5), (80, 0.5)])[1] is False
    # failing: not below 0.1 × the target mean square, or diverged
    assert timing(fixed=[(PAPER_BAND, np.inf)])[1] is True
    assert timing(fixed=[(PAPER_BAND, 0.1)])[1] is True
    assert timing(fixed=[(PAPER_BAND, 0.0999)])[1] is False
    # premise: the fixed-timing system switches at its trained n = 0
    assert timing(fixed=[(PAPER_BAND, 0.5), (0, 0.1)])[1] is None
    assert timing(fixed=[(PAPER_BAND, 0.5), (0, 0.0999)])[1] is True


def test_lissajous_timing_a_diverged_system_is_not_testable_and_the_other_still_is():
    assert timing(fixed=[(PAPER_BAND, 0.5)], fixed_diverged="the switching training diverged") == [True, None]
    assert timing(fixed=[(PAPER_BAND, 0.5)], random_diverged="the switching training diverged") == [None, True]
    c = lsw.timing_claims(lsw.TimingNumbers(np.full(100, np.inf), np.full(100, np.inf), 5, fixed_diverged="planted",
                                            random_diverged="planted too"))
    assert [x.evidence for x in c] == ["planted too", "planted"]


# -- closed-loop-schemes: [scheme 1 draws nothing, scheme 2 / scheme 3 improve only some] ------------------------------
def scheme_numbers(*, before=None, s1=None, s2=None, s3=None, trained1=None, motion1=None,
                   shape=(3, 5)) -> schemes.SchemeNumbers:
    def table(v, fill):
        return np.full(shape, fill) if v is None else np.asarray(v, float).reshape(shape)

    return schemes.SchemeNumbers(table(before, 0.01), table(s1, 1.0), table(s2, 0.02), table(s3, 0.02),
                                 np.ones(shape), np.ones(shape, bool) if trained1 is None else np.asarray(trained1),
                                 scheme1_motion=table(motion1, 0.001))


def improved(k: int, n: int = 15) -> np.ndarray:
    """E_after for n systems with E_before = 0.01: the first k improved (ratio 0.5), the others not (ratio 2)."""
    return np.array([0.005] * k + [0.02] * (n - k))


def test_closed_loop_schemes_scheme1():
    assert verdicts(schemes.claims(scheme_numbers()))[0] is True  # every error = the target's size
    s1 = np.ones(15)
    s1[3] = 0.0999  # one system draws
    assert verdicts(schemes.claims(scheme_numbers(s1=s1)))[0] is False
    s1[3] = 0.1  # at the threshold: does not draw
    assert verdicts(schemes.claims(scheme_numbers(s1=s1)))[0] is True
    s1[3] = np.nan  # its closed loop blew up: draws nothing
    assert verdicts(schemes.claims(scheme_numbers(s1=s1)))[0] is True
    # premise: some scheme-1 training finished (every one diverging is no attempt to draw)
    c = schemes.claims(scheme_numbers(s1=np.full(15, np.nan), trained1=np.zeros((3, 5), bool)))
    assert c[0].holds is None and "diverged" in c[0].evidence
    one = np.zeros((3, 5), bool)
    one[2, 4] = True
    assert verdicts(schemes.claims(scheme_numbers(s1=np.full(15, np.nan), trained1=one)))[0] is True


def scheme1_rest(**kw) -> bool | None:
    return verdicts(schemes.claims(scheme_numbers(**kw)))[1]


def test_closed_loop_schemes_scheme1_comes_to_rest():
    # target mean square 1 m²: at rest when the CMP's motion mean square < 0.01 m², in every finished system
    assert scheme1_rest() is True
    m = np.full(15, 0.001)
    m[4] = 0.0099
    assert scheme1_rest(motion1=m) is True
    m[4] = 0.01  # at the bound: moving
    assert scheme1_rest(motion1=m) is False
    m[4] = np.nan  # its closed loop blew up: not at rest
    assert scheme1_rest(motion1=m) is False
    trained = np.ones((3, 5), bool)
    trained.ravel()[4] = False  # ... unless its scheme-1 training diverged: it does not count
    assert scheme1_rest(motion1=m, trained1=trained) is True
    # relative to each system's target mean square
    c = schemes.claims(schemes.SchemeNumbers(*(np.full((1, 2), v) for v in (0.01, 1.0, 0.02, 0.02)),
                                             np.array([[1.0, 4.0]]), np.ones((1, 2), bool),
                                             scheme1_motion=np.array([[0.005, 0.039]])))
    assert c[1].holds is True and "2 of 2" in c[1].evidence
    # premises: some scheme-1 training finished; the motion was measured (a run made before it was is not testable)
    assert scheme1_rest(trained1=np.zeros((3, 5), bool)) is None
    old = schemes.SchemeNumbers(*(np.full((3, 5), v) for v in (0.01, 1.0, 0.02, 0.02, 1.0)), np.ones((3, 5), bool))
    c = schemes.claims(old)
    assert c[1].holds is None and "not measured" in c[1].evidence


def test_closed_loop_schemes_improve_only_some():
    # the paper's 7 and 6 of 15
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(7), s3=improved(6))))[2:] == [True, True]
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(8), s3=improved(15))))[2:] == [False, False]  # most
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(0), s3=improved(1))))[2:] == [False, True]
    # ratio = 1 is not an improvement; a diverged scheme (NaN) is none either
    s2 = improved(7)
    s2[8:] = [0.01, np.nan, 0.01, 0.02, 0.02, 0.02, 0.02]
    assert verdicts(schemes.claims(scheme_numbers(s2=s2)))[2] is True
    # half of an even count is the edge: 7 of 14 holds, 8 of 14 does not (one preliminary training diverged)
    before = np.full(15, 0.01)
    before[14] = np.nan
    edge = schemes.claims(scheme_numbers(before=before, s2=improved(7), s3=improved(8)))
    assert verdicts(edge)[2:] == [True, False] and "7 of 14" in edge[2].evidence
    # a system whose preliminary training diverged counts neither as improved (its ratio is NaN) ...
    s3 = improved(7)
    s3[14] = 0.005
    assert verdicts(schemes.claims(scheme_numbers(before=before, s3=s3)))[3] is True  # 7 of 14, not 8
    # ... nor in the denominator: 7 of 13 is more than half (7 of 15 would not be)
    before[13] = np.nan
    c = schemes.claims(scheme_numbers(before=before, s2=improved(7)))
    assert c[2].holds is False and "7 of 13" in c[2].evidence


def test_closed_loop_schemes_need_two_systems():
    one = dict(shape=(1, 1), s2=[0.005], s3=[0.02])
    assert verdicts(schemes.claims(scheme_numbers(**one))) == [True, True, None, None]
    two = dict(shape=(1, 2), s2=[0.005, 0.02], s3=[0.005, 0.005])
    assert verdicts(schemes.claims(scheme_numbers(**two)))[2:] == [True, False]  # 1 of 2 (edge), 2 of 2
    c = schemes.claims(schemes.SchemeNumbers(np.array([[np.nan, 0.01]]), np.ones((1, 2)), np.full((1, 2), 0.005),
                                             np.full((1, 2), 0.005), np.ones((1, 2)), np.ones((1, 2), bool),
                                             note=" (1 preliminary training(s) diverged: planted)"))
    assert verdicts(c)[2:] == [None, None] and "diverged" in c[2].evidence


# -- locomotion-closed-loop-20: [some succeed, consistent with 8/20] --------------------------------------------------
def loco(successes: int, n: int = 20, not_forward: int = 0) -> list[Claim]:
    speed = np.array([0.5] * n + [0.0] * not_forward)
    ok = np.array([True] * successes + [False] * (n - successes) + [False] * not_forward)
    return locl.claims(locl.ClosedLoopCounts(speed, ok))


def test_locomotion_closed_loop_claims():
    # Binomial(20, 0.4): central 95 % is 4…12 (tests/experiments/test_locomotion_experiments.py has the hand values)
    assert verdicts(loco(8)) == [True, True]
    assert verdicts(loco(4)) == [True, True]
    assert verdicts(loco(3)) == [True, False]
    assert verdicts(loco(12)) == [True, True]
    assert verdicts(loco(13)) == [True, False]
    assert verdicts(loco(0)) == [False, False]
    # only agents that learned forward behaviour count ("20 agents that learned forward behavior")
    c = loco(8, 20, not_forward=1)
    assert verdicts(c) == [True, True]
    assert "Binomial(20, 0.4): 4–12" in c[1].evidence and "21 evaluated" in c[1].evidence
    # the statement is the same whatever the seed's count (an aggregate over seeds matches claims by it)
    assert [x.claim for x in loco(8, 19)] == [x.claim for x in c] == [x.claim for x in loco(0, 0, not_forward=3)]
    odd = locl.claims(locl.ClosedLoopCounts(np.array([0.0, 0.5, 0.5]), np.array([True, False, False])))
    assert verdicts(odd)[0] is False  # a "success" without forward motion is none
    # premises: some agent moves forward; enough agents that the interval excludes a count
    assert verdicts(loco(0, 0, not_forward=3)) == [None, None]
    assert verdicts(loco(1, 2)) == [True, None]  # Binomial(2, 0.4): 0…2, every count


# -- locomotion-headwind: [near with and without wind, drops and recovers, interpolates, far below −1] ---------------
HW_WINDS = np.round(np.arange(-2.0, 1.0 + 1e-9, 0.05), 2)


def headwind(calm=1.0, early=0.8, late=1.0, blocks=(5, 5, 5), speed: dict | None = None,
             strong: float = 0.2) -> list[bool | None]:
    v = np.where(HW_WINDS < -1, strong, 1.0)  # target 1 m/s, met for F ∈ [−1, 1]
    for f, s in (speed or {}).items():
        v[np.isclose(HW_WINDS, f)] = s
    phases = {"calm": calm, "windy_early": early, "windy_late": late}
    return verdicts(hw.claims(hw.HeadwindNumbers(1.0, phases, dict(zip(hw.PHASES, blocks, strict=True)), HW_WINDS,
                                                 v)))


def test_locomotion_headwind_near_the_target():
    assert headwind() == [True, True, True, True]
    assert headwind(calm=1.25, early=0.8, late=1.0)[0] is True  # 25 %: the edge, inclusive
    assert headwind(calm=1.0, early=0.7, late=0.75)[0] is True
    assert headwind(calm=1.26)[0] is False
    assert headwind(late=0.74, early=0.7)[0] is False
    assert headwind(late=float("nan"))[0] is False  # diverged
    assert headwind(blocks=(5, 5, 0))[:2] == [None, None]  # no block in the windy phase's second half
    assert headwind(blocks=(5, 0, 5))[:2] == [True, None]


def test_locomotion_headwind_drops_and_recovers():
    assert headwind(calm=1.0, early=1.0, late=1.0)[1] is False  # no drop
    assert headwind(calm=1.0, early=0.9, late=0.85)[1] is False  # keeps slowing: no recovery
    assert headwind(calm=1.2, early=0.8, late=0.9)[1] is False  # recovers, not to the windless speed
    assert headwind(calm=1.25, early=0.8, late=1.0)[1] is True  # |1.0 − 1.25| = 0.25 v_tgt: the edge
    assert headwind(calm=1.0, early=1.05, late=1.1)[1] is False  # faster right after the wind starts


def test_locomotion_headwind_untrained_winds():
    assert headwind(speed={0.5: 1.5})[2] is True  # 50 %: the edge, inclusive
    assert headwind(speed={0.5: 0.5})[2] is True
    assert headwind(speed={0.5: 1.51})[2] is False
    assert headwind(speed={-0.95: np.nan})[2] is False  # diverged
    assert headwind(speed={1.0: 5.0})[2] is True  # F = 1 is outside −1 < F < 1
    # far below −1: mean error over F < −1 greater than 50 % (farther than "somewhat close")
    assert headwind(strong=0.5)[3] is False  # mean error exactly 0.5
    assert headwind(strong=0.49)[3] is True
    assert headwind(strong=1.0, speed={-1.5: np.nan})[3] is True  # a blow-up is far
    assert headwind(strong=1.3)[3] is False  # close to the target
    # premise of both: the trained F = 0 and −1 are near the target in the sweep (within 25 %)
    assert headwind(speed={0.0: 1.26})[2:] == [None, None]
    assert headwind(speed={-1.0: 0.75})[2:] == [True, True]
    assert headwind(speed={-1.0: 0.74})[2:] == [None, None]


# -- locomotion-perturbation: [open falls, closed falls, almost the same] --------------------------------------------
def lp(rate_open, rate_closed, open_moves=True, closed_ok=True) -> list[bool | None]:
    return verdicts(lopert.claims(lopert.PerturbationRates(np.array(lopert.SIGMAS), np.asarray(rate_open, float),
                                                           np.asarray(rate_closed, float), open_moves, closed_ok)))


FALLING = np.array([1, 1, 1, 1, 1, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4])


def test_locomotion_perturbation_claims():
    assert lp(FALLING, FALLING) == [True, True, True]
    flat = np.full(11, 0.7)
    assert lp(flat, FALLING)[:2] == [False, True]  # mean over σ ≥ 0.6 equals the mean over σ ≤ 0.4
    rising = FALLING[::-1]
    assert lp(FALLING, rising)[:2] == [True, False]
    # almost the same: |difference| ≤ 0.2 at every σ, inclusive (the Lissajous rule: claim_rules.almost_same_rates)
    assert lp(FALLING, FALLING - 0.2)[2] is True
    assert lp(FALLING, FALLING - 0.21)[2] is False
    one_off = FALLING.copy()
    one_off[8] -= 0.3  # one σ off by 0.3, the mean |difference| only 0.027: not almost the same
    assert lp(FALLING, one_off)[2] is False
    # premises: the closed loop perturbed succeeded; the open loop moved forward; some σ gives a rate < 1
    assert lp(FALLING, FALLING, closed_ok=False) == [True, None, None]
    assert lp(FALLING, FALLING, open_moves=False) == [None, True, None]
    assert lp(np.ones(11), np.ones(11)) == [False, False, None]
    almost_ones = np.ones(11)
    almost_ones[10] = 0.9
    assert lp(np.ones(11), almost_ones) == [False, True, True]


def standstill(early, late, *, runs=100, moving=True, diverged="") -> list[bool | None]:
    return verdicts(lopert.standstill_claims(lopert.StandstillNumbers("FL (closed loop)", np.asarray(early, float),
                                                                      np.asarray(late, float), runs, moving,
                                                                      diverged)))


def test_locomotion_some_perturbed_runs_suddenly_came_to_a_standstill():
    # speeds / the speed before: early over the first 10 % of the run after the perturbation, late over its last half
    assert standstill([0.3], [0.05]) == [True]
    assert standstill([0.3, 0.9], [0.5, 0.4]) == [False]  # slowed, but did not stop
    # standstill: |late| ≤ 0.1 (inclusive), backwards too; a run going backwards faster is no standstill
    assert standstill([0.3], [0.1]) == [True]
    assert standstill([0.3], [0.1001]) == [False]
    assert standstill([0.3], [-0.1]) == [True]
    assert standstill([0.3], [-0.2]) == [False]
    # suddenly: already below half the speed before early on (strict); a gradual stop is not sudden
    assert standstill([0.4999], [0.0]) == [True]
    assert standstill([0.5], [0.0]) == [False]
    # a diverged run came to no standstill; a run that returned (late ≥ 0.7) is not one that did not
    assert standstill([np.nan], [np.nan]) == [False]
    assert standstill([0.1, 0.2], [0.7, 0.4]) == [False]
    assert standstill([0.1, 0.2], [0.69, 0.05]) == [True]
    # premises: some run did not return; the agents move forward before
    c = lopert.standstill_claims(lopert.StandstillNumbers("SWG (open loop)", np.array([0.1]), np.array([0.8]), 50,
                                                          True))
    assert c[0].holds is None and "50 perturbed runs returned" in c[0].evidence
    assert standstill(np.zeros(0), np.zeros(0)) == [None]
    assert standstill([0.3], [0.05], moving=False) == [None]
    assert standstill(np.zeros(0), np.zeros(0), diverged="planted") == [None]


def test_locomotion_headwind_claims_read_the_sweep_relative_to_the_trained_wind():
    """The authors' −15 N protocol: the same rules with F scaled by 15 (trained 0 and −15, unlearned (−15, 15))."""
    winds = HW_WINDS * 15
    v = np.where(winds < -15, 0.2, 1.0)
    phases = {"calm": 1.0, "windy_early": 0.8, "windy_late": 1.0}
    blocks = dict(zip(hw.PHASES, (5, 5, 5), strict=True))
    out = hw.claims(hw.HeadwindNumbers(1.0, phases, blocks, winds, v, -15.0))
    assert verdicts(out) == [True, True, True, True]
    assert "F = −15" in out[0].claim and "−15 < F_wind < 15" in out[2].claim and "F_wind < −15" in out[3].claim
    v2 = v.copy()
    v2[np.isclose(winds, -15.0)] = 2.0  # the trained −15 N missed: the sweep claims lose their premise
    assert verdicts(hw.claims(hw.HeadwindNumbers(1.0, phases, blocks, winds, v2, -15.0)))[2:] == [None, None]
    v3 = v.copy()
    v3[np.isclose(winds, -7.5)] = 1.51  # an unlearned wind inside (−15, 15) too far
    assert verdicts(hw.claims(hw.HeadwindNumbers(1.0, phases, blocks, winds, v3, -15.0)))[2] is False
    with pytest.raises(ValueError, match="the trained headwind must be < 0 N, got 1.0"):
        hw.claims(hw.HeadwindNumbers(1.0, phases, blocks, winds, v, 1.0))
