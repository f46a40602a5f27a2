"""Information processing capacity (IPC; Dambre et al., Sci. Rep. 2, 514, 2012).

Given an i.i.d. input u(t) uniform on [−1, 1] and states X(t) (T × N), the capacity of the states for a
target function f(t) is

    C[f] = 1 − min_{w, b} ⟨(f − wᵀX − b)²⟩ / ⟨(f − ⟨f⟩)²⟩  =  ‖Qᵀ f_c‖² / ‖f_c‖²,

with f_c and X_c centred over the samples and Q an orthonormal basis of the column space of X_c (its SVD;
the columns whose singular value exceeds ``rank_tol`` × the largest give the rank r). The targets are the
products of orthonormal Legendre polynomials of delayed inputs,

    f(t) = ∏_i P̃_{n_i}(u(t − Δt_i)),   P̃_n = √(2n + 1) P_n,   distinct delays Δt_i ∈ [0, max_delay],

grouped by degree n = Σ n_i ≤ ``max_degree``. For orthogonal targets the capacities sum to at most r, and
to r when the system has fading memory and the basis is complete enough.

In a finite sample the Legendre products are only orthogonal on average: P̃₃(u(t)) overlaps P̃₁(u(t)) by
≈ 1/√T, so a state with a strong linear component would show a spurious 3rd-order capacity that no shuffled
surrogate reproduces. The basis functions of degree ≥ 2 are therefore orthogonalised, in-sample, against the
span of the degree-1 functions (one QR of the (T × (max_delay + 1)) linear block) before their capacities are
taken; a purely linear system then has exactly zero capacity above degree 1. (Overlaps among functions of the
same degree, or between degrees 2 and 3, are left: the thresholded total can exceed the rank by a few per cent
in finite samples.)

A finite sample also gives every target a small spurious capacity (≈ χ²_r / T). It is removed with surrogates:
the same computation with the input shuffled in time (``surrogates`` permutations), and a capacity is kept
only if it exceeds a threshold taken from them:

* ``"degree-max"`` (default): the maximum surrogate capacity over every surrogate **and every basis function
  of the same degree** (one threshold per state set and degree; conservative — on pure noise states almost
  nothing survives, so the thresholded total stays ≤ the rank);
* ``"function-max"``: the maximum over the surrogates of **the same basis function** (per-function; at the
  chance level 1/(surrogates + 1) a spurious function survives);
* ``"none"``: raw capacities.

Several state sets sharing one input (each mass's x, each mass's y, the output, all together) are computed
in one pass: the basis matrix of a degree is built once per (surrogate) input and projected onto the
stacked orthonormal bases of all sets with a single GEMM. Everything is float64.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

THRESHOLDS = ("degree-max", "function-max", "none")


class IPCError(ValueError):
    """Input or states unsuitable for an IPC computation; one line naming the problem."""


Term = tuple[tuple[int, int], ...]  # ((delay, order), ...), delays strictly increasing


def basis_terms(degree: int, max_delay: int) -> list[Term]:
    """Every product of Legendre polynomials of total degree ``degree`` over distinct delays 0..max_delay.

    A term is ((Δt₁, n₁), (Δt₂, n₂), ...) with Δt₁ < Δt₂ < … and Σ nᵢ = ``degree``.
    """
    out: list[Term] = []

    def grow(start: int, remaining: int, prefix: list[tuple[int, int]]) -> None:
        if remaining == 0:
            out.append(tuple(prefix))
            return
        for d in range(start, max_delay + 1):
            for n in range(1, remaining + 1):
                prefix.append((d, n))
                grow(d + 1, remaining - n, prefix)
                prefix.pop()

    grow(0, degree, [])
    return out


def legendre_orthonormal(u: np.ndarray, max_order: int) -> np.ndarray:
    """(max_order, T) values √(2n+1)·P_n(u) for n = 1..max_order; unit mean square for u ~ U(−1, 1)."""
    u = np.asarray(u, dtype=np.float64)
    p_prev, p = np.ones_like(u), u.copy()
    out = np.empty((max_order, len(u)))
    for n in range(1, max_order + 1):
        out[n - 1] = np.sqrt(2 * n + 1) * p
        p_prev, p = p, ((2 * n + 1) * u * p - n * p_prev) / (n + 1)  # Bonnet's recursion
    return out


@dataclass(frozen=True)
class _DegreeBasis:
    degree: int
    terms: list[Term]
    orders: np.ndarray  # (F, k) order of each factor (0 where the term has fewer factors)
    delays: np.ndarray  # (F, k)


def _degree_basis(degree: int, max_delay: int) -> _DegreeBasis:
    terms = basis_terms(degree, max_delay)
    k = degree
    orders = np.zeros((len(terms), k), dtype=np.int64)
    delays = np.zeros((len(terms), k), dtype=np.int64)
    for i, term in enumerate(terms):
        for j, (d, n) in enumerate(term):
            orders[i, j], delays[i, j] = n, d
    return _DegreeBasis(degree, terms, orders, delays)


def _basis_matrix(lagged: np.ndarray, db: _DegreeBasis) -> np.ndarray:
    """(F, S) centred basis values; ``lagged`` is (max_order + 1, max_delay + 1, S) with order 0 = ones."""
    f = lagged[db.orders[:, 0], db.delays[:, 0]].copy()
    for j in range(1, db.orders.shape[1]):
        f *= lagged[db.orders[:, j], db.delays[:, j]]
    f -= f.mean(axis=1, keepdims=True)
    return f


def _lagged(u: np.ndarray, max_order: int, max_delay: int, start: int) -> np.ndarray:
    """(max_order + 1, max_delay + 1, T − start): P̃_n(u(t − d)) for t ≥ start; order 0 is the constant 1."""
    p = np.vstack([np.ones((1, len(u))), legendre_orthonormal(u, max_order)])
    samples = len(u) - start
    out = np.empty((max_order + 1, max_delay + 1, samples))
    for d in range(max_delay + 1):
        out[:, d] = p[:, start - d: start - d + samples]
    return out


@dataclass
class IPCResult:
    """Capacities of G state sets for F basis functions (all degrees, in order)."""

    labels: list[str]
    terms: list[Term]
    degrees: np.ndarray  # (F,)
    raw: np.ndarray  # (G, F) capacities before thresholding
    threshold: np.ndarray  # (G, F)
    rank: np.ndarray  # (G,)
    dims: np.ndarray  # (G,) number of state columns
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def capacity(self) -> np.ndarray:
        """(G, F) capacities after thresholding (0 where the raw value does not exceed the threshold)."""
        return np.where(self.raw > self.threshold, self.raw, 0.0)

    @property
    def total(self) -> np.ndarray:
        """(G,) total capacity."""
        return self.capacity.sum(axis=1)

    def by_degree(self) -> np.ndarray:
        """(G, max_degree) capacity summed per degree (column n−1 is degree n)."""
        cap = self.capacity
        return np.stack([cap[:, self.degrees == n].sum(axis=1) for n in range(1, int(self.degrees.max()) + 1)], 1)

    def max_delays(self) -> np.ndarray:
        """(F,) the longest delay of each basis function."""
        return np.array([max(d for d, _ in t) for t in self.terms])

    def index(self, term: Term) -> int:
        """Column of the basis function ``term`` (e.g. ((8, 1),) for P̃₁(u(t−8)))."""
        return self.terms.index(tuple(term))

    def group(self, label: str) -> int:
        return self.labels.index(label)

    def name(self, f: int) -> str:
        return " ".join(f"P{n}(u(t-{d}))" if d else f"P{n}(u(t))" for d, n in self.terms[f])

    def summary(self) -> list[dict[str, Any]]:
        """Per state set: total, per-degree totals, rank, dims."""
        bd = self.by_degree()
        return [{"label": lab, "total": float(self.total[g]), "rank": int(self.rank[g]), "dims": int(self.dims[g]),
                 "by_degree": {str(n + 1): float(bd[g, n]) for n in range(bd.shape[1])}}
                for g, lab in enumerate(self.labels)]

    def to_json(self) -> dict[str, Any]:
        return {
            "settings": self.settings,
            "basis": [{"degree": int(self.degrees[f]), "delays": [d for d, _ in t], "orders": [n for _, n in t]}
                      for f, t in enumerate(self.terms)],
            "states": [{**s, "capacity": [round(float(c), 8) for c in self.capacity[g]],
                        "raw": [round(float(c), 8) for c in self.raw[g]],
                        "threshold": [round(float(c), 8) for c in self.threshold[g]]}
                       for g, s in enumerate(self.summary())],
        }

    def write_json(self, path: str | Path) -> Path:
        path = Path(path)
        path.write_text(json.dumps(self.to_json()))
        return path


def _check_inputs(u: Any, groups: Sequence[Any], washout: int, max_delay: int) -> tuple[np.ndarray, list[np.ndarray]]:
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 1:
        raise IPCError(f"the input u must be one-dimensional (T,), got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise IPCError("the input u has non-finite values")
    if u.size and (u.min() < -1 - 1e-12 or u.max() > 1 + 1e-12):
        raise IPCError(f"the input u must lie in [-1, 1] (Legendre polynomials of a uniform input), got "
                       f"[{u.min():.4g}, {u.max():.4g}]")
    if washout < 0 or max_delay < 0:
        raise IPCError("washout and max_delay must be >= 0")
    start = max(washout, max_delay)
    if len(u) - start < 10:
        raise IPCError(f"only {len(u) - start} samples remain after the washout/max delay ({start}) of {len(u)}")
    xs = []
    for i, x in enumerate(groups):
        x = np.asarray(x, dtype=np.float64)
        x = x[:, None] if x.ndim == 1 else x
        if x.ndim != 2 or x.shape[0] != len(u):
            raise IPCError(f"state set {i} must be (T,) or (T, N) with T = {len(u)} (the input's length), "
                           f"got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise IPCError(f"state set {i} has non-finite values")
        xs.append(x)
    if not xs:
        raise IPCError("no state set given")
    return u, xs


def _orthonormal_bases(xs: list[np.ndarray], start: int, rank_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Stacked orthonormal bases (S, R) of the centred states' column spaces, and each set's rank (G,)."""
    qs, ranks = [], []
    for x in xs:
        xc = x[start:] - x[start:].mean(axis=0)
        uu, s, _ = np.linalg.svd(xc, full_matrices=False)
        r = int(np.sum(s > rank_tol * s[0])) if s.size and s[0] > 0 else 0
        qs.append(uu[:, :r])
        ranks.append(r)
    return np.hstack(qs), np.array(ranks)


