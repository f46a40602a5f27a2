"""Information processing capacity (the definition of K. Inoue's ipc-module): planted systems with known
capacities (expectations from closed forms or computed here, independently of bptsb_ros.analysis.ipc), the basis,
the per-degree-tuple surrogate threshold, the rank cap, the command and bad input."""

from __future__ import annotations

import json
import os
from itertools import combinations

import numpy as np
import pytest

from bptsb_ros.analysis.ipc import IPCError, basis_terms, ipc, ipc_groups, legendre_orthonormal
from bptsb_ros.cli import main

T = 2000


@pytest.fixture(scope="module")
def u() -> np.ndarray:
    return np.random.default_rng(7).uniform(-1, 1, T)


def delayed(u: np.ndarray, d: int) -> np.ndarray:
    out = np.zeros_like(u)
    out[d:] = u[: len(u) - d] if d else u
    return out


def test_basis_counts_and_legendre_values():
    # counted by hand: degree 1: one per delay; degree 2: P2 at one delay + P1·P1 at two; degree 3: P3, P2·P1
    # (ordered pair of distinct delays), P1·P1·P1
    D = 6
    assert len(basis_terms(1, D - 1)) == D
    assert len(basis_terms(2, D - 1)) == D + len(list(combinations(range(D), 2)))
    assert len(basis_terms(3, D - 1)) == D + D * (D - 1) + len(list(combinations(range(D), 3)))
    x = np.array([-1.0, -0.3, 0.0, 0.5, 1.0])
    p = legendre_orthonormal(x, 3)
    np.testing.assert_allclose(p[0], np.sqrt(3) * x)
    np.testing.assert_allclose(p[1], np.sqrt(5) * (3 * x**2 - 1) / 2)
    np.testing.assert_allclose(p[2], np.sqrt(7) * (5 * x**3 - 3 * x) / 2)
    # orthonormal under U(-1, 1): Gauss-Legendre quadrature of the products
    nodes, weights = np.polynomial.legendre.leggauss(10)
    q = legendre_orthonormal(nodes, 3)
    np.testing.assert_allclose((q * weights) @ q.T / 2, np.eye(3), atol=1e-12)


def test_linear_delay_line_has_all_capacity_at_degree_one_at_its_delays(u):
    delays = [0, 1, 2, 5, 9]
    x = np.stack([delayed(u, d) for d in delays], axis=1)
    res = ipc(u, x, max_degree=3, max_delay=12, washout=20, surrogates=30)
    cap = res.capacity[0]
    assert res.rank[0] == len(delays)
    np.testing.assert_allclose(res.total[0], len(delays), atol=1e-9)
    for d in range(13):
        c = cap[res.index(((d, 1),))]
        assert c == pytest.approx(1.0 if d in delays else 0.0, abs=1e-9), d
    assert res.by_degree()[0, 1:].sum() == pytest.approx(0.0, abs=1e-12)


def test_planted_quadratic_map_has_degree_two_capacity_where_expected(u):
    # s(t) = u(t)² + u(t−1)u(t−3): in Legendre terms u² = (2/√5·P̃₂ + 1)/3 and u(t−1)u(t−3) = P̃₁P̃₁/3, so a
    # single state holds capacity a²/(a²+b²) on P̃₂(u(t)) and b²/(a²+b²) on P̃₁(u(t−1))P̃₁(u(t−3)), a = 2/(3√5),
    # b = 1/3 (unit-variance basis), nothing else.
    s = u**2 + delayed(u, 1) * delayed(u, 3)
    res = ipc(u, s, max_degree=3, max_delay=6, washout=10, surrogates=30)
    a2, b2 = (2 / (3 * np.sqrt(5))) ** 2, (1 / 3) ** 2
    cap = res.capacity[0]
    assert cap[res.index(((0, 2),))] == pytest.approx(a2 / (a2 + b2), abs=0.03)
    assert cap[res.index(((1, 1), (3, 1)))] == pytest.approx(b2 / (a2 + b2), abs=0.03)
    bd = res.by_degree()[0]
    assert bd[1] == pytest.approx(1.0, abs=0.01) and bd[0] < 0.01 and bd[2] < 0.01
    assert res.total[0] <= res.rank[0] + 1e-9
    # nonlinear memory: the part on a past input, P̃₁(u(t−1))P̃₁(u(t−3)), not the instantaneous P̃₂(u(t))
    assert res.nonlinear_memory()[0] == pytest.approx(b2 / (a2 + b2), abs=0.03)


