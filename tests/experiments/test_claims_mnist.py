"""Every claim of the five MNIST experiments on planted numbers: where it holds, where it fails, at its boundary (the
edge and just past it) and where its premise fails (not testable, holds = None); the separation scores the PCA
claims rest on against an independent numpy recomputation; the label maps' start point and width by hand.

The expected verdicts are written by hand from the planted numbers and the paper's sentence each claim tests
(quoted in the docstring of each experiment's ``claims`` function); none is computed by the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from bptsb_ros.analysis import separation
from bptsb_ros.experiments import mnist_drawing as draw
from bptsb_ros.experiments import mnist_labelmap as lm
from bptsb_ros.experiments import mnist_pca as pca
from bptsb_ros.experiments import mnist_readout as ro
from bptsb_ros.experiments import mnist_specific100 as sp
from bptsb_ros.experiments.mnist_claims import Check, Separation, Skill, all_of, learned
from bptsb_ros.experiments.result import Claim


def verdicts(claims: list[Claim]) -> list[bool | None]:
    assert all(isinstance(c, Claim) and c.evidence.strip() for c in claims)
    return [c.holds for c in claims]


# chance 0.1 on 900 samples: the learned margin is 0.1 + 3·√(0.1·0.9/900) = 0.1 + 3·0.01 = 0.13 (by hand)
GOOD = Skill(0.5, 900, 0.1)
EDGE = Skill(0.13, 900, 0.1)  # at the margin: not learned (strictly above)
PAST = Skill(0.1301, 900, 0.1)


# -- shared rules -------------------------------------------------------------------------------------------------
def test_learned_is_strictly_above_chance_by_three_standard_errors():
    assert learned(GOOD) and learned(PAST) and not learned(EDGE)
    # 100 samples, chance 0.1: 0.1 + 3·0.03 = 0.19
    assert not learned(Skill(0.19, 100, 0.1)) and learned(Skill(0.2, 100, 0.1))
    # chance 0.5 on 400: 0.5 + 3·√(0.25/400) = 0.5 + 3·0.025 = 0.575
    assert not learned(Skill(0.575, 400, 0.5)) and learned(Skill(0.5751, 400, 0.5))
    assert not learned(Skill(float("nan"), 900, 0.1)) and not learned(Skill(1.0, 0, float("nan")))
    s = Skill.of(0.75, np.array([0, 0, 0, 1]))  # the most common label: 3 of 4
    assert (s.n, s.chance) == (4, 0.75)


def test_all_of_is_a_three_valued_and():
    t, f, u = Check("a", True), Check("b", False), Check("c", True, "c did not learn")
    assert all_of("x", [t, t]).holds is True
    assert all_of("x", [t, u]).holds is None and "c did not learn" in all_of("x", [t, u]).evidence
    assert all_of("x", [f, u]).holds is False and "c did not learn" in all_of("x", [f, u]).evidence
    assert all_of("x", [Check("d", False, "d did not learn"), t]).holds is None  # an untestable check never refutes
    with pytest.raises(ValueError, match="no comparison"):
        all_of("x", [])


# -- mnist-drawing: [MLP < LIL (both bodies), N_mov 65 < 17 (both brains)] ----------------------------------------
MSE = {("lil", 17): 0.02, ("mlp", 17): 0.01, ("lil", 65): 0.015, ("mlp", 65): 0.008}


def drawing(mse: dict | None = None, skill: dict | None = None) -> list[bool | None]:
    m = {**MSE, **(mse or {})}
    s = {k: GOOD for k in MSE} | (skill or {})
    return verdicts(draw.claims(draw.DrawingNumbers(m, s)))


def test_mnist_drawing_claims():
    assert drawing() == [True, True]
    assert drawing({("mlp", 17): 0.02}) == [False, True]  # equal is not smaller
    assert drawing({("mlp", 17): 0.0199999}) == [True, True]
    assert drawing({("mlp", 65): 0.015}) == [False, False]  # the 65 body: MLP = LIL, and MLP 65 > MLP 17
    assert drawing({("lil", 65): 0.008}) == [False, True]  # the 65 body: LIL = MLP
    assert drawing({("lil", 65): 0.0080001}) == [True, True]
    assert drawing({("lil", 65): 0.02}) == [True, False]  # LIL: 65 = 17
    assert drawing({("lil", 65): 0.0199999}) == [True, True]
    assert drawing({("mlp", 65): 0.01}) == [True, False]  # MLP: 65 = 17
    assert drawing({("mlp", 65): float("nan")}) == [False, False]  # a NaN error is never smaller


def test_mnist_drawing_premise_both_systems_learned():
    # LIL 17 did not learn: its two comparisons are not testable, the other two hold
    c = draw.claims(draw.DrawingNumbers(MSE, {k: GOOD for k in MSE} | {("lil", 17): EDGE}))
    assert verdicts(c) == [None, None]
    assert all("LIL + multiple-circle (N_mov 17)" in x.evidence and "did not learn" in x.evidence for x in c)
    assert drawing(skill={("lil", 17): PAST}) == [True, True]
    # an untestable comparison does not hide a refuting one
    assert drawing({("mlp", 65): 0.02}, {("lil", 17): EDGE}) == [False, False]
    assert drawing(skill={("mlp", 65): Skill(float("nan"), 900, 0.1)}) == [None, None]


# -- mnist-pca: [each output classifies, body separates more, especially 5/7/8] ----------------------------------
def sep(sil: float, per: dict[int, float] | None = None, probe: float = 0.5) -> Separation:
    labels = [sil] * 10
    for d, v in (per or {}).items():
        labels[d] = v
    return Separation(sil, tuple(labels), Skill(probe, 900, 0.1))


#: the body's default per-digit silhouettes: 0.2, and 0.4 at the emphasised digits 5, 7, 8 (gains there 0.35 against
#: 0.15 at the other seven digits over the brain's 0.05)
BODY_578 = {5: 0.4, 7: 0.4, 8: 0.4}


def pcav(brain: Separation | None = None, body: Separation | None = None, drawing_skill: Skill = GOOD):
    return verdicts(pca.claims(pca.PcaNumbers(drawing_skill, brain or sep(0.05), body or sep(0.2, BODY_578))))


def gains(emphasised: float, others: list[float]) -> tuple[Separation, Separation]:
    """Brain 0 at every digit; body = the planted gain: ``emphasised`` at 5, 7 and 8, ``others`` at 0-4, 6, 9."""
    per = dict(zip((0, 1, 2, 3, 4, 6, 9), others)) | {5: emphasised, 7: emphasised, 8: emphasised}
    return sep(0.0, {d: 0.0 for d in range(10)}), sep(0.2, per)


def test_mnist_pca_claims():
    assert pcav() == [True, True, True]
    # classified: the 2-D probe of each output beats chance by the margin (0.13 on 900, chance 0.1)
    assert pcav(brain=sep(0.05, probe=0.13))[0] is False
    assert pcav(brain=sep(0.05, probe=0.1301))[0] is True
    assert pcav(body=sep(0.2, BODY_578, probe=0.13))[0] is False
    # more separation in the body: silhouette (2-D) body > brain, strictly
    assert pcav(body=sep(0.05, BODY_578))[1] is False
    assert pcav(body=sep(0.0500001, BODY_578))[1] is True
    assert pcav(brain=sep(0.3, {d: 0.0 for d in range(10)}))[1:] == [False, True]  # overall worse, 5/7/8 gain most
    assert pcav(body=sep(float("nan"), BODY_578))[1] is None  # undefined silhouette (one label)


def test_mnist_pca_especially_5_7_8_is_a_larger_gain_than_at_the_other_digits():
    # the body beats the brain at all ten digits by the same 0.15: nothing is "especially" separated
    assert pcav(body=sep(0.2))[1:] == [True, False]
    # ... or by more at every other digit than at 8
    assert pcav(body=sep(0.2, {5: 0.4, 7: 0.4, 8: 0.1}))[2] is False
    # above the median gain of the other seven digits, strictly: others 0, 0, 0, 0.1, 0.5, 0.5, 0.5 (median 0.1,
    # mean 0.229, maximum 0.5, minimum 0)
    spread = [0.0, 0.0, 0.0, 0.1, 0.5, 0.5, 0.5]
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(0.1, spread))))[2] is False  # at the median
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(0.1000001, spread))))[2] is True
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(0.15, spread))))[2] is True  # below mean and maximum
    # others 0.1 ×3 and 0.3 ×4 (median 0.3, minimum 0.1): 0.2 is above the minimum only
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(0.2, [0.1, 0.1, 0.1, 0.3, 0.3, 0.3, 0.3]))))[2] is False
    # one emphasised digit below the median refutes it
    brain, body = gains(0.3, [0.1] * 7)
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, brain, sep(0.2, dict(enumerate(body.per_label)) | {7: 0.1}))))[2] \
        is False
    # positive: above the others' median but the body still worse than the brain at 5, 7, 8
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(0.0, [-0.3] * 7))))[2] is False
    assert verdicts(pca.claims(pca.PcaNumbers(GOOD, *gains(1e-6, [-0.3] * 7))))[2] is True
    c = pca.claims(pca.PcaNumbers(GOOD, *gains(0.15, spread)))[2]
    assert "digit 5: gain 0.15" in c.evidence and "median gain 0.1" in c.evidence


def test_mnist_pca_premises():
    c = pca.claims(pca.PcaNumbers(EDGE, sep(0.05), sep(0.2, BODY_578)))
    assert verdicts(c) == [None, None, None] and all("did not learn to draw" in x.evidence for x in c)
    assert pcav(drawing_skill=PAST) == [True, True, True]
    # a digit without test images (any of the ten: the others' median needs them all)
    assert pcav(body=sep(0.2, BODY_578 | {8: float("nan")}), brain=sep(0.05, {8: float("nan")}))[2] is None
    c = pca.claims(pca.PcaNumbers(GOOD, sep(0.05, {2: float("nan")}), sep(0.2, BODY_578 | {2: float("nan")})))
    assert c[2].holds is None and "no test image of digit 2" in c[2].evidence


# -- mnist-labelmap: [joined smaller (mean), largest not joined / smallest joined, others mostly original] ----------
JOINED = np.array([False] * 12 + [True] * 4)  # multiple circle N_mov 17: 12 placed masses, then 4 joined to the CMP


def maps(others, joined, centre=None, boundary=None, regions=None) -> lm.LabelMapNumbers:
    size = np.array(list(others) + list(joined), float)
    extra = {k: np.asarray(v, float) for k, v in (("boundary", boundary), ("regions", regions)) if v is not None}
    return lm.LabelMapNumbers(size, JOINED.copy(), np.arange(20, 36), np.arange(10) if centre is None else centre,
                              **extra)


def labelmap(others, joined, centre=None) -> list[bool | None]:
    """The first three claims (sizes); the maps' intricacy is not planted here (its claim: not testable)."""
    got = verdicts(lm.claims(maps(others, joined, centre)))
    assert got[3] is None
    return got[:3]