def ipc_groups(
    u: Any,
    groups: Sequence[Any],
    labels: Sequence[str] | None = None,
    *,
    max_degree: int = 3,
    max_delay: int = 20,
    washout: int = 100,
    surrogates: int = 200,
    threshold: str = "degree-max",
    seed: int = 0,
    rank_tol: float = 1e-10,
    progress: bool = False,
) -> IPCResult:
    """IPC of several state sets driven by the same input.

    Args:
        u: (T,) i.i.d. input in [−1, 1].
        groups: state sets, each (T,) or (T, N_g), row t the state after input u(t) was applied.
        labels: a name per set (default "states 0", ...).
        max_degree: the basis's degrees 1..max_degree.
        max_delay: the basis's delays 0..max_delay [task steps].
        washout: samples discarded at the start (at least max_delay are always discarded).
        surrogates: shuffled-input surrogates for the threshold (0 with ``threshold="none"``).
        threshold: "degree-max", "function-max" or "none" (module docstring).
        seed: seed of the surrogate permutations.
        rank_tol: singular values below rank_tol × the largest do not count toward the rank.
        progress: a progress bar over the surrogates on stderr.
    """
    if threshold not in THRESHOLDS:
        raise IPCError(f"threshold must be one of {', '.join(THRESHOLDS)}, got {threshold!r}")
    if max_degree < 1:
        raise IPCError("max_degree must be >= 1")
    if threshold != "none" and surrogates < 1:
        raise IPCError(f"threshold {threshold!r} needs surrogates >= 1")
    u, xs = _check_inputs(u, groups, washout, max_delay)
    labels = list(labels) if labels is not None else [f"states {i}" for i in range(len(xs))]
    if len(labels) != len(xs):
        raise IPCError(f"{len(labels)} labels for {len(xs)} state sets")
    t0 = time.perf_counter()
    start = max(washout, max_delay)
    q, ranks = _orthonormal_bases(xs, start, rank_tol)
    bounds = np.concatenate([[0], np.cumsum(ranks)])
    bases = [_degree_basis(n, max_delay) for n in range(1, max_degree + 1)]

    def capacities(series: np.ndarray) -> list[np.ndarray]:
        """Per degree, (G, F_n) capacities of the basis built from ``series``."""
        lagged = _lagged(series, max_degree, max_delay, start)
        out = []
        lower: np.ndarray | None = None  # (S, k) orthonormal basis of the degree-1 functions, in-sample
        for db in bases:
            f = _basis_matrix(lagged, db)  # (F, S)
            if lower is not None:
                f -= (f @ lower) @ lower.T
            if db.degree == 1 and max_degree > 1:
                qb, rb = np.linalg.qr(f.T)
                d = np.abs(np.diag(rb))
                lower = qb[:, d > 1e-8 * d.max()]
            norm = np.einsum("fs,fs->f", f, f)
            proj = (f @ q) ** 2  # (F, R): one GEMM for every set
            per_set = np.stack([proj[:, bounds[g]: bounds[g + 1]].sum(axis=1) for g in range(len(xs))])
            out.append(per_set / np.where(norm > 0, norm, np.inf))
        return out

    raw = capacities(u)
    thr = [np.zeros_like(c) for c in raw]
    n_sur = surrogates if threshold != "none" else 0
    if n_sur:
        rng = np.random.default_rng(seed)
        import sys

        from tqdm import tqdm

        bar = tqdm(range(n_sur), desc="IPC surrogates", disable=not progress, unit="sur", file=sys.stderr,
                   mininterval=0.1 if sys.stderr.isatty() else 10.0)  # in a log file, a line every 10 s
        for _ in bar:
            for n, c in enumerate(capacities(rng.permutation(u))):
                if threshold == "degree-max":
                    thr[n] = np.maximum(thr[n], c.max(axis=1, keepdims=True))
                else:
                    thr[n] = np.maximum(thr[n], c)
    degrees = np.concatenate([np.full(len(db.terms), db.degree) for db in bases])
    terms = [t for db in bases for t in db.terms]
    settings = {"max_degree": max_degree, "max_delay": max_delay, "washout": washout, "samples": len(u) - start,
                "surrogates": n_sur, "threshold": threshold, "seed": seed, "rank_tol": rank_tol,
                "seconds": round(time.perf_counter() - t0, 3)}
    return IPCResult(labels, terms, degrees, np.hstack(raw),
                     np.hstack([np.broadcast_to(t, r.shape) for t, r in zip(thr, raw)]).copy(),
                     ranks, np.array([x.shape[1] for x in xs]), settings)