def test_total_never_exceeds_rank_and_noise_states_have_none(u):
    rng = np.random.default_rng(3)
    noise = rng.normal(size=(T, 8))
    mixed = np.column_stack([np.tanh(u + 0.5 * delayed(u, 1)), delayed(u, 2) ** 3, rng.normal(size=T),
                             np.ones(T)])  # a constant column adds no rank
    res = ipc_groups(u, [noise, mixed, noise[:, :1]], ["noise", "mixed", "one noise"], max_degree=3, max_delay=8,
                     washout=10, surrogates=40)
    assert list(res.rank) == [8, 3, 1]
    assert np.all(res.total <= res.rank + 1e-9)
    # Gaussian noise independent of the input: each function's chance capacity has mean r / (S − 1) exactly (a
    # random r-dimensional subspace of the S − 1 centred dimensions); unthresholded they add up to F·r/(S − 1)
    raw = ipc(u, noise, max_degree=3, max_delay=8, washout=10, threshold="none", rank_cap=False)
    chance = len(raw.terms) * 8 / (T - 10 - 1)
    assert raw.total[0] == pytest.approx(chance, rel=0.1)
    # the threshold (the largest of 40 surrogates of the same degree tuple) lets through ≈ 1/41 of them (each
    # with about 2 - 7 times the mean chance capacity)
    assert res.total[0] < 0.3 * chance and res.total[2] < 0.3 * len(raw.terms) / (T - 11)
    # the surrogates are chance capacities too: their mean is r/(S − 1) for every tuple
    for tup, caps in res.surrogate.items():
        assert caps.shape == (40, 3)
        assert caps[:, 0].mean() == pytest.approx(8 / (T - 11), rel=0.25), tup
        np.testing.assert_allclose(res.tuple_thresholds()[tup], caps.max(axis=0))


def test_groups_equal_separate_computations(u):
    x = np.column_stack([np.tanh(2 * u), delayed(u, 1) ** 2])
    both = ipc_groups(u, [x[:, 0], x[:, 1], x], ["a", "b", "ab"], max_delay=4, washout=5, threshold="none")
    for g, states in enumerate([x[:, 0], x[:, 1], x]):
        alone = ipc(u, states, max_delay=4, washout=5, threshold="none")
        np.testing.assert_allclose(both.raw[g], alone.raw[0], atol=1e-12)


def test_chunk_size_changes_no_capacity(u, monkeypatch):
    """Basis functions and surrogates are computed in chunks: one function or one permutation per chunk gives
    the same raw capacities, surrogate thresholds and kept capacities as everything in one chunk."""
    import bptsb_ros.analysis.ipc as ipc_module

    x = np.column_stack([np.tanh(2 * u), delayed(u, 1) ** 2, delayed(u, 2) * u])
    opts = dict(max_degree=3, max_delay=4, washout=5, surrogates=7, seed=3)
    monkeypatch.setattr(ipc_module, "_CHUNK", 10**9)
    whole = ipc(u, x, **opts)
    monkeypatch.setattr(ipc_module, "_CHUNK", 1)
    pieces = ipc(u, x, **opts)
    np.testing.assert_allclose(pieces.raw, whole.raw, rtol=0, atol=1e-13)
    np.testing.assert_allclose(pieces.threshold, whole.threshold, rtol=0, atol=1e-13)
    np.testing.assert_allclose(pieces.capacity, whole.capacity, rtol=0, atol=1e-13)
    assert (whole.capacity > 0).sum() >= 3  # the comparison covers kept capacities, not only zeros


@pytest.mark.parametrize("args, message", [
    (dict(u=np.full(100, 2.0), states=np.zeros((100, 2))), r"\[-1, 1\]"),
    (dict(u=np.zeros(100), states=np.zeros((99, 2))), "T = 100"),
    (dict(u=np.zeros(100), states=np.full((100, 2), np.nan)), "non-finite"),
    (dict(u=np.zeros(30), states=np.zeros((30, 2)), washout=25), "samples remain"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), threshold="chi"), "threshold must be"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), threshold="degree-max"), "threshold must be"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), min_delay=4), r"min_delay \(4\) must not exceed"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), min_delay=-1), "must be >= 0"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), threshold_scale=-0.1), "threshold_scale"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), threshold_scale=np.inf), "threshold_scale"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), surrogates=0), "needs surrogates >= 1"),
])
def test_bad_input_is_one_clear_error(args, message):
    with pytest.raises(IPCError, match=message):
        ipc(**{"max_delay": 3, "washout": 5, **args})