def test_mnist_labelmap_claims():
    others = [0.8] * 11 + [0.9]
    assert labelmap(others, [0.6, 0.65, 0.7, 0.55]) == [True, True, True]
    assert labelmap([0.8] * 12, [0.8] * 4) == [False, False, True]  # equal means; a tie across the kinds
    # joined mean just below the others'; the maximum 0.8 is shared by three joined masses: refuted
    assert labelmap([0.8] * 12, [0.8, 0.8, 0.8, 0.8 - 1e-6]) == [True, False, True]
    assert labelmap([0.8] * 12, [0.95, 0.5, 0.5, 0.5]) == [True, False, True]  # the largest is joined
    # the smallest (0.4) is not joined, and it is not mostly its original label
    assert labelmap([0.8] * 11 + [0.4], [0.6] * 4) == [True, False, False]
    # mostly: size > 1/2, strictly, for every mass not joined
    assert labelmap([0.9] * 11 + [0.5], [0.3, 0.35, 0.4, 0.2]) == [True, True, False]
    assert labelmap([0.9] * 11 + [0.500001], [0.3, 0.35, 0.4, 0.2]) == [True, True, True]


def test_mnist_labelmap_extremes_ties():
    # a float tie (sizes equal up to rounding) between a joined and a not-joined mass at the maximum refutes it
    assert labelmap([0.8] * 11 + [0.9], [0.9 + 1e-12, 0.5, 0.5, 0.5])[1] is False
    assert labelmap([0.8] * 11 + [0.9], [0.9 - 1e-12, 0.5, 0.5, 0.5])[1] is False  # the joined one a hair below
    assert labelmap([0.8] * 11 + [0.9], [0.9 - 1e-6, 0.5, 0.5, 0.5])[1] is True
    assert labelmap([0.8] * 11 + [0.5 + 1e-12], [0.6, 0.5, 0.5, 0.6])[1] is False  # tie at the minimum
    assert labelmap([0.8] * 11 + [0.5 + 1e-6], [0.6, 0.5, 0.5, 0.6])[1] is True
    c = lm.claims(maps([0.8] * 11 + [0.9], [0.6, 0.65, 0.7, 0.55]))
    assert "mass 31 (0.9, not joined)" in c[1].evidence and "mass 35 (0.55, joined)" in c[1].evidence


