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


# -- lissajous-bifurcation: [period 1 at the trained F, more diverse than trained] ------------------------------------
WINDS = np.round(np.arange(-1.0, 2.0001, 0.05), 10)


def bifurcation(per: dict[float, int] | None = None, nmse=(0.05, 0.05)) -> list[bool | None]:
    period = np.ones(len(WINDS), dtype=int)
    for f, m in (per or {}).items():
        period[np.isclose(WINDS, f)] = m
    return verdicts(lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, period, {0.0: nmse[0], 1.0: nmse[1]})))


def test_lissajous_bifurcation_claims():
    assert bifurcation() == [True, False]  # period 1 everywhere: nothing more diverse than trained
    assert bifurcation({0.5: 2}) == [True, True]  # a period-2 orbit at an untrained value
    assert bifurcation({1.5: 0}) == [True, True]  # an aperiodic one
    assert bifurcation({0.5: -1}) == [True, False]  # a blow-up is not an embedded dynamics
    # period 1 (one SWG period), not any period: the trained values at period 8 do not hold, and then "more
    # diverse than trained" is not testable
    assert bifurcation({0.0: 8}) == [False, None]
    assert bifurcation({1.0: 2, 0.5: 0}) == [False, None]
    assert bifurcation({1.0: 0}) == [False, None]
    # premise: the system learned to switch (draws its curve at F = 0 and 1, < 0.1 × target mean square)
    assert bifurcation({0.5: 2}, nmse=(0.1, 0.05)) == [None, None]
    assert bifurcation({0.5: 2}, nmse=(0.05, float("nan"))) == [None, None]
    assert bifurcation({0.5: 2}, nmse=(0.0999, 0.0999)) == [True, True]
    missing = lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS, np.ones(len(WINDS), int), {0.0: 0.05}))
    assert verdicts(missing) == [None, None]
    with pytest.raises(ValueError, match="trained value 1.0"):
        lsw.bifurcation_claims(lsw.BifurcationNumbers(WINDS[:40], np.ones(40, int), {0.0: 0.05, 1.0: 0.05}))


# -- lissajous-timing: [random timing converges for every n, fixed timing fails for a band] --------------------------
def timing(fixed=(), rand=()) -> list[bool | None]:
    """Every n draws the target (0.05) except the planted (index or slice, value) pairs."""
    f, r = np.full(100, 0.05), np.full(100, 0.05)
    for arr, planted in ((f, fixed), (r, rand)):
        for where, value in planted:
            arr[where] = value
    return verdicts(lsw.timing_claims(lsw.TimingNumbers(f, r, last=5)))


def test_lissajous_timing_random_converges_for_every_n():
    assert timing()[0] is True
    assert timing(rand=[(99, 0.0999)])[0] is True
    assert timing(rand=[(99, 0.1)])[0] is False  # one n that does not draw the target
    assert timing(rand=[(50, np.inf)])[0] is False  # diverged
    # compared with the target, not with the n = 0 run: identical runs that all miss the target are not testable
    assert timing(rand=[(slice(None), 0.3)])[0] is None
    assert timing(rand=[(0, 0.1)])[0] is None  # premise: it switches at n = 0 (its n = 0 run draws the target)


def test_lissajous_timing_fixed_fails_for_a_band():
    band = slice(22, 70)  # the paper's 22 ≤ n ≤ 69
    assert timing()[1] is False  # every n converges
    assert timing(fixed=[(band, 0.5)])[1] is True
    assert timing(fixed=[(slice(30, 35), 0.5)])[1] is True  # 5 consecutive n: the edge
    assert timing(fixed=[(slice(30, 34), 0.5)])[1] is False  # 4
    assert timing(fixed=[(slice(10, 14), 0.5), (slice(20, 24), 0.5)])[1] is False  # 8 fail, no 5 in a row
    assert timing(fixed=[(slice(40, 45), np.inf)])[1] is True  # diverged runs fail
    assert timing(fixed=[(slice(40, 45), 0.1)])[1] is True  # 0.1 is not below 0.1: they fail
    assert timing(fixed=[(slice(40, 45), 0.0999)])[1] is False
    # premise: the fixed-timing system switches at its trained n = 0
    assert timing(fixed=[(band, 0.5), (0, 0.1)])[1] is None
    assert timing(fixed=[(band, 0.5), (0, 0.0999)])[1] is True


# -- closed-loop-schemes: [scheme 1 draws nothing, scheme 2 / scheme 3 improve only some] ------------------------------
def scheme_numbers(*, before=None, s1=None, s2=None, s3=None, trained1=None, shape=(3, 5)) -> schemes.SchemeNumbers:
    def table(v, fill):
        return np.full(shape, fill) if v is None else np.asarray(v, float).reshape(shape)

    return schemes.SchemeNumbers(table(before, 0.01), table(s1, 1.0), table(s2, 0.02), table(s3, 0.02),
                                 np.ones(shape), np.ones(shape, bool) if trained1 is None else np.asarray(trained1))


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