def test_accepted_edges_of_the_options(u):
    """min_delay = max_delay (one delay), threshold_scale 0 (keep every positive capacity), one surrogate."""
    x = np.column_stack([delayed(u, 3), delayed(u, 3) ** 2])
    res = ipc(u, x, max_degree=2, max_delay=3, min_delay=3, washout=5, surrogates=1, threshold_scale=0.0)
    assert res.terms == [((3, 1),), ((3, 2),)]  # degree 2 at one delay: only P2 (a product needs two delays)
    np.testing.assert_allclose(res.capacity[0], [1.0, 1.0], atol=1e-9)
    assert np.all(res.threshold == 0.0)


def test_ipc_command_writes_json_and_figure(tmp_path, u):
    x = np.column_stack([delayed(u, 0), delayed(u, 2)])
    np.savez(tmp_path / "in.npz", u=u, states=x)
    rc = main(["ipc", "--input", str(tmp_path / "in.npz"), "--out", str(tmp_path / "o"), "--max-degree", "2",
               "--max-delay", "4", "--washout", "10", "--surrogates", "10"])
    assert rc == 0
    data = json.loads((tmp_path / "o" / "ipc.json").read_text())
    st = data["states"][0]
    assert st["rank"] == 2 and st["total"] == pytest.approx(2.0, abs=1e-6)
    kept = [(b["delays"], b["orders"]) for b, c in zip(data["basis"], st["capacity"]) if c > 0.5]
    assert sorted(kept) == [([0], [1]), ([2], [1])]
    assert set(st["thresholds"]) == {"1", "2", "1,1"} and data["settings"]["surrogates"] == 10
    # the new options: delays from 1 (u(t) is then no basis function), no rank cap, a scaled threshold
    rc = main(["ipc", "--input", str(tmp_path / "in.npz"), "--out", str(tmp_path / "o2"), "--max-degree", "2",
               "--max-delay", "4", "--min-delay", "1", "--washout", "10", "--surrogates", "10",
               "--threshold-scale", "3", "--no-rank-cap", "--orthogonalise-linear"])
    assert rc == 0
    data2 = json.loads((tmp_path / "o2" / "ipc.json").read_text())
    assert all(min(b["delays"]) >= 1 for b in data2["basis"])
    assert data2["settings"]["rank_cap"] is False and data2["settings"]["threshold_scale"] == 3.0
    assert data2["settings"]["definition"] == "orthogonalised-linear"
    assert data2["states"][0]["total"] == pytest.approx(1.0, abs=1e-6)  # only u(t − 2) is left
    assert (tmp_path / "o" / "ipc.png").stat().st_size > 1000
    np.savez(tmp_path / "bad.npz", u=u * 3, states=x)
    assert main(["ipc", "--input", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "b")]) == 1
    assert not (tmp_path / "b" / "ipc.json").exists()


@pytest.mark.ros
def test_ipc_of_a_bag_reads_inputs_and_block_end_states(tmp_path):
    """A bag written with the live nodes' message builders: three masses (0 fixed, 1 movable, 2 the CMP) whose
    block-end positions are planted functions of the held input: mass 1 x = u(t−1), mass 1 y = u(t)²,
    CMP y = u(t−2) (u mapped to [−1, 1]); positions inside a block are junk that must not be read."""
    from bptsb_ros.bags.writer import BagWriter
    from bptsb_ros.interface.topics import dt_to_ns, input_names
    from bptsb_ros.ros import messages as m

    tau, blocks = 4, 260
    u01 = np.random.default_rng(5).uniform(0, 1, blocks)
    v = 2 * u01 - 1
    ns = dt_to_ns(0.01)
    springs = np.array([[0, 1], [1, 2], [0, 2]])
    fixed = np.array([True, False, False])
    junk = np.random.default_rng(6)
    with BagWriter(tmp_path / "bag", custom_data={"loop": "narma", "mode": "lockstep"}) as w:
        for k in range(blocks * tau + 1):
            t = k * ns
            j = max(k - 1, 0) // tau  # held_inputs: step k carries u[(k − 1) // τ]
            pos = junk.normal(size=(3, 2))
            if k % tau == 0 and k:
                jb = k // tau - 1  # the block that just ended
                pos = np.array([[5.0, 5.0], [v[jb - 1] if jb >= 1 else 0.0, v[jb] ** 2],
                                [0.3, v[jb - 2] if jb >= 2 else 0.0]])
            w.write_message("/body/positions", m.pose_array(k, ns, pos, "msdn"), t)
            w.write_message("/task/input", m.joint_state(k, ns, input_names(1), position=np.array([u01[j]])), t)
            if k == 0:
                w.write_message("/body/markers", m.body_markers(k, ns, pos, springs, fixed, 2, np.zeros(3), "msdn",
                                                                0.1), t)
    out = tmp_path / "o"
    assert main(["ipc", "--bag", str(tmp_path / "bag"), "--out", str(out), "--max-degree", "2", "--max-delay", "3",
                 "--washout", "5", "--surrogates", "10"]) == 0
    data = json.loads((out / "ipc.json").read_text())
    assert data["source"]["tau"] == tau
    states = {s["label"]: s for s in data["states"]}
    assert set(states) == {"output (CMP y)", "mass 1 x", "mass 1 y", "mass 2 x", "mass 2 y", "all movable x, y"}

    def top(label):
        s = states[label]
        i = int(np.argmax(s["capacity"]))
        return data["basis"][i]["delays"], data["basis"][i]["orders"], s["capacity"][i]

    assert top("output (CMP y)")[:2] == ([2], [1]) and top("output (CMP y)")[2] == pytest.approx(1, abs=1e-9)
    assert top("mass 1 x")[:2] == ([1], [1]) and top("mass 1 x")[2] == pytest.approx(1, abs=1e-9)
    # u(t)² = (2/√5·P̃₂(u(t)) + 1)/3 is affine in P̃₂(u(t)): capacity 1
    assert top("mass 1 y")[:2] == ([0], [2]) and top("mass 1 y")[2] == pytest.approx(1, abs=1e-9)
    assert states["mass 2 x"]["rank"] == 0 and states["mass 2 x"]["total"] == 0
    # three exact capacities of 1 reach the rank; the cap drops anything a surrogate threshold let through
    assert states["all movable x, y"]["total"] == pytest.approx(3, abs=1e-9)