def test_mnist_labelmap_premise():
    others, joined = [0.8] * 11 + [0.9], [0.6, 0.65, 0.7, 0.55]
    centre = np.arange(10)
    centre[3] = 5  # the best 3 draws a 5: its maps are not around a drawing of its own digit
    c = lm.claims(maps(others, joined, centre, np.full(16, 0.2), np.full(16, 2.0)))
    assert verdicts(c) == [None] * 4 and all("digit 3 → 5" in x.evidence for x in c)
    assert labelmap(others, joined, centre[:9] * 0 + np.arange(9)) == [None, None, None]  # fewer than 10 digits
    one_kind = lm.LabelMapNumbers(np.full(16, 0.8), np.zeros(16, bool), np.arange(20, 36), np.arange(10),
                                  np.full(16, 0.2), np.full(16, 2.0))
    assert verdicts(lm.claims(one_kind)) == [None] * 4
    assert verdicts(lm.claims(lm.LabelMapNumbers(np.full(16, 0.8), np.ones(16, bool), np.arange(20, 36),
                                                 np.arange(10), np.full(16, 0.2), np.full(16, 2.0)))) == [None] * 4


def test_mnist_labelmap_maps_of_the_masses_joined_to_the_cmp_are_intricate():
    others, joined = [0.8] * 11 + [0.9], [0.6, 0.65, 0.7, 0.55]

    def intricate(boundary, regions, centre=None):
        return lm.claims(maps(others, joined, centre, boundary, regions))[3]

    # joined masses (the last 4): boundary 0.3, 4 regions; the others 0.1, 2 regions
    b, r = [0.1] * 12 + [0.3] * 4, [2.0] * 12 + [4.0] * 4
    c = intricate(b, r)
    assert c.holds is True and "boundary share: joined 0.3, others 0.1" in c.evidence
    assert intricate([0.1] * 12 + [0.1] * 4, r).holds is False  # equal boundary shares
    assert intricate([0.1] * 12 + [0.1000001] * 4, r).holds is True
    assert intricate(b, [2.0] * 12 + [2.0] * 4).holds is False  # as many regions: both are needed
    assert intricate(b, [2.0] * 12 + [2.0 + 1e-12] * 4).holds is False  # equal up to rounding
    # the means, not the extremes: one intricate non-joined mass among eleven plain ones does not refute it
    assert intricate([0.05] * 11 + [0.9] + [0.3] * 4, r).holds is True  # others' mean 0.121
    assert intricate([0.05] * 11 + [0.9] + [0.1] * 4, r).holds is False  # joined 0.1 < 0.121
    centre = np.arange(10)
    centre[7] = 1
    assert intricate(b, r, centre).holds is None
    c = lm.claims(maps(others, joined))[3]
    assert c.holds is None and "not measured" in c.evidence