def ipc(u: Any, states: Any, **kwargs: Any) -> IPCResult:
    """IPC of one state set (T,) or (T, N); keyword arguments as :func:`ipc_groups`."""
    label = kwargs.pop("label", "states")
    return ipc_groups(u, [states], [label], **kwargs)


def to_unit_interval(u01: np.ndarray) -> np.ndarray:
    """Map an input uniform on [0, 1] (the tasks' u) to [−1, 1] (the paper: "shifting and scaling")."""
    return 2.0 * np.asarray(u01, dtype=np.float64) - 1.0


def benchmark_ipc(samples: int = 3000, masses: int = 17, max_degree: int = 3, max_delay: int = 20,
                  surrogates: int = 200, seed: int = 0) -> dict[str, Any]:
    """Time the per-mass IPC of ``masses`` × 2 axes (each coordinate its own 1-D state set) plus all of them
    together, for a synthetic fading-memory system driven by i.i.d. input (the `bptsb bench` entry)."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, samples)
    # each coordinate: a leaky nonlinear filter of the input with its own time constant
    a = np.linspace(0.2, 0.9, 2 * masses)
    x = np.zeros((samples, 2 * masses))
    for t in range(1, samples):
        x[t] = a * x[t - 1] + (1 - a) * np.tanh(1.5 * u[t] + 0.3 * x[t - 1])
    groups = [x[:, i] for i in range(2 * masses)] + [x]
    t0 = time.perf_counter()
    res = ipc_groups(u, groups, max_degree=max_degree, max_delay=max_delay, washout=100, surrogates=surrogates,
                     seed=seed)
    wall = time.perf_counter() - t0
    return {"workload": f"IPC of {masses} masses x 2 axes (+ all together), degree <= {max_degree}, "
                        f"delay <= {max_delay}, {samples} samples, {surrogates} surrogates",
            "basis_functions": len(res.terms), "state_sets": len(groups), "seconds": round(wall, 3),
            "total_capacity_all": round(float(res.total[-1]), 4), "rank_all": int(res.rank[-1])}


def infer_tau(inputs: dict[int, float]) -> int:
    """Steps each input is held, from a {step: u} series held by the rule of ``held_inputs`` (changes at
    steps jτ + 1): the smallest distance between consecutive changes."""
    steps = np.array(sorted(inputs))
    values = np.array([inputs[int(s)] for s in steps])
    changes = steps[1:][values[1:] != values[:-1]]
    if len(changes) < 2:
        raise IPCError("cannot infer τ: the task input changes fewer than twice; give --tau")
    return int(np.diff(changes).min())


@dataclass
class BagSeries:
    """One sample per task step of a recorded run: u (K,) in [0, 1], the positions at the block ends."""

    u: np.ndarray  # (K,) raw task input in [0, 1]
    positions: np.ndarray  # (K, M, 2) movable masses [m]
    movable: np.ndarray  # (M,) mass indices
    cmp_index: int
    tau: int


def bag_series(bag: str | Path, tau: int | None = None) -> BagSeries:
    """Inputs from ``task/input`` and body positions from ``body/positions`` of a recorded NARMA/memory run.

    Block j holds u_j at steps jτ+1 … (j+1)τ (``held_inputs``); its state is the position at step (j+1)τ,
    "immediately after the final step" (the paper). Blocks are taken consecutively from the start and stop
    at the first missing step or input.
    """
    from bptsb_ros.analysis.replay import read_run
    from bptsb_ros.bags.errors import BagError

    run = read_run(bag)
    if not run.inputs:
        raise BagError(f"bag {bag} has no task/input messages: IPC needs the input series of a NARMA/memory run")
    tau = int(tau) if tau else infer_tau(run.inputs)
    row = {int(s): i for i, s in enumerate(run.steps)}
    blocks = 0
    while (blocks + 1) * tau in row and blocks * tau + 1 in run.inputs:
        blocks += 1
    if blocks < 20:
        raise BagError(f"bag {bag} holds only {blocks} complete input blocks of τ = {tau} steps")
    u = np.array([run.inputs[j * tau + 1] for j in range(blocks)])
    movable = np.flatnonzero(~run.fixed)
    pos = np.stack([run.positions[row[(j + 1) * tau]][movable] for j in range(blocks)])
    return BagSeries(u, pos, movable, run.cmp_index, tau)


def mass_groups(positions: np.ndarray, movable: np.ndarray,
                cmp_index: int) -> tuple[list[np.ndarray], list[str]]:
    """State sets for the figures: the output (CMP y) if there is a CMP, every movable mass's x and y, and all
    coordinates together; ``positions`` (K, M, 2) of the masses ``movable`` (M,)."""
    groups: list[np.ndarray] = []
    labels: list[str] = []
    movable = list(int(i) for i in movable)
    if cmp_index >= 0 and cmp_index in movable:
        groups.append(positions[:, movable.index(cmp_index), 1])
        labels.append("output (CMP y)")
    for m, i in enumerate(movable):
        for a, axis in enumerate("xy"):
            groups.append(positions[:, m, a])
            labels.append(f"mass {i} {axis}")
    groups.append(positions.reshape(len(positions), -1))
    labels.append("all movable x, y")
    return groups, labels