def test_benchmark_entry_reports_its_workload():
    from bptsb_ros.analysis.ipc import benchmark_ipc

    out = benchmark_ipc(samples=400, masses=2, max_degree=2, max_delay=5, surrogates=2)
    assert out["basis_functions"] == 6 + (6 + 15)  # degree 1: 6 delays; degree 2: P2 at 6 + pairs of 6
    assert out["state_sets"] == 2 * 2 + 1 and out["seconds"] > 0
    assert 0 < out["total_capacity_all"] <= out["rank_all"] + 1e-9
    assert out["seconds_orthogonalise_linear"] > 0
    res = out["reservoir"]
    assert res["seconds"] > 0 and res["seconds_orthogonalise_linear"] > 0
    assert res["rank"] == 4 and 0 < sum(res["by_degree"]) <= 4 + 1e-9


def test_a_linear_filter_has_only_chance_capacity_above_degree_one(u):
    """x(t) = 0.5·x(t−1) + u(t) is uncorrelated with every degree ≥ 2 function: its raw capacity for them is chance
    (≈ 1/S each in-sample: P̃₃(u(t)) overlaps P̃₁(u(t)) by ≈ 1/√T), which the surrogate threshold removes; the
    capacity left above degree 1 is that of the ≈ 1/(surrogates + 1) chance survivors."""
    x = np.zeros(T)
    for t in range(1, T):
        x[t] = 0.5 * x[t - 1] + u[t]  # memory ≈ 0.5^d: all of it within the 25 delays below
    raw = ipc(u, x, max_degree=3, max_delay=25, washout=30, threshold="none", rank_cap=False)
    res = ipc(u, x, max_degree=3, max_delay=25, washout=30, surrogates=200)
    nonlinear = raw.degrees > 1
    assert raw.by_degree()[0, 0] == pytest.approx(1.0, abs=0.05)  # delays overlap in-sample by ≈ 1/√T
    assert raw.raw[0, nonlinear].sum() == pytest.approx(nonlinear.sum() / (T - 31), rel=0.3)
    assert res.by_degree()[0, 1:].sum() < 0.05 * raw.raw[0, nonlinear].sum()
    assert res.total[0] <= 1 + 1e-9
    # the linearity-test variant: degree >= 2 functions orthogonalised in-sample against the degree-1 ones;
    # x lies in their span up to 0.5^26, so nothing above degree 1 is left even unthresholded
    orth = ipc(u, x, max_degree=3, max_delay=25, washout=30, threshold="none", orthogonalise_linear=True)
    assert orth.raw[0, nonlinear].sum() < 1e-9
    np.testing.assert_allclose(orth.raw[0, ~nonlinear], raw.raw[0, ~nonlinear], atol=1e-12)
    assert orth.settings["definition"] == "orthogonalised-linear" and raw.settings["definition"] == "ipc-module"