# -- mnist-specific100: [high accuracy, MLP < LIL, 65 < 17, brain separates, body every label, body > brain,
#    joined smaller, extremes, brain not one output per label, body's gain more pronounced than with all data,
#    label maps more intricate than with all data] -------------------------------------------------------------------
KEYS = [(b, s, m) for s in ("double_circle", "multiple_circle") for m in (17, 65) for b in ("lil", "mlp")]
# every body: LIL 17 0.02, LIL 65 0.018, MLP 17 0.01, MLP 65 0.008 (MLP < LIL, 65 < 17 everywhere)
SP_MSE = {(b, s, m): {("lil", 17): 0.02, ("lil", 65): 0.018, ("mlp", 17): 0.01, ("mlp", 65): 0.008}[(b, m)]
          for b, s, m in KEYS}
HIGH = Skill(0.95, 100, 0.1)  # 100 images, chance 0.1: learned above 0.19
ANALYSED = ("mlp", "multiple_circle", 17)
SP_OTHERS, SP_JOINED = [0.8] * 11 + [0.9], [0.6, 0.65, 0.7, 0.55]


def sp_maps(boundary: float = 0.3, regions: float = 4.0, centre=None) -> lm.LabelMapNumbers:
    """The default label maps with every mass's boundary share and regions per map as given."""
    return maps(SP_OTHERS, SP_JOINED, centre, np.full(16, boundary), np.full(16, regions))


def spread(ratio: list[float] | float = 0.5, gap: float = 0.1) -> sp.LabelSpread:
    """Brain outputs whose RMS radius is ``ratio`` × the ``gap`` [m] to the nearest other label, per digit."""
    r = np.broadcast_to(np.asarray(ratio, float), (10,)) * gap
    return sp.LabelSpread(r.copy(), np.full(10, gap))


FULL = {"full_skill": GOOD, "full_brain": sep(0.2), "full_body": sep(0.3),  # gain 0.1 against 0.15 here
        "full_maps": sp_maps(0.1, 2.0), "brain_spread": spread()}


def sp_numbers(mse=None, skill=None, brain=None, body=None, label_maps=None, **full) -> sp.Specific100Numbers:
    return sp.Specific100Numbers({**SP_MSE, **(mse or {})}, {k: HIGH for k in KEYS} | (skill or {}),
                                 brain or sep(0.05), body or sep(0.2), label_maps or sp_maps(), **(FULL | full))


def specific(mse=None, skill=None, brain=None, body=None, label_maps=None, **full) -> list[bool | None]:
    return verdicts(sp.claims(sp_numbers(mse, skill, brain, body, label_maps, **full)))


def test_mnist_specific100_claims():
    assert specific() == [True] * 11
    # high accuracy: ≥ 90 % of the drawings nearest to their own target, inclusive
    assert specific(skill={("lil", "double_circle", 65): Skill(0.9, 100, 0.1)}) == [True] * 11
    assert specific(skill={("lil", "double_circle", 65): Skill(0.89, 100, 0.1)}) == [False] + [True] * 10
    # MLP < LIL for every body, strictly
    assert specific({("lil", "double_circle", 65): 0.008})[1:3] == [False, True]  # DC 65: LIL = MLP
    assert specific({("lil", "double_circle", 65): 0.0080001})[1:3] == [True, True]
    assert specific({("mlp", "multiple_circle", 17): 0.02})[1:3] == [False, True]  # MC 17: MLP = LIL
    # 65 < 17 for every brain and shape, strictly
    assert specific({("lil", "multiple_circle", 65): 0.02})[1:3] == [True, False]
    assert specific({("lil", "multiple_circle", 65): 0.0199999})[1:3] == [True, True]
    # brain: some separation (2-D probe above 0.13 on 900, chance 0.1)
    assert specific(brain=sep(0.05, probe=0.13))[3] is False
    assert specific(brain=sep(0.05, probe=0.1301))[3] is True
    # body: every digit's mean silhouette > 0, strictly
    assert specific(body=sep(0.2, {4: 0.0}))[4:6] == [False, True]
    assert specific(body=sep(0.2, {4: 1e-6}))[4:6] == [True, True]
    assert specific(body=sep(0.2, {4: float("nan")}))[4] is None  # no image of digit 4
    # body > brain
    assert specific(body=sep(0.05))[5] is False
    assert specific(body=sep(0.0500001))[5] is True
    # label maps as mnist-labelmap
    assert specific(label_maps=maps([0.8] * 12, [0.8] * 4, None, np.full(16, 0.3), np.full(16, 4.0)))[6:8] \
        == [False, False]
    assert specific(label_maps=maps([0.8] * 12, [0.95, 0.5, 0.5, 0.5], None, np.full(16, 0.3),
                                    np.full(16, 4.0)))[6:8] == [True, False]