def test_closed_loop_schemes_improve_only_some():
    # the paper's 7 and 6 of 15
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(7), s3=improved(6))))[1:] == [True, True]
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(8), s3=improved(15))))[1:] == [False, False]  # most
    assert verdicts(schemes.claims(scheme_numbers(s2=improved(0), s3=improved(1))))[1:] == [False, True]
    # ratio = 1 is not an improvement; a diverged scheme (NaN) is none either
    s2 = improved(7)
    s2[8:] = [0.01, np.nan, 0.01, 0.02, 0.02, 0.02, 0.02]
    assert verdicts(schemes.claims(scheme_numbers(s2=s2)))[1] is True
    # half of an even count is the edge: 7 of 14 holds, 8 of 14 does not (one preliminary training diverged)
    before = np.full(15, 0.01)
    before[14] = np.nan
    edge = schemes.claims(scheme_numbers(before=before, s2=improved(7), s3=improved(8)))
    assert verdicts(edge)[1:] == [True, False] and "7 of 14" in edge[1].evidence
    # a system whose preliminary training diverged counts neither as improved (its ratio is NaN) ...
    s3 = improved(7)
    s3[14] = 0.005
    assert verdicts(schemes.claims(scheme_numbers(before=before, s3=s3)))[2] is True  # 7 of 14, not 8
    # ... nor in the denominator: 7 of 13 is more than half (7 of 15 would not be)
    before[13] = np.nan
    c = schemes.claims(scheme_numbers(before=before, s2=improved(7)))
    assert c[1].holds is False and "7 of 13" in c[1].evidence


def test_closed_loop_schemes_need_two_systems():
    one = dict(shape=(1, 1), s2=[0.005], s3=[0.02])
    assert verdicts(schemes.claims(scheme_numbers(**one))) == [True, None, None]
    two = dict(shape=(1, 2), s2=[0.005, 0.02], s3=[0.005, 0.005])
    assert verdicts(schemes.claims(scheme_numbers(**two)))[1:] == [True, False]  # 1 of 2 (edge), 2 of 2
    c = schemes.claims(schemes.SchemeNumbers(np.array([[np.nan, 0.01]]), np.ones((1, 2)), np.full((1, 2), 0.005),
                                             np.full((1, 2), 0.005), np.ones((1, 2)), np.ones((1, 2), bool),
                                             note=" (1 preliminary training(s) diverged: planted)"))
    assert verdicts(c)[1:] == [None, None] and "diverged" in c[1].evidence


# -- locomotion-closed-loop-20: [some succeed, consistent with 8/20] --------------------------------------------------
def loco(successes: int, n: int = 20, not_forward: int = 0) -> list[Claim]:
    speed = np.array([0.5] * n + [0.0] * not_forward)
    ok = np.array([True] * successes + [False] * (n - successes) + [False] * not_forward)
    return locl.claims(locl.ClosedLoopCounts(speed, ok))


def test_locomotion_closed_loop_claims():
    # Binomial(20, 0.4): central 95 % is 4…12 (tests/test_locomotion_experiments.py has the hand values)
    assert verdicts(loco(8)) == [True, True]
    assert verdicts(loco(4)) == [True, True]
    assert verdicts(loco(3)) == [True, False]
    assert verdicts(loco(12)) == [True, True]
    assert verdicts(loco(13)) == [True, False]
    assert verdicts(loco(0)) == [False, False]
    # only agents that learned forward behaviour count ("20 agents that learned forward behavior")
    c = loco(8, 20, not_forward=1)
    assert verdicts(c) == [True, True] and "Binomial(20, 0.4)" in c[1].claim and "21 evaluated" in c[1].evidence
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
    # almost the same: mean |difference| ≤ 0.15, inclusive (1 − 0.85 = 0.15000000000000002 in floats)
    assert lp(FALLING, FALLING - 0.15)[2] is True
    assert lp(FALLING, FALLING - 0.16)[2] is False
    # premises: the closed loop perturbed succeeded; the open loop moved forward; some σ gives a rate < 1
    assert lp(FALLING, FALLING, closed_ok=False) == [True, None, None]
    assert lp(FALLING, FALLING, open_moves=False) == [None, True, None]
    assert lp(np.ones(11), np.ones(11)) == [False, False, None]
    almost_ones = np.ones(11)
    almost_ones[10] = 0.9
    assert lp(np.ones(11), almost_ones) == [False, True, True]


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