def test_orthogonalised_variant_removes_clustered_linear_overlaps(u):
    """Four states u(t), …, u(t − 3): in-sample, P̃₁(u(t))P̃₁(u(t−1))P̃₁(u(t−2)) overlaps u(t − 3) by the sum
    Σ u(t)u(t−1)u(t−2)u(t−3)/S, and the same sum (one step shifted) is its overlap with its shifted versions: chance
    capacities of the reference definition (≈ 1/S each) that the orthogonalised variant sets to 0 for every
    degree >= 2 function, with the surrogates in the same orthogonal complement (a threshold of ≈ 0 but > 0 is
    irrelevant: the raw values are 0 up to rounding)."""
    x = np.column_stack([delayed(u, d) for d in range(4)])
    ref = ipc(u, x, max_degree=3, max_delay=3, washout=5, surrogates=100)
    orth = ipc(u, x, max_degree=3, max_delay=3, washout=5, surrogates=100, orthogonalise_linear=True)
    nonlinear = ref.degrees > 1
    assert ref.raw[0, nonlinear].max() > 1 / (T - 5)  # chance overlaps, each of order 1/S
    assert orth.raw[0, nonlinear].max() < 1e-20 and orth.by_degree()[0, 1:].sum() < 1e-20
    assert orth.total[0] == pytest.approx(4.0, abs=1e-9)


# ---- the reference definition (K. Inoue's ipc-module): expectations from closed forms / independent fits ----

def legendre_term(u: np.ndarray, term, start: int) -> np.ndarray:
    """∏ √(2n+1)·P_n(u(t − d)) for t ≥ start, with numpy's Legendre basis (independent of the code's recursion)."""
    out = np.ones(len(u) - start)
    for d, n in term:
        out = out * np.sqrt(2 * n + 1) * np.polynomial.legendre.Legendre.basis(n)(u[start - d: len(u) - d])
    return out


def own_fit_capacity(f: np.ndarray, x: np.ndarray) -> float:
    """1 − min_w,b ‖f − Xw − b‖² / ‖f − f̄‖²: the target's own least-squares fit on the states."""
    a = np.column_stack([x, np.ones(len(x))])
    w, *_ = np.linalg.lstsq(a, f, rcond=None)
    return 1.0 - float(np.sum((f - a @ w) ** 2) / np.sum((f - f.mean()) ** 2))


def planted(u: np.ndarray, terms, start: int) -> np.ndarray:
    """(T, len(terms)) states: column j the Legendre product terms[j] (zero before ``start``)."""
    x = np.zeros((len(u), len(terms)))
    for j, term in enumerate(terms):
        x[start:, j] = legendre_term(u, term, start)
    return x


#: 22 orthonormal basis functions as states: degree 1 only at some delays (so that a degree ≥ 2 function's
#: linear neighbours are not all in the state space), degree 2 and 3 at delays 0..6
STATE_TERMS = [((0, 1),), ((2, 1),), ((5, 1),),
               ((0, 2),), ((3, 2),), ((6, 2),), ((0, 1), (1, 1)), ((1, 1), (4, 1)), ((2, 1), (6, 1)),
               ((3, 1), (5, 1)), ((0, 3),), ((4, 3),), ((0, 2), (2, 1)), ((1, 1), (3, 2)), ((5, 2), (6, 1)),
               ((0, 1), (1, 1), (2, 1)), ((1, 1), (3, 1), (6, 1)), ((2, 1), (4, 1), (5, 1)), ((0, 1), (3, 1), (6, 1)),
               ((1, 3),), ((2, 2), (4, 1)), ((0, 1), (4, 2))]


def test_each_functions_capacity_is_its_own_least_squares_fit(u):
    """Every basis function's raw capacity equals its own least-squares fit on the states (1 exactly for the
    functions present as states); nothing is orthogonalised against the linear functions first."""
    D, start = 6, 6
    x = planted(u, STATE_TERMS, start)
    res = ipc(u, x, max_degree=3, max_delay=D, washout=start, threshold="none")
    assert res.rank[0] == len(STATE_TERMS)
    for f, term in enumerate(res.terms):
        expected = own_fit_capacity(legendre_term(u, term, start), x[start:])
        assert res.raw[0, f] == pytest.approx(expected, abs=1e-9), res.name(f)
    for term in STATE_TERMS:
        assert res.raw[0, res.index(term)] == pytest.approx(1.0, abs=1e-9)