def test_mnist_specific100_premises():
    # a LIL that did not learn (100 images, chance 0.1: 0.19 is the margin itself): its comparisons are open
    bad = {("lil", "double_circle", 17): Skill(0.19, 100, 0.1)}
    assert specific(skill=bad) == [False, None, None] + [True] * 8  # 0.19 < 0.9 too
    assert specific(skill={("lil", "double_circle", 17): Skill(0.2, 100, 0.1)}) == [False] + [True] * 10
    assert specific({("mlp", "multiple_circle", 65): 0.02}, skill=bad)[1:3] == [False, False]  # refuted elsewhere
    # the analysed system did not learn: its PCA claims and the comparisons that read its outputs are not
    # testable; the label maps keep their own premise
    c = sp.claims(sp_numbers(skill={ANALYSED: Skill(0.19, 100, 0.1)}))
    assert verdicts(c) == [False, None, None, None, None, None, True, True, None, None, True]
    assert all("MLP MC N_mov 17" in x.evidence for x in c[1:6] + c[8:10])
    centre = np.arange(10)
    centre[0] = 6
    assert specific(label_maps=sp_maps(centre=centre))[6:8] == [None, None]


def test_mnist_specific100_the_brain_does_not_deliver_one_output_per_label():
    claim = 8
    # the median over the labels of RMS radius / gap > 0.1, strictly
    assert specific(brain_spread=spread(0.1))[claim] is False  # every label at the bound
    assert specific(brain_spread=spread(0.100001))[claim] is True
    assert specific(brain_spread=spread(0.01))[claim] is False  # ten tight dots: a unique output per label
    # the median, not the largest nor the smallest ratio: 4 spread labels of 10 are not the typical label ...
    assert specific(brain_spread=spread([5.0] * 4 + [0.05] * 6))[claim] is False
    # ... and 6 of 10 are
    assert specific(brain_spread=spread([0.5] * 6 + [0.01] * 4))[claim] is True
    # two labels with the same output (gap 0): not a unique output per label (ratio infinite)
    same = sp.LabelSpread(np.zeros(10), np.zeros(10))
    c = sp.claims(sp_numbers(brain_spread=same))[claim]
    assert c.holds is True and "median ratio inf" in c.evidence
    # a digit with fewer than two images, or numbers the run never measured: not testable
    r = spread()
    r.radius[3] = float("nan")
    c = sp.claims(sp_numbers(brain_spread=r))[claim]
    assert c.holds is None and "digit 3" in c.evidence
    c = sp.claims(sp_numbers(brain_spread=None))[claim]
    assert c.holds is None and "not measured" in c.evidence
    c = sp.claims(sp_numbers(brain_spread=spread(0.2, gap=0.05)))[claim]
    assert "median ratio 0.2" in c.evidence and "0 of 10 labels one point" in c.evidence


def test_mnist_specific100_the_bodys_gain_is_more_pronounced_than_with_all_data():
    claim = 9
    # gain here: body 0.2 − brain 0.05; with all data body − brain as planted, strictly smaller
    assert specific(full_brain=sep(0.05), full_body=sep(0.2))[claim] is False  # the same gain
    assert specific(full_brain=sep(0.05), full_body=sep(0.1999999))[claim] is True
    assert specific(full_brain=sep(0.0), full_body=sep(0.16))[claim] is False  # gain 0.16 > 0.15
    # the gain, not the body's silhouette alone: all data's body separates more (0.5 > 0.2), its gain is smaller
    assert specific(full_brain=sep(0.45), full_body=sep(0.5))[claim] is True
    # premises: both systems learned; silhouettes defined; numbers measured
    c = sp.claims(sp_numbers(full_skill=EDGE))[claim]
    assert c.holds is None and "all data" in c.evidence and "did not learn" in c.evidence
    assert specific(full_skill=PAST)[claim] is True
    assert specific(skill={ANALYSED: Skill(0.19, 100, 0.1)})[claim] is None
    assert specific(full_body=sep(float("nan")))[claim] is None
    assert specific(full_brain=None)[claim] is None and specific(full_skill=None)[claim] is None


def test_mnist_specific100_label_maps_are_more_intricate_than_with_all_data():
    claim = 10
    # the default: boundary share 0.3 vs 0.1 and 4 vs 2 regions per map; each must be larger, strictly
    assert specific(full_maps=sp_maps(0.3, 2.0))[claim] is False  # equal boundary share
    assert specific(full_maps=sp_maps(0.2999, 2.0))[claim] is True
    assert specific(full_maps=sp_maps(0.1, 4.0))[claim] is False  # as many regions
    assert specific(full_maps=sp_maps(0.1, 3.999))[claim] is True
    assert specific(full_maps=sp_maps(0.3 - 1e-12, 2.0))[claim] is False  # equal up to rounding
    # the mean over every mass: one intricate mass does not make the maps intricate
    one = maps(SP_OTHERS, SP_JOINED, None, [0.05] * 15 + [0.95], [1.0] * 15 + [40.0])  # means 0.10625, 3.4375
    assert specific(label_maps=one)[claim] is True  # against 0.1 and 2
    assert specific(label_maps=one, full_maps=sp_maps(0.25, 2.0))[claim] is False
    # premises: each system's maps start from drawings of their own digits; numbers measured
    centre = np.arange(10)
    centre[4] = 1
    c = sp.claims(sp_numbers(full_maps=sp_maps(0.1, 2.0, centre)))[claim]
    assert c.holds is None and "all data" in c.evidence and "digit 4 → 1" in c.evidence
    assert specific(label_maps=sp_maps(centre=centre))[claim] is None
    assert specific(full_maps=None)[claim] is None
    assert specific(full_maps=maps(SP_OTHERS, SP_JOINED))[claim] is None  # maps of a run before they were measured


