"""Information processing capacity: planted systems with known capacities (expectations computed here,
independently of bptsb_ros.analysis.ipc), the basis, thresholds, the command and bad input."""

from __future__ import annotations

import json
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


def test_total_never_exceeds_rank_and_noise_states_have_none(u):
    rng = np.random.default_rng(3)
    noise = rng.normal(size=(T, 8))
    mixed = np.column_stack([np.tanh(u + 0.5 * delayed(u, 1)), delayed(u, 2) ** 3, rng.normal(size=T),
                             np.ones(T)])  # a constant column adds no rank
    res = ipc_groups(u, [noise, mixed, noise[:, :1]], ["noise", "mixed", "one noise"], max_degree=3, max_delay=8,
                     washout=10, surrogates=40)
    assert list(res.rank) == [8, 3, 1]
    assert np.all(res.total <= res.rank + 1e-9)
    assert res.total[0] < 0.02 and res.total[2] < 0.02
    # without the threshold the same noise shows its spurious capacity (≈ rank × functions / samples)
    raw = ipc(u, noise, max_degree=3, max_delay=8, washout=10, threshold="none")
    assert raw.total[0] > 10 * res.total[0] + 0.5
    # the per-function threshold lets through about 1/(surrogates + 1) of the null functions, each small
    fmax = ipc(u, noise, max_degree=3, max_delay=8, washout=10, surrogates=40, threshold="function-max")
    assert fmax.total[0] < 0.3


def test_groups_equal_separate_computations(u):
    x = np.column_stack([np.tanh(2 * u), delayed(u, 1) ** 2])
    both = ipc_groups(u, [x[:, 0], x[:, 1], x], ["a", "b", "ab"], max_delay=4, washout=5, threshold="none")
    for g, states in enumerate([x[:, 0], x[:, 1], x]):
        alone = ipc(u, states, max_delay=4, washout=5, threshold="none")
        np.testing.assert_allclose(both.raw[g], alone.raw[0], atol=1e-12)


@pytest.mark.parametrize("args, message", [
    (dict(u=np.full(100, 2.0), states=np.zeros((100, 2))), r"\[-1, 1\]"),
    (dict(u=np.zeros(100), states=np.zeros((99, 2))), "T = 100"),
    (dict(u=np.zeros(100), states=np.full((100, 2), np.nan)), "non-finite"),
    (dict(u=np.zeros(30), states=np.zeros((30, 2)), washout=25), "samples remain"),
    (dict(u=np.zeros(100), states=np.zeros((100, 2)), threshold="chi"), "threshold must be"),
])
def test_bad_input_is_one_clear_error(args, message):
    with pytest.raises(IPCError, match=message):
        ipc(**{"max_delay": 3, "washout": 5, **args})


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
    assert (tmp_path / "o" / "ipc.png").stat().st_size > 1000
    np.savez(tmp_path / "bad.npz", u=u * 3, states=x)
    assert main(["ipc", "--input", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "b")]) == 2
    assert not (tmp_path / "b" / "ipc.json").exists()


def test_ipc_of_a_bag_reads_inputs_and_block_end_states(tmp_path):
    """A bag written with the live nodes' message builders: three masses (0 fixed, 1 movable, 2 the CMP) whose
    block-end positions are planted functions of the held input: mass 1 x = u(t−1), mass 1 y = u(t)²,
    CMP y = u(t−2) (u mapped to [−1, 1]); positions inside a block are junk that must not be read."""
    from bptsb_ros.bags.writer import BagWriter
    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.topics import dt_to_ns, input_names

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
    # degree-2 functions are orthogonalised in-sample against the linear ones: u(t)² keeps 1 − O(delays / T)
    assert top("mass 1 y")[:2] == ([0], [2]) and top("mass 1 y")[2] == pytest.approx(1, abs=0.05)
    assert states["mass 2 x"]["rank"] == 0 and states["mass 2 x"]["total"] == 0
    assert states["all movable x, y"]["total"] == pytest.approx(3, abs=0.05)


def test_benchmark_entry_reports_its_workload():
    from bptsb_ros.analysis.ipc import benchmark_ipc

    out = benchmark_ipc(samples=400, masses=2, max_degree=2, max_delay=5, surrogates=2)
    assert out["basis_functions"] == 6 + (6 + 15)  # degree 1: 6 delays; degree 2: P2 at 6 + pairs of 6
    assert out["state_sets"] == 2 * 2 + 1 and out["seconds"] > 0
    assert 0 < out["total_capacity_all"] <= out["rank_all"] + 1e-9


def test_a_linear_filter_has_no_capacity_above_degree_one_even_unthresholded(u):
    """In-sample, P̃₃(u(t)) overlaps P̃₁(u(t)); without the orthogonalisation a strong linear state would show
    raw 3rd-order capacity ≈ its linear capacity × overlap² that no surrogate reproduces."""
    x = np.zeros(T)
    for t in range(1, T):
        x[t] = 0.5 * x[t - 1] + u[t]  # memory ≈ 0.5^d: all of it within the 25 delays below
    raw = ipc(u, x, max_degree=3, max_delay=25, washout=30, threshold="none")
    assert raw.by_degree()[0, 0] == pytest.approx(1.0, abs=0.05)  # delays overlap in-sample by ≈ 1/√T
    assert raw.by_degree()[0, 1:].sum() < 1e-9