def test_planted_mixtures_over_24_states_have_their_closed_form_capacities():
    """State j = a_j·f_j + b_j·g_j + σ·noise_j for 48 distinct orthonormal basis functions (many small
    degree-2/3 terms) and unit-variance noise: C[f_j] = a_j²/(a_j² + b_j² + σ²), C[g_j] = b_j²/(…) (population
    values; in-sample ±1/√T), nothing else; the per-degree totals are the sums of those (19.2 < the rank 24, so
    the rank cap does not bite)."""
    rng = np.random.default_rng(11)
    T_, D, start = 8000, 10, 10
    u = rng.uniform(-1, 1, T_)
    pool = [t for n in (1, 2, 3) for t in basis_terms(n, D)]
    picked = [pool[i] for i in rng.choice(len(pool), 48, replace=False)]
    f_terms, g_terms = picked[:24], picked[24:]
    share, sigma2 = np.linspace(0.06, 0.94, 24), 0.25  # a_j², b_j² = 1 − a_j²: capacities from 0.048 up
    x = rng.normal(scale=np.sqrt(sigma2), size=(T_, 24))
    for j in range(24):
        x[start:, j] += (np.sqrt(share[j]) * legendre_term(u, f_terms[j], start)
                         + np.sqrt(1 - share[j]) * legendre_term(u, g_terms[j], start))
    res = ipc(u, x, max_degree=3, max_delay=D, washout=start, surrogates=300)
    expected = np.zeros(len(res.terms))
    for j in range(24):
        expected[res.index(f_terms[j])] = share[j] / (1 + sigma2)
        expected[res.index(g_terms[j])] = (1 - share[j]) / (1 + sigma2)
    # in-sample, the unexplained part (1 − C) of a planted function also has the chance capacity (r − 1)/(S − 1)
    # on the other states' directions
    planted_ = expected > 0
    expected[planted_] += (1 - expected[planted_]) * 23 / (T_ - start - 1)
    cap = res.capacity[0]
    np.testing.assert_allclose(cap[expected > 0], expected[expected > 0], atol=0.03)
    for term in picked:  # in-sample, exactly each function's own least-squares fit
        f = res.index(term)
        assert res.raw[0, f] == pytest.approx(own_fit_capacity(legendre_term(u, term, start), x[start:]), abs=1e-9)
    bd = res.by_degree()[0]
    for n in (1, 2, 3):
        assert bd[n - 1] == pytest.approx(expected[res.degrees == n].sum(), abs=0.1), n
    assert res.total[0] <= res.rank[0] + 1e-9


def test_surrogate_threshold_keeps_a_small_planted_term_of_its_own_tuple(u):
    """A 1-D state whose in-sample capacity for P̃₂(u(t−3))P̃₁(u(t−7)) is exactly c = 20/S (built here: the
    centred term plus noise made orthogonal to it): above the (2, 1) tuple's surrogate maximum (the largest of
    200 chance capacities χ²₁/S), so it is counted with its exact value; the chance capacities of the ~1,800
    other basis functions are mostly removed (about 1/(surrogates + 1) of them survive, each ≈ 10/S)."""
    D, start = 20, 20
    S = T - start
    term = ((3, 2), (7, 1))
    f = legendre_term(u, term, start)
    f -= f.mean()
    e = np.random.default_rng(4).normal(size=S)
    e -= e.mean()
    e -= (e @ f) / (f @ f) * f
    c = 20 / S
    s = np.zeros(T)
    s[start:] = f / np.linalg.norm(f) + np.sqrt((1 - c) / c) * e / np.linalg.norm(e)
    res = ipc(u, s, max_degree=3, max_delay=D, washout=start, surrogates=200)
    i = res.index(term)
    assert res.raw[0, i] == pytest.approx(c, rel=1e-9)
    assert res.capacity[0, i] == pytest.approx(c, rel=1e-9)
    others = np.delete(res.capacity[0], i)
    assert others.sum() < 0.02 * len(res.terms) * 10 / S + 1e-12


def test_total_is_capped_at_the_rank_by_dropping_the_smallest(u):
    """20 states, each the sum of 5 distinct basis functions (100 functions, population capacity 1/5 each): more
    capacities than the rank; raw, they (with the chance capacity of all other functions) sum past the rank of
    20; capped, the largest ones are kept while their sum stays ≤ the rank."""
    rng = np.random.default_rng(8)
    T_, D, start = 6000, 8, 8
    u = rng.uniform(-1, 1, T_)
    pool = [t for n in (1, 2, 3) for t in basis_terms(n, D)]
    picked = [pool[i] for i in rng.choice(len(pool), 100, replace=False)]
    x = np.zeros((T_, 20))
    for j in range(20):
        x[start:, j] = sum(legendre_term(u, t, start) for t in picked[5 * j: 5 * j + 5])
    res = ipc(u, x, max_degree=3, max_delay=D, washout=start, threshold="none")
    assert res.rank[0] == 20
    raw = res.raw[0]
    assert raw.sum() > 20 + 0.5 * (len(raw) - 100) * 20 / T_  # + chance capacities of the other functions
    cap = res.capacity[0]
    assert res.total[0] <= 20 + 1e-9
    kept, dropped = raw[cap > 0], raw[cap == 0]
    assert kept.min() >= dropped.max()
    assert res.total[0] > 20 - dropped.max()
    planted_ = np.array([res.index(t) for t in picked])
    assert np.all(cap[np.setdiff1d(np.arange(len(raw)), planted_)] == 0)  # the chance capacities go first
    kept_planted = cap[planted_][cap[planted_] > 0]
    assert len(kept_planted) >= 95  # the planted sum ≈ 20 + 100·0.8·19/S: only its smallest few are dropped
    np.testing.assert_allclose(kept_planted, 0.2, atol=0.05)
    uncapped = ipc(u, x, max_degree=3, max_delay=D, washout=start, threshold="none", rank_cap=False)
    assert uncapped.total[0] == pytest.approx(raw.sum(), rel=1e-12)