def test_mnist_specific100_numbers_stored_before_the_comparisons_judge_again():
    """A run that stored Specific100Numbers without the new fields (made before they existed) judges again: the
    new claims are not testable, the others as before."""
    from bptsb_ros.experiments import measured

    entry = measured.record(sp.claims, [sp_numbers()], {})
    fields = entry["args"][0]["fields"]
    for key in ("full_skill", "full_brain", "full_body", "full_maps", "brain_spread"):
        del fields[key]
    for key in ("boundary", "regions"):
        del fields["maps"]["fields"][key]
    again = measured.call(entry)
    assert [c.holds for c in again] == [True] * 8 + [None] * 3
    assert all("not measured" in c.evidence for c in again[8:])
    now = measured.call(measured.record(sp.claims, [sp_numbers()], {}))
    assert [c.holds for c in now] == [True] * 11


# -- mnist-readout: [> 95 %, body > brain, 65 > 17, shapes within 1 point] -----------------------------------------
def ro_skill(acc: float) -> Skill:
    return Skill(acc, 10000, 0.1135)  # learned above 0.1135 + 3·√(0.1135·0.8865/10000) = 0.12302 (by hand)


PAPER = {(None, 0): 0.9118, ("double_circle", 17): 0.9569, ("double_circle", 65): 0.9677,
         ("multiple_circle", 17): 0.9536, ("multiple_circle", 65): 0.9622}


def readout(**acc: float) -> list[bool | None]:
    keys = {"brain": (None, 0), "dc17": ("double_circle", 17), "dc65": ("double_circle", 65),
            "mc17": ("multiple_circle", 17), "mc65": ("multiple_circle", 65)}
    a = PAPER | {keys[k]: v for k, v in acc.items()}
    return verdicts(ro.claims(ro.ReadoutNumbers({k: ro_skill(v) for k, v in a.items()})))


def test_mnist_readout_claims_on_the_papers_table():
    assert readout() == [True, True, True, True]  # gaps of 0.33 and 0.55 points between the shapes


def test_mnist_readout_claims():
    # higher than 95 %, strictly
    assert readout(mc17=0.95)[0] is False
    assert readout(mc17=0.9501)[0] is True
    # every body beats the brain alone, strictly
    assert readout(brain=0.9536)[1] is False  # = multiple circle 17
    assert readout(brain=0.9535)[1] is True
    # more states: 65 > 17 in each shape, strictly
    assert readout(mc65=0.9536)[2] is False
    assert readout(mc65=0.9537)[2] is True
    # little effect of the shape: within 1 point, inclusive (0.96 − 0.95 = 0.010000000000000009 in floats)
    assert readout(dc17=0.96, mc17=0.95, dc65=0.97, mc65=0.965)[3] is True
    assert readout(dc17=0.96, mc17=0.9499, dc65=0.97, mc65=0.965)[3] is False
    assert readout(dc65=0.9722, mc65=0.9622)[3] is True
    assert readout(dc65=0.9723, mc65=0.9622)[3] is False


def test_mnist_readout_premise_the_systems_learned():
    # the brain alone at the margin (0.12302...): 0.123 did not learn, 0.1231 did
    assert readout(brain=0.123) == [True, None, True, True]
    assert readout(brain=0.1231) == [True, True, True, True]
    # a body system at chance: below 95 % (no premise), its comparisons open, the other shape still decides
    assert readout(mc65=0.1135) == [False, None, None, None]
    assert readout(mc65=0.1135, dc65=0.9569) == [False, None, False, None]  # DC: 65 = 17 refutes "more states"
    c = ro.claims(ro.ReadoutNumbers({k: ro_skill(v) for k, v in (PAPER | {(None, 0): 0.123}).items()}))
    assert "only brain" in c[1].evidence and "did not learn" in c[1].evidence


