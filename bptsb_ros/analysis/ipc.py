"""Information processing capacity (IPC; Dambre et al., Sci. Rep. 2, 514, 2012), defined as in K. Inoue's
``ipc-module`` (PyPI, MIT licence; the implementation the paper used), computed here from that definition.

Given an i.i.d. input u(t) uniform on [−1, 1] and states X(t) (T × N), only the samples t ≥ ``start`` =
max(washout, max_delay) are used (S = T − start of them). The capacity of the states for a target f(t) is

    C[f] = 1 − min_{w, b} Σ_t (f − wᵀX − b)² / Σ_t (f − f̄)²  =  ‖Qᵀ f_c‖² / ‖f_c‖²,

f_c and X_c centred over the samples, Q (S × r) an orthonormal basis of the column space of X_c: its left
singular vectors whose singular value exceeds ``rank_tol`` × the largest (default ε·max(S, N), numpy's
``matrix_rank`` rule); r is the rank. Every target is fitted on its own (nothing is orthogonalised against other
targets). The targets are the products of orthonormal Legendre polynomials of delayed inputs,

    f(t) = ∏_i P̃_{n_i}(u(t − Δt_i)),   P̃_n = √(2n + 1) P_n,   distinct delays Δt_i ∈ [min_delay, max_delay],

of degree n = Σ n_i ≤ ``max_degree``; a function's *degree tuple* is its orders sorted, e.g. (2, 1) for
P̃₂(u(t−3))·P̃₁(u(t−7)) (degree 3 has the tuples (3,), (2, 1), (1, 1, 1)).

A finite sample gives every target a chance capacity (≈ χ²_r / S). It is removed with shuffled-input
surrogates, **one threshold per degree tuple**: for each of ``surrogates`` permutations of u (the same ones for
every tuple; permutation i from the i-th generator spawned from ``default_rng(seed)``, as the reference draws
them), the capacity of that tuple's product of the shuffled input at the delays 1, 2, …; a function is kept if
its capacity exceeds ``threshold_scale`` × the largest of its tuple's surrogate capacities (else it counts 0).
About 1/(surrogates + 1) of the functions that the states do not carry survive this (each with a capacity near
the threshold). Finally (``rank_cap``) the capacities of each state set are sorted in decreasing order and every
one whose running sum exceeds the rank is set to 0, so the total is at most the rank.

The reference's settings (ipc-module 1.0.1: ``UnivariateProfiler``, ``calc``, ``to_dataframe``), its
defaults, and their names here (default here in brackets):

* ``offset=1000`` (samples discarded)              → ``washout`` [100]; start = max(washout, max_delay);
* ``calc(n, delay_max=100)`` (delays 0 … 99)       → ``max_delay`` (inclusive: delay_max − 1) [20];
* ``zero_offset=True`` (first delay 0; False: 1)   → ``min_delay`` [0];
* ``surrogate_num=1000``, ``surrogate_seed=0``     → ``surrogates`` [1000], ``seed`` [0] (same permutations);
* ``max_scale=1.0`` (in ``to_dataframe``/``total``) → ``threshold_scale`` [1.0];
* ``truncate_by_rank=True`` (in ``to_dataframe``)  → ``rank_cap`` [True];
* ``poly_name`` (default ``"GramSchmidt"``, the input's empirical orthogonal polynomials) → always Legendre,
  the polynomials of the uniform distribution on [−1, 1] (the paper maps u to it; the two agree to O(1/√T)).

Two details differ by design: the reference divides by the uncentred Σ f² (here the centred Σ f_c², the
1 − MSE / variance definition; a relative difference of O(1/S)), and its rank rule compares the singular values
with ε·max(S, N)·σ²_max, which depends on the states' units (here ε·max(S, N)·σ_max, numpy's scale-free rule;
the two differ only for nearly singular states).

A variant (``orthogonalise_linear``; not the reference's) is for testing whether a system is linear: in a
finite sample a degree ≥ 2 function overlaps the degree-1 functions by O(1/√S) (Σ_t u(t)u(t−1)u(t−2)·u(t−3) ≠ 0),
so a state with a strong linear part has chance capacities for the degree ≥ 2 functions that come in clusters
(the same overlap at every shift of the delays) and survive the per-tuple thresholds far more often than
1/(surrogates + 1); e.g. a linear 8-mass chain shows a degree-3 "capacity" of up to 0.2 at 700 samples. With
the variant every degree ≥ 2 function and every degree ≥ 2 surrogate target is first made orthogonal, in-sample,
to the span of the degree-1 functions of u (delays min_delay..max_delay), so a linear system has none above
degree 1. It lowers the degree ≥ 2 capacities of nonlinear systems by the part they share with
linear functions in-sample.

Several state sets sharing one input (each mass's x, each mass's y, the output, all together) are computed in
one pass: the basis functions (in chunks) and the surrogate targets (in chunks of permutations) are built once
and projected onto the stacked orthonormal bases of all sets with one GEMM. Everything is float64.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

THRESHOLDS = ("tuple-max", "none")
#: elements of one chunk of basis-function or surrogate values (float64: 8 MB; at 32 MB a process's first call
#: spent more time faulting in its fresh buffers than computing: 0.43 s against 0.19 s for a 34-state body)
_CHUNK = 1_000_000


class IPCError(ValueError):
    """Input or states unsuitable for an IPC computation; one line naming the problem."""


Term = tuple[tuple[int, int], ...]  # ((delay, order), ...), delays strictly increasing
DegreeTuple = tuple[int, ...]  # the orders of a term, sorted in decreasing order: (2, 1)


def basis_terms(degree: int, max_delay: int, min_delay: int = 0) -> list[Term]:
    """Every product of Legendre polynomials of total degree ``degree`` over distinct delays
    min_delay..max_delay: ((Δt₁, n₁), (Δt₂, n₂), ...) with Δt₁ < Δt₂ < … and Σ nᵢ = ``degree``."""
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

    grow(min_delay, degree, [])
    return out


def degree_tuple(term: Term) -> DegreeTuple:
    """The orders of ``term`` in decreasing order, e.g. (2, 1) for ((3, 2), (7, 1)) and for ((3, 1), (7, 2))."""
    return tuple(sorted((n for _, n in term), reverse=True))


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
    orders: np.ndarray  # (F, degree) order of each factor (0: the constant 1, where the term has fewer factors)
    delays: np.ndarray  # (F, degree)


def _degree_basis(degree: int, max_delay: int, min_delay: int) -> _DegreeBasis:
    terms = basis_terms(degree, max_delay, min_delay)
    orders = np.zeros((len(terms), degree), dtype=np.int64)
    delays = np.full((len(terms), degree), min_delay, dtype=np.int64)
    for i, term in enumerate(terms):
        for j, (d, n) in enumerate(term):
            orders[i, j], delays[i, j] = n, d
    return _DegreeBasis(degree, terms, orders, delays)


def _centred_product(factors: Sequence[np.ndarray]) -> np.ndarray:
    f = factors[0] * factors[1] if len(factors) > 1 else factors[0].copy()
    for g in factors[2:]:
        f *= g
    f -= f.mean(axis=-1, keepdims=True)
    return f


def _linear_basis(lin: np.ndarray) -> np.ndarray:
    """(S, D) orthonormal basis of the span of the centred degree-1 functions ``lin`` (D, S)."""
    q, r = np.linalg.qr((lin - lin.mean(axis=1, keepdims=True)).T)
    d = np.abs(np.diag(r))
    return q[:, d > 1e-10 * d.max()] if d.size and d.max() > 0 else q[:, :0]


def _capacities(f: np.ndarray, q: np.ndarray, member: np.ndarray) -> np.ndarray:
    """(n, G) capacities of the centred targets ``f`` (n, S) for the orthonormal bases ``q`` (S, R) of G state
    sets (``member`` (R, G): which set each column belongs to)."""
    norm = np.einsum("ns,ns->n", f, f)
    proj = (f @ q) ** 2 @ member
    return proj / np.where(norm > 0, norm, np.inf)[:, None]


@dataclass
class IPCResult:
    """Capacities of G state sets for F basis functions (all degrees, in order)."""

    labels: list[str]
    terms: list[Term]
    degrees: np.ndarray  # (F,)
    raw: np.ndarray  # (G, F) every function's own capacity, before thresholding
    threshold: np.ndarray  # (G, F) its tuple's threshold (threshold_scale × the largest surrogate capacity)
    rank: np.ndarray  # (G,)
    dims: np.ndarray  # (G,) number of state columns
    surrogate: dict[DegreeTuple, np.ndarray] = field(default_factory=dict)  # tuple -> (surrogates, G) capacities
    rank_cap: bool = True
    settings: dict[str, Any] = field(default_factory=dict)

    @cached_property
    def tuples(self) -> list[DegreeTuple]:
        """(F,) the degree tuple of each basis function."""
        return [degree_tuple(t) for t in self.terms]

    @cached_property
    def capacity(self) -> np.ndarray:
        """(G, F) capacities: 0 where the raw value does not exceed the threshold, then (``rank_cap``) 0 where
        the running sum of the capacities in decreasing order exceeds the rank."""
        cap = np.where(self.raw > self.threshold, self.raw, 0.0)
        if self.rank_cap:
            order = np.argsort(-cap, axis=1, kind="stable")
            running = np.cumsum(np.take_along_axis(cap, order, axis=1), axis=1)
            over = running > self.rank[:, None] * (1 + 1e-12) + 1e-9  # tolerance: sums of exact 1s
            np.put_along_axis(cap, order, np.where(over, 0.0, np.take_along_axis(cap, order, axis=1)), axis=1)
        return cap

    @property
    def total(self) -> np.ndarray:
        """(G,) total capacity."""
        return self.capacity.sum(axis=1)

    def by_degree(self) -> np.ndarray:
        """(G, max_degree) capacity summed per degree (column n−1 is degree n)."""
        cap = self.capacity
        return np.stack([cap[:, self.degrees == n].sum(axis=1) for n in range(1, int(self.degrees.max()) + 1)], 1)

    def by_tuple(self) -> dict[DegreeTuple, np.ndarray]:
        """Degree tuple -> (G,) capacity summed over its functions."""
        cap, tuples = self.capacity, self.tuples
        return {t: cap[:, [i for i, s in enumerate(tuples) if s == t]].sum(axis=1)
                for t in dict.fromkeys(tuples)}

    def tuple_thresholds(self) -> dict[DegreeTuple, np.ndarray]:
        """Degree tuple -> (G,) its threshold."""
        first = {t: i for i, t in reversed(list(enumerate(self.tuples)))}
        return {t: self.threshold[:, first[t]] for t in dict.fromkeys(self.tuples)}

    def nonlinear_memory(self) -> np.ndarray:
        """(G,) capacity of the basis functions of degree ≥ 2 that involve a past input (longest delay ≥ 1): the
        nonlinear memory of each state set, as opposed to its instantaneous nonlinearity (delay 0 only)."""
        return self.capacity[:, (self.degrees >= 2) & (self.max_delays() >= 1)].sum(axis=1)

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
        """Per state set: total, per-degree and per-tuple totals, per-tuple thresholds, rank, dims."""
        bd, bt, thr = self.by_degree(), self.by_tuple(), self.tuple_thresholds()
        return [{"label": lab, "total": float(self.total[g]), "rank": int(self.rank[g]), "dims": int(self.dims[g]),
                 "by_degree": {str(n + 1): float(bd[g, n]) for n in range(bd.shape[1])},
                 "by_tuple": {",".join(map(str, t)): float(v[g]) for t, v in bt.items()},
                 "thresholds": {",".join(map(str, t)): float(v[g]) for t, v in thr.items()}}
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
        from bptsb_ros.files.safe_write import write_atomic

        return write_atomic(path, json.dumps(self.to_json()))


def _check_inputs(u: Any, groups: Sequence[Any], washout: int, max_delay: int,
                  min_delay: int) -> tuple[np.ndarray, list[np.ndarray]]:
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 1:
        raise IPCError(f"the input u must be one-dimensional (T,), got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise IPCError("the input u has non-finite values")
    if u.size and (u.min() < -1 - 1e-12 or u.max() > 1 + 1e-12):
        raise IPCError(f"the input u must lie in [-1, 1] (Legendre polynomials of a uniform input), got "
                       f"[{u.min():.4g}, {u.max():.4g}]")
    if washout < 0 or max_delay < 0 or min_delay < 0:
        raise IPCError("washout, min_delay and max_delay must be >= 0")
    if min_delay > max_delay:
        raise IPCError(f"min_delay ({min_delay}) must not exceed max_delay ({max_delay})")
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


def _orthonormal_bases(xs: list[np.ndarray], start: int,
                       rank_tol: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Stacked orthonormal bases (S, R) of the centred states' column spaces, and each set's rank (G,)."""
    qs, ranks = [], []
    for x in xs:
        xc = x[start:] - x[start:].mean(axis=0)
        qx, r_x = np.linalg.qr(xc)  # (S, N), (N, N): the SVD of the small R is cheaper than that of X_c
        ur, s, _ = np.linalg.svd(r_x)
        uu = qx @ ur
        tol = np.finfo(np.float64).eps * max(xc.shape) if rank_tol is None else rank_tol
        r = int(np.sum(s > tol * s[0])) if s.size and s[0] > 0 else 0
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
    min_delay: int = 0,
    washout: int = 100,
    surrogates: int = 1000,
    threshold: str = "tuple-max",
    threshold_scale: float = 1.0,
    rank_cap: bool = True,
    orthogonalise_linear: bool = False,
    seed: int = 0,
    rank_tol: float | None = None,
    progress: bool = False,
) -> IPCResult:
    """IPC of several state sets driven by the same input (definitions and the reference's defaults: the
    module docstring).

    Args:
        u: (T,) i.i.d. input in [−1, 1].
        groups: state sets, each (T,) or (T, N_g), row t the state after input u(t) was applied.
        labels: a name per set (default "states 0", ...).
        max_degree: the basis's degrees 1..max_degree.
        max_delay: the basis's largest delay [task steps] (the reference: 99).
        min_delay: the basis's smallest delay [task steps] (the reference: 0).
        washout: samples discarded at the start (at least max_delay are always discarded; the reference: 1000).
        surrogates: shuffled-input surrogates per degree tuple (ignored with ``threshold="none"``).
        threshold: "tuple-max" (a function counts if its capacity exceeds threshold_scale × the largest
            surrogate capacity of its degree tuple) or "none" (raw capacities).
        threshold_scale: the factor on the surrogate maximum (the reference's ``max_scale``).
        rank_cap: drop the smallest capacities of a set while their total exceeds its rank.
        orthogonalise_linear: the linearity-test variant (module docstring); not the reference's definition.
        seed: seed of the surrogate permutations.
        rank_tol: singular values ≤ rank_tol × the largest do not count toward the rank (default ε·max(S, N)).
        progress: a progress bar over the surrogates on stderr.
    """
    if threshold not in THRESHOLDS:
        raise IPCError(f"threshold must be one of {', '.join(THRESHOLDS)}, got {threshold!r}")
    if max_degree < 1:
        raise IPCError("max_degree must be >= 1")
    if threshold != "none" and surrogates < 1:
        raise IPCError(f"threshold {threshold!r} needs surrogates >= 1")
    if not (math.isfinite(threshold_scale) and threshold_scale >= 0):
        raise IPCError(f"threshold_scale must be a finite number >= 0, got {threshold_scale}")
    u, xs = _check_inputs(u, groups, washout, max_delay, min_delay)
    labels = list(labels) if labels is not None else [f"states {i}" for i in range(len(xs))]
    if len(labels) != len(xs):
        raise IPCError(f"{len(labels)} labels for {len(xs)} state sets")
    t0 = time.perf_counter()
    start = max(washout, max_delay)
    samples = len(u) - start
    q, ranks = _orthonormal_bases(xs, start, rank_tol)
    member = np.zeros((q.shape[1], len(xs)))
    member[np.arange(q.shape[1]), np.repeat(np.arange(len(xs)), ranks)] = 1.0
    bases = [b for b in (_degree_basis(n, max_delay, min_delay) for n in range(1, max_degree + 1)) if b.terms]
    # table[n, t] = P̃_n(u(t)), order 0 the constant 1; lagged[n, d, s] = P̃_n(u(start + s − d))
    table = np.vstack([np.ones((1, len(u))), legendre_orthonormal(u, max_degree)])
    lagged = np.stack([table[:, start - d: start - d + samples] for d in range(max_delay + 1)], axis=1)

    delays = np.arange(min_delay, max_delay + 1)
    # orthonormal basis of the centred degree-1 functions, in-sample (orthogonalise_linear only)
    lin = _linear_basis(lagged[1, delays]) if orthogonalise_linear else None

    raw_parts = []
    for db in bases:
        rows = max(1, _CHUNK // samples)
        for lo in range(0, len(db.terms), rows):
            o, d = db.orders[lo: lo + rows], db.delays[lo: lo + rows]
            f = _centred_product([lagged[o[:, j], d[:, j]] for j in range(db.degree)])
            if lin is not None and db.degree > 1:
                f -= (f @ lin) @ lin.T
            raw_parts.append(_capacities(f, q, member).T)
    raw = np.hstack(raw_parts)
    terms = [t for db in bases for t in db.terms]
    tuples = list(dict.fromkeys(degree_tuple(t) for t in terms))
    n_sur = surrogates if threshold != "none" else 0
    sur = {t: np.zeros((n_sur, len(xs))) for t in tuples}
    if n_sur:
        from tqdm import tqdm

        per = max(1, _CHUNK // ((max_degree + 1) * len(u)))
        # permutation i from the i-th generator spawned from default_rng(seed): the reference's convention,
        # so that the same seed gives the same surrogates (and the chunking does not matter)
        children = np.random.default_rng(seed).spawn(n_sur)
        bar = tqdm(total=n_sur, desc="IPC surrogates", disable=not progress, unit="sur", file=sys.stderr,
                   mininterval=0.1 if sys.stderr.isatty() else 10.0)  # in a log file, a line every 10 s
        for lo in range(0, n_sur, per):
            n = min(per, n_sur - lo)
            perms = np.stack([g.permutation(len(u)) for g in children[lo: lo + n]])
            shuffled = np.take(table, perms, axis=1)  # (orders + 1, n, T); take: 3-4 times faster than [:, perms]
            for t in tuples:
                lag = 1 if start >= len(t) else 0  # the reference's delays 1, 2, …; any distinct ones would do
                f = _centred_product([shuffled[o, :, start - lag - i: start - lag - i + samples]
                                      for i, o in enumerate(t)])
                if lin is not None and sum(t) > 1:  # the null of an orthogonalised function: in the same space
                    f -= (f @ lin) @ lin.T
                sur[t][lo: lo + n] = _capacities(f, q, member)
            bar.update(n)
        bar.close()
    thr_tuple = {t: threshold_scale * s.max(axis=0) if n_sur else np.zeros(len(xs)) for t, s in sur.items()}
    thr = np.stack([thr_tuple[degree_tuple(t)] for t in terms], axis=1)
    degrees = np.array([sum(n for _, n in t) for t in terms])
    settings = {"definition": "orthogonalised-linear" if orthogonalise_linear else "ipc-module",
                "max_degree": max_degree, "max_delay": max_delay, "min_delay": min_delay, "washout": washout,
                "samples": samples, "surrogates": n_sur,
                "threshold": threshold, "threshold_scale": threshold_scale, "rank_cap": rank_cap, "seed": seed,
                "rank_tol": rank_tol, "seconds": round(time.perf_counter() - t0, 3)}
    return IPCResult(labels, terms, degrees, raw, thr, ranks, np.array([x.shape[1] for x in xs]), sur, rank_cap,
                     settings)


def ipc(u: Any, states: Any, **kwargs: Any) -> IPCResult:
    """IPC of one state set (T,) or (T, N); keyword arguments as :func:`ipc_groups`."""
    label = kwargs.pop("label", "states")
    return ipc_groups(u, [states], [label], **kwargs)


def to_unit_interval(u01: np.ndarray) -> np.ndarray:
    """Map an input uniform on [0, 1] (the tasks' u) to [−1, 1] (the paper: "shifting and scaling")."""
    return 2.0 * np.asarray(u01, dtype=np.float64) - 1.0


def tanh_reservoir(samples: int, units: int, seed: int = 0, spectral_radius: float = 0.9,
                   input_scale: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """A random tanh echo-state network driven by i.i.d. u ~ U(−1, 1): (u (T,), states (T, units))."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, samples)
    w = rng.normal(size=(units, units))
    w *= spectral_radius / np.abs(np.linalg.eigvals(w)).max()
    w_in = input_scale * rng.uniform(-1, 1, units)
    x = np.zeros((samples, units))
    s = np.zeros(units)
    for t in range(samples):
        s = np.tanh(w @ s + w_in * u[t])
        x[t] = s
    return u, x


def benchmark_ipc(samples: int = 3000, masses: int = 17, max_degree: int = 3, max_delay: int = 20,
                  surrogates: int = 1000, seed: int = 0) -> dict[str, Any]:
    """Time two IPC workloads (the `bptsb bench` entry), each with the reference definition and with
    ``orthogonalise_linear``: the per-mass IPC of ``masses`` × 2 axes (each coordinate its own 1-D state set)
    plus all of them together, for a synthetic fading-memory system; and one 2·``masses``-unit tanh reservoir
    as a single state set. Both driven by i.i.d. input, ``samples`` samples."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1, 1, samples)
    # each coordinate: a leaky nonlinear filter of the input with its own time constant
    a = np.linspace(0.2, 0.9, 2 * masses)
    x = np.zeros((samples, 2 * masses))
    for t in range(1, samples):
        x[t] = a * x[t - 1] + (1 - a) * np.tanh(1.5 * u[t] + 0.3 * x[t - 1])
    groups = [x[:, i] for i in range(2 * masses)] + [x]
    ur, xr = tanh_reservoir(samples, 2 * masses, seed)
    opts = dict(max_degree=max_degree, max_delay=max_delay, washout=100, surrogates=surrogates, seed=seed)

    def timed(u: np.ndarray, groups: list[np.ndarray], orth: bool) -> tuple[IPCResult, float]:
        t0 = time.perf_counter()
        res = ipc_groups(u, groups, orthogonalise_linear=orth, **opts)
        return res, float(f"{time.perf_counter() - t0:.4g}")  # 4 significant digits: a tiny workload is not 0 s

    res, wall = timed(u, groups, False)
    _, wall_orth = timed(u, groups, True)
    rres, rwall = timed(ur, [xr], False)
    _, rwall_orth = timed(ur, [xr], True)
    return {"workload": f"IPC of {masses} masses x 2 axes (+ all together), degree <= {max_degree}, "
                        f"delay <= {max_delay}, {samples} samples, {surrogates} surrogates per degree tuple",
            "basis_functions": len(res.terms), "state_sets": len(groups), "seconds": wall,
            "seconds_orthogonalise_linear": wall_orth,
            "total_capacity_all": round(float(res.total[-1]), 4), "rank_all": int(res.rank[-1]),
            "reservoir": {"workload": f"IPC of a {2 * masses}-unit tanh reservoir (one state set), same basis "
                                      "and surrogates",
                          "seconds": rwall, "seconds_orthogonalise_linear": rwall_orth,
                          "by_degree": [round(float(v), 4) for v in rres.by_degree()[0]], "rank": int(rres.rank[0])}}


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
    from bptsb_ros.analysis.bag_run import read_run
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