def test_min_delay_shifts_the_basis(u):
    """Delays 2..6: the counts of the closed forms below with D = 5 delays, and a state u(t − 1) (outside the
    range) has no capacity while u(t − 2) has capacity 1."""
    x = np.column_stack([delayed(u, 1), delayed(u, 2)])
    res = ipc(u, x, max_degree=3, max_delay=6, min_delay=2, washout=10, surrogates=50)
    D = 5
    assert len(res.terms) == D + (D + len(list(combinations(range(D), 2)))) + (
        D + D * (D - 1) + len(list(combinations(range(D), 3))))
    assert min(d for t in res.terms for d, _ in t) == 2
    assert res.capacity[0, res.index(((2, 1),))] == pytest.approx(1.0, abs=1e-9)
    assert res.total[0] == pytest.approx(1.0, abs=0.05)




def _npz_with_header(path, name: str, shape: tuple[int, ...], data: bytes, dtype: str = "<f8") -> None:
    """A zip holding NAME.npy whose header declares ``shape`` but whose data are ``data`` (planted bytes)."""
    import io
    import zipfile

    from numpy.lib import format as npy_format

    head = io.BytesIO()
    npy_format.write_array_header_1_0(head, {"descr": dtype, "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(f"{name}.npy", head.getvalue() + data)
        zf.writestr("states.npy", _npy_bytes(np.zeros((100, 2))))


def _npy_bytes(array: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _peak_bytes(fn):
    import tracemalloc

    tracemalloc.start()
    try:
        result = fn()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return result, peak


def test_ipc_npz_with_a_forged_shape_is_one_line(tmp_path, capsys):
    """15 kB claiming 2**40 float64 (8 TiB): refused from the header, nothing allocated; np.load tried to."""
    bad = tmp_path / "forged.npz"
    _npz_with_header(bad, "u", (2**40,), bytes(15_000))
    assert bad.stat().st_size < 20_000
    assert main(["ipc", "--input", str(bad), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert "array 'u': declares shape (1099511627776,) of float64 (8796093022208 bytes)" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "o").exists()
    # a shape the zip entry does not hold (100 declared, 10 present) is refused too
    _npz_with_header(bad, "u", (100,), bytes(80))
    assert main(["ipc", "--input", str(bad), "--out", str(tmp_path / "o")]) == 1
    assert "declares shape (100,) of float64 (800 bytes) but the zip entry holds 80 bytes" in capsys.readouterr().err


def test_ipc_npz_bomb_is_refused_by_its_declared_shape(tmp_path, capsys, monkeypatch):
    """64 MiB of zeros deflated to ~64 kB, against a bound of 8 MiB: refused before decompressing (the old
    np.load decompressed it all)."""
    from bptsb_ros.files import npz as safe_npz

    path = tmp_path / "bomb.npz"
    np.savez_compressed(path, u=np.zeros(2**23), states=np.zeros((10, 1)))
    assert path.stat().st_size < 2**20
    monkeypatch.setattr(safe_npz, "MAX_NPZ_BYTES", 8 * 2**20)
    rc, peak = _peak_bytes(lambda: main(["ipc", "--input", str(path), "--out", str(tmp_path / "o"), "--max-degree",
                                         "1", "--max-delay", "0", "--threshold", "none"]))
    assert rc == 1 and peak < 4 * 2**20
    assert "array 'u': declares shape (8388608,) of float64 (67108864 bytes), more than the 8388608 bytes" in (
        capsys.readouterr().err)


def test_npz_byte_bound_both_sides(tmp_path):
    from bptsb_ros.files.npz import NpzError, load_npz

    path = tmp_path / "a.npz"
    u, states = np.linspace(-1, 1, 10), np.arange(20.0).reshape(10, 2)
    np.savez(path, u=u, states=states)
    got = load_npz(path, ("u", "states"), max_bytes=240)  # exactly 80 + 160 bytes of data
    np.testing.assert_array_equal(got["u"], u)
    np.testing.assert_array_equal(got["states"], states)
    with pytest.raises(NpzError, match="array 'states': declares shape \\(10, 2\\) of float64 \\(160 bytes\\), "
                                       "more than the 159 bytes allowed"):
        load_npz(path, ("u", "states"), max_bytes=239)
    np.savez(path, u=np.array([object()], dtype=object), states=states)
    with pytest.raises(NpzError, match="holds Python objects"):
        load_npz(path, ("u",))
    with pytest.raises(NpzError, match="must hold arrays 'nope'; it has states, u"):
        load_npz(path, ("nope",))


def _stars_and_bars(max_degree: int, max_delay: int) -> list[int]:
    """Functions of degree n over D + 1 delays: each delay carries an order >= 0, the orders sum to n, so
    C(n + D, D) (stars and bars) -- a different derivation from the code's compositions."""
    from math import comb

    return [comb(n + max_delay, max_delay) for n in range(1, max_degree + 1)]


def test_basis_size_in_closed_form():
    from bptsb_ros.cli.ipc_cmd import basis_size

    assert basis_size(3, 20) == [21, 231, 1771]  # by hand: 21; 21 + C(21, 2); 21 + 2 C(21, 2) + C(21, 3)
    for n, d in [(1, 0), (2, 3), (4, 5), (5, 2), (12, 400)]:
        assert basis_size(n, d) == _stars_and_bars(n, d)
    for n, d in [(2, 3), (4, 5), (5, 2)]:
        assert sum(basis_size(n, d)) == sum(len(basis_terms(k, d)) for k in range(1, n + 1))


def test_ipc_refuses_a_basis_too_large_before_reading_anything(tmp_path, capsys, u, monkeypatch):
    from bptsb_ros.cli import ipc_cmd

    total = sum(_stars_and_bars(12, 400))
    rc = main(["ipc", "--input", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "o"), "--max-degree", "12",
               "--max-delay", "400"])
    err = capsys.readouterr().err
    assert rc == 2 and f"is a basis of {total:.3e} functions, more than the maximum of 100,000" in err
    assert len(err.strip().splitlines()) == 1
    # both sides of the bounds (patched to the planted input's sizes): degree 2, delay 4 is 5 + 15 functions
    np.savez(tmp_path / "in.npz", u=u[:300], states=np.column_stack([delayed(u[:300], 0), delayed(u[:300], 1)]))
    args = ["ipc", "--input", str(tmp_path / "in.npz"), "--max-degree", "2", "--max-delay", "4", "--washout",
            "10", "--surrogates", "2"]
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_FUNCTIONS", 20)
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_BYTES", 15 * 290 * 8)  # the degree-2 block over 300 - 10 samples
    assert main([*args, "--out", str(tmp_path / "ok")]) == 0
    assert (tmp_path / "ok" / "ipc.json").exists()
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_FUNCTIONS", 19)
    assert main([*args, "--out", str(tmp_path / "no1")]) == 2  # the options alone ask too much
    assert "is a basis of 20 functions, more than the maximum of 19" in capsys.readouterr().err
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_FUNCTIONS", 20)
    monkeypatch.setattr(ipc_cmd, "MAX_BASIS_BYTES", 15 * 290 * 8 - 1)
    assert main([*args, "--out", str(tmp_path / "no2")]) == 1  # too much for this many samples
    assert "the degree-2 basis (15 functions × 290 samples)" in capsys.readouterr().err
    assert not (tmp_path / "no1").exists() and not (tmp_path / "no2").exists()


def test_ipc_checks_out_before_computing(tmp_path, capsys, u, monkeypatch):
    import bptsb_ros.analysis.ipc as ipc_module

    def never(*args, **kwargs):
        raise AssertionError("computed before --out was checked")

    monkeypatch.setattr(ipc_module, "ipc_groups", never)
    np.savez(tmp_path / "in.npz", u=u[:300], states=delayed(u[:300], 0))
    a_file = tmp_path / "file"
    a_file.write_text("keep me")
    outs = [(str(a_file), f"{a_file} is not a directory"), (str(a_file / "sub"), f"{a_file} is not a directory")]
    if os.path.isdir("/sys/kernel"):  # read-only even for root
        outs.append(("/sys/kernel/bptsb_ipc", "/sys/kernel is not writable"))
    for out, message in outs:
        assert main(["ipc", "--input", str(tmp_path / "in.npz"), "--out", out, "--max-delay", "4"]) == 1
        err = capsys.readouterr().err
        assert f"cannot write --out {out}: {message}" in err and len(err.strip().splitlines()) == 1
    assert a_file.read_text() == "keep me"