# -- separation scores (analysis/separation.py), against numpy ----------------------------------------------------
def numpy_silhouettes(points: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Per-point silhouette by its definition: (b − a) / max(a, b), a lone point of its label 0."""
    dist = np.sqrt(((points[:, None] - points[None]) ** 2).sum(-1))
    out = np.zeros(len(points))
    for i in range(len(points)):
        same = (labels == labels[i]) & (np.arange(len(points)) != i)
        if not same.any():
            continue
        a = dist[i, same].mean()
        b = min(dist[i, labels == o].mean() for o in np.unique(labels) if o != labels[i])
        out[i] = (b - a) / max(a, b)
    return out


def planted_clusters(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Three labels (0, 1, 4) with 12, 10 and 8 points in 5-D: 2·label + noise of scale 0.3 along feature 0, noise
    of scale 1 along features 1-4 (standardising shrinks feature 0, so it changes the geometry)."""
    rng = np.random.default_rng(seed)
    labels = np.array([0] * 12 + [1] * 10 + [4] * 8)
    x = rng.normal(0, 1, (30, 5)) * np.array([0.3, 1, 1, 1, 1])
    x[:, 0] += 2.0 * labels
    return x, labels


def test_separation_silhouettes_equal_a_numpy_recomputation():
    x, y = planted_clusters()
    got = separation.separation_scores(x, y, seed=0)
    centred = x - x.mean(0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    plane = centred @ vt[:2].T  # PCA: the first two right singular vectors (the sign does not move a silhouette)
    np.testing.assert_allclose(got["points_2d"] @ np.diag(np.sign(got["points_2d"][0] / plane[0])), plane,
                               atol=1e-9)
    s2 = numpy_silhouettes(plane, y)
    assert got["silhouette_2d"] == pytest.approx(s2.mean(), abs=1e-12)
    per = got["per_label_2d"]
    assert per.shape == (10,) and np.isnan(per[[2, 3, 5, 6, 7, 8, 9]]).all()
    np.testing.assert_allclose(per[[0, 1, 4]], [s2[y == d].mean() for d in (0, 1, 4)], atol=1e-12)
    z = (x - x.mean(0)) / x.std(0)  # the documented standardisation (population std)
    assert got["silhouette_full"] == pytest.approx(numpy_silhouettes(z, y).mean(), abs=1e-12)
    assert abs(numpy_silhouettes(x, y).mean() - got["silhouette_full"]) > 0.05  # the raw features differ
    one = separation.separation_scores(x, np.zeros(30, int))
    assert math.isnan(one["silhouette_2d"]) and np.isnan(one["per_label_2d"]).all() and math.isnan(one["probe_2d"])


def test_separation_probe_is_scored_on_the_held_out_half():
    rng = np.random.default_rng(3)
    # noise: 200 features, 60 points, 3 labels at random; a probe fits its training half perfectly (sklearn,
    # directly) but cannot beat chance on the other half
    y = np.repeat(np.arange(3), 20)
    x = rng.normal(size=(60, 200))
    held = separation.held_out(y, seed=0)
    fit = np.setdiff1d(np.arange(60), held)
    assert len(held) == 30 and np.bincount(y[held]).tolist() == [10, 10, 10]  # stratified halves
    from sklearn.linear_model import LogisticRegression

    assert LogisticRegression(max_iter=2000).fit(x[fit], y[fit]).score(x[fit], y[fit]) == 1.0
    assert separation.probe_accuracy(x, y, seed=0) < 0.6
    # separated labels: every held-out point right
    x_sep = rng.normal(0, 0.1, (60, 3)) + 5.0 * y[:, None]
    assert separation.probe_accuracy(x_sep, y) == 1.0
    # standardised inputs: a label carried by a feature of scale 1e-4 among noise of scale 1 is still read
    y2 = np.repeat([0, 1], 40)
    x2 = np.column_stack([1e-4 * y2 + rng.normal(0, 1e-5, 80), rng.normal(0, 1, (80, 5))])
    held2 = separation.held_out(y2, seed=0)
    fit2 = np.setdiff1d(np.arange(80), held2)
    raw = LogisticRegression(max_iter=2000).fit(x2[fit2], y2[fit2]).score(x2[held2], y2[held2])
    assert raw < 0.8 and separation.probe_accuracy(x2, y2, seed=0) >= 0.95


def test_separation_probe_size_and_chance():
    y = np.array([0] * 6 + [1] * 4)  # stratified half of 10: 3 zeros and 2 ones
    x = np.random.default_rng(0).normal(size=(10, 3))
    got = separation.separation_scores(x, y)
    assert got["probe_n"] == 5 and got["probe_chance"] == pytest.approx(0.6)
    assert np.bincount(y[separation.held_out(y)]).tolist() == [3, 2]
    assert len(separation.held_out(np.arange(7) % 3)) == 4  # ⌈7/2⌉
    # 5 zeros and 4 ones: the held-out 5 take 5·5/9 ≈ 2.8 → 3 zeros; chance among them 3/5, not 5/9
    y9 = np.array([0] * 5 + [1] * 4)
    got9 = separation.separation_scores(np.random.default_rng(1).normal(size=(9, 3)), y9)
    assert np.bincount(y9[separation.held_out(y9)]).tolist() == [3, 2]
    assert got9["probe_n"] == 5 and got9["probe_chance"] == pytest.approx(0.6)


# -- label maps: start point (each digit's best sample) and width (±size/5) ------------------------------------------
@pytest.mark.slow
def test_label_maps_start_at_each_digits_best_sample_within_0_8_m(tmp_path, monkeypatch):
    from bptsb_ros.experiments import mnist_analysis as ma
    from bptsb_ros.experiments.registry import Context
    from bptsb_ros.experiments.result import ExperimentResult
    from bptsb_ros.tasks import drawing as md

    assert ma.label_map_half_width(4.0) == pytest.approx(0.8)  # the published deltaScale 5 on the size-4 bodies
    labels = np.array([d % 10 for d in range(30)])
    errors = np.full(30, 0.05)
    best = [10, 21, 2, 13, 24, 5, 16, 27, 8, 19]  # planted: the lowest error of each digit
    errors[best] = 0.01
    errors[[0, 11]] = 0.011
    assert ma.best_per_digit(errors, labels).tolist() == best
    with pytest.raises(ValueError, match="digit 9"):
        ma.best_per_digit(errors[labels != 9], labels[labels != 9])

    system = md.ImageToBody(md.SystemSpec(brain="mlp", nodes=37, dtype="float64"), 0)
    disp = system.displacement(torch.rand(30, 784, dtype=torch.float64,
                                          generator=torch.Generator().manual_seed(0))).detach().numpy()
    seen = {}
    real = md.label_maps

    def spy(system, base, *, half_width, grid):
        """The real label maps, their labels replaced by planted ones: digit d's Δ = 0 cells d, every other
        cell (d + 1) mod 10, so only the centre cell tells each digit's start drawing."""
        out = real(system, base, half_width=half_width, grid=grid)
        seen.update(base=base.numpy().copy(), half_width=half_width, real=out["labels"].copy())
        planted = np.broadcast_to((np.arange(10) + 1)[:, None, None, None] % 10, out["labels"].shape).copy()
        planted[:, :, grid // 2, grid // 2] = np.arange(10)[:, None]
        seen["out"] = {**out, "labels": planted}
        return seen["out"]

    monkeypatch.setattr(md, "label_maps", spy)
    ctx = Context("smoke", 0, tmp_path, ExperimentResult("mnist-labelmap", "", "smoke", 0), log=lambda _: None)
    out = ma.labelmap_analysis(ctx, system, {"errors": errors, "displacement": disp}, labels, 3, "planted")
    np.testing.assert_array_equal(seen["base"], disp[best])
    assert seen["half_width"] == pytest.approx(0.8) and out["half_width_m"] == pytest.approx(0.8)
    assert seen["out"]["deltas"].tolist() == pytest.approx([-0.8, 0.0, 0.8])
    assert out["centre_labels"] == list(range(10))  # read at the Δ = 0 cell
    # in the real maps the Δ = 0 cell of every mass is the same unshifted body
    assert (seen["real"][:, :, 1, 1] == seen["real"][:, :1, 1, 1]).all()
    with pytest.raises(ValueError, match="odd"):
        ma.labelmap_analysis(ctx, system, {"errors": errors, "displacement": disp}, labels, 4, "planted")


# -- the brain output's spread per label (analysis/separation.py) and the label maps' intricacy, by hand ------------
def test_label_spread_is_the_rms_radius_and_the_gap_to_the_nearest_other_mean():
    points = np.array([[0, 0], [2, 0],  # digit 0: mean (1, 0), radius 1
                       [10, 0], [10, 4],  # digit 1: mean (10, 2), radius √((4 + 4) / 2) = 2
                       [50, 50],  # digit 2: one image, no spread to tell
                       [0, 10], [0, 10], [0, 16]], float)  # digit 3: mean (0, 12), distances 2, 2, 4
    labels = np.array([0, 0, 1, 1, 2, 3, 3, 3])
    radius, gap = separation.label_spread(points, labels)
    assert radius.shape == gap.shape == (10,)
    assert radius[[0, 1]] == pytest.approx([1.0, 2.0])
    assert radius[3] == pytest.approx(math.sqrt((4 + 4 + 16) / 3))  # RMS, not the mean distance 8/3
    # nearest other mean: 0 ↔ 1 √85, 3 → 0 √145 (not 1 at √200); digit 2's lone point is nobody's neighbour
    assert gap[[0, 1, 3]] == pytest.approx([math.sqrt(85), math.sqrt(85), math.sqrt(145)])
    assert np.isnan(radius[[2, 4, 5, 6, 7, 8, 9]]).all() and np.isnan(gap[[2, 4, 5, 6, 7, 8, 9]]).all()
    # features of any shape per sample (the brain's (n, masses, 2) positions), one label: no gap
    r, g = separation.label_spread(points[:2].reshape(2, 1, 2), labels[:2])
    assert r[0] == pytest.approx(1.0) and np.isnan(g).all()


def test_map_intricacy_counts_differing_neighbours_and_4_connected_regions():
    from bptsb_ros.experiments.mnist_analysis import map_intricacy

    uniform = np.full((3, 3), 7)
    checker = np.indices((3, 3)).sum(0) % 2  # 5 zeros touching only at corners, 4 ones
    split = np.array([[5, 5, 7, 7]] * 4)  # two columns each: 4 of the 2·4·3 = 24 neighbour pairs differ
    islands = np.zeros((5, 5), int)
    islands[1, 1] = islands[3, 3] = 1  # two single-cell islands: 8 of 40 pairs differ, 3 regions
    b, r = map_intricacy(uniform)
    assert (float(b), int(r)) == (0.0, 1)
    b, r = map_intricacy(checker)
    assert (float(b), int(r)) == (1.0, 9)  # every pair differs; 4-connected: every cell its own region
    b, r = map_intricacy(split)
    assert (float(b), int(r)) == (pytest.approx(4 / 24), 2)
    b, r = map_intricacy(islands)
    assert (float(b), int(r)) == (pytest.approx(8 / 40), 3)
    # a stack (labels, masses, G, G): each map on its own; regions never run from one map into the next
    stack = np.stack([np.stack([uniform, checker]), np.stack([uniform, uniform])])
    b, r = map_intricacy(stack)
    assert b.shape == r.shape == (2, 2)
    assert r.tolist() == [[1, 9], [1, 1]] and b.tolist() == [[0.0, 1.0], [0.0, 0.0]]
