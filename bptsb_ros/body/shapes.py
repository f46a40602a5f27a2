"""Body geometries: where the masses sit, which springs connect them, which masses are fixed.

A shape is pure topology + initial geometry; no physics lives here. Coordinates are in metres
(simulation units), the origin is the centre of circular bodies, y points up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: the body shapes (the registry: the config's ``body.shape``, ``bptsb simulate --shape`` and ``bptsb render --shape``
#: read it), each with its default number of masses (fixed ones included)
DEFAULT_NODES: dict[str, int] = {"double_circle": 25, "multiple_circle": 17, "caterpillar": 10}
SHAPES = tuple(DEFAULT_NODES)
#: Largest body accepted (masses, fixed ones included). The dense spring operators grow as N²: building a
#: 2,001-mass double circle peaks at about 650 MB RSS (measured), 8,001 would need about 7 GB. The paper's
#: largest body has 65 masses.
MAX_MASSES = 2001


@dataclass(frozen=True)
class Topology:
    """A mass-spring network layout.

    Attributes:
        name: shape name (one of ``SHAPES``).
        positions: (N, 2) initial mass positions [m].
        springs: (E, 2) int mass indices (i, j) of each spring, i != j.
        fixed: (N,) bool, True for masses pinned in place.
        cmp_index: index of the central mass point, or -1 when the shape has none.
    """

    name: str
    positions: np.ndarray
    springs: np.ndarray
    fixed: np.ndarray
    cmp_index: int

    @property
    def n_masses(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_springs(self) -> int:
        return int(self.springs.shape[0])

    @property
    def movable(self) -> np.ndarray:
        """(N_mov,) indices of movable masses, ascending."""
        return np.flatnonzero(~self.fixed)

    def rest_lengths(self) -> np.ndarray:
        """(E,) geometric spring lengths of the initial layout [m]."""
        p = self.positions
        return np.linalg.norm(p[self.springs[:, 0]] - p[self.springs[:, 1]], axis=1)


def _ring(count: int, radius: float, offset: float) -> np.ndarray:
    """Masses on a circle: angle (k + offset)·2π/count, x = r sin θ, y = r cos θ (0 on top, clockwise)."""
    theta = (np.arange(count) + offset) * 2.0 * math.pi / count
    return np.stack([radius * np.sin(theta), radius * np.cos(theta)], axis=1)


def double_circle(n_masses: int = 25, size: float = 4.0) -> Topology:
    """Two concentric rings and a centre mass point (CMP).

    Outer ring (M = (N-1)/2 masses, radius size/2) fixed; inner ring (M masses, radius size/4,
    rotated by half a spacing) and CMP (last index) movable. Springs: each outer mass to its two
    neighbouring inner masses, the closed inner ring, and every inner mass to the CMP (4M springs).
    """
    if n_masses < 7 or n_masses % 2 == 0:
        raise ValueError(f"double_circle needs an odd number of masses >= 7, got n_masses={n_masses}")
    m = (n_masses - 1) // 2
    pos = np.concatenate([_ring(m, size / 2, 0.0), _ring(m, size / 4, 0.5), np.zeros((1, 2))])
    outer = np.arange(m)
    inner = m + np.arange(m)
    cmp = 2 * m
    springs = np.concatenate(
        [
            np.stack([outer, inner], 1),  # outer k -> inner k (angle +half spacing)
            np.stack([outer, m + (outer - 1) % m], 1),  # outer k -> inner k-1 (angle -half spacing)
            np.stack([inner, m + (np.arange(m) + 1) % m], 1),  # closed inner ring
            np.stack([inner, np.full(m, cmp)], 1),  # spokes to the CMP
        ]
    )
    fixed = np.zeros(n_masses, dtype=bool)
    fixed[:m] = True
    return Topology("double_circle", pos, springs.astype(np.int64), fixed, cmp)


def multiple_circle(n_masses: int = 17, size: float = 4.0) -> Topology:
    """c nested square-ish rings around a CMP, for N = 4c² + 1 masses (17, 37, 65, ...).

    Ring i (0 = outermost) holds 4(2(c-i)-1) masses at radius (size/2)(c-i)/c, every other ring
    rotated by half a spacing. Each ring links to the next inner one (ring corners: three
    consecutive outer masses share one inner mass), inner rings are closed, the innermost ring links
    to the CMP (last index). The outermost ring is fixed. ``n_masses`` counts every mass.
    """
    c = int(round(math.sqrt((n_masses - 1) / 4)))
    if c < 2 or 4 * c * c + 1 != n_masses:
        raise ValueError(
            f"multiple_circle needs n_masses = 4c²+1 with c >= 2 (17, 37, 65, ...), got {n_masses}"
        )
    rings: list[np.ndarray] = []
    starts: list[int] = []
    pos_list = []
    start = 0
    for i in range(c):
        count = 4 * (2 * (c - i) - 1)
        pos_list.append(_ring(count, (size / 2) * (c - i) / c, 0.5 * (i % 2)))
        rings.append(np.arange(count) + start)
        starts.append(start)
        start += count
    cmp = start
    pos = np.concatenate(pos_list + [np.zeros((1, 2))])
    springs: list[tuple[int, int]] = []
    for i in range(c):
        outer = rings[i]
        if i > 0:  # inner rings are closed; the fixed outermost ring needs no springs
            springs += [(int(outer[k]), int(outer[(k + 1) % len(outer)])) for k in range(len(outer))]
        if i == c - 1:
            springs += [(int(o), cmp) for o in outer]
            continue
        inner = rings[i + 1]
        # Link each outer mass to its angularly nearest inner mass(es): the outer ring has 8 more
        # masses than the inner one, so at the 4 corners three outer masses share an inner mass.
        n_out, n_in = len(outer), len(inner)
        ang_out = (np.arange(n_out) + 0.5 * (i % 2)) / n_out
        ang_in = (np.arange(n_in) + 0.5 * ((i + 1) % 2)) / n_in
        for k in range(n_out):
            delta = np.abs(((ang_in - ang_out[k]) + 0.5) % 1.0 - 0.5)
            springs.append((int(outer[k]), int(inner[int(np.argmin(delta))])))
    fixed = np.zeros(len(pos), dtype=bool)
    fixed[rings[0]] = True
    return Topology("multiple_circle", pos, np.asarray(springs, dtype=np.int64), fixed, cmp)


def caterpillar(n_masses: int = 10, neighbours: int = 3) -> Topology:
    """Caterpillar robot: a chain of masses, all movable; mass k connects to k+1 … k+neighbours.

    x_k = k - N/2 + 0.5; y_k = 4(1 - (2 x_k / N)²) for even k (the back), 0 for odd k (the feet).
    N = 10, neighbours = 3 gives 24 springs. There is no CMP (cmp_index = -1).
    """
    if n_masses < 2 or neighbours < 1:
        raise ValueError(f"caterpillar needs n_masses >= 2 and neighbours >= 1, got {n_masses}, {neighbours}")
    k = np.arange(n_masses)
    x = k - n_masses / 2 + 0.5
    y = np.where(k % 2 == 0, 4.0 * (1 - (2 * x / n_masses) ** 2), 0.0)
    springs = [(i, j) for i in range(n_masses) for j in range(i + 1, min(i + neighbours, n_masses - 1) + 1)]
    return Topology(
        "caterpillar",
        np.stack([x, y], 1).astype(np.float64),
        np.asarray(springs, dtype=np.int64),
        np.zeros(n_masses, dtype=bool),
        -1,
    )


def nodes_for_movable(name: str, n_movable: int) -> int:
    """The ``n_masses`` (every mass, fixed ones included) of the ``name`` body with ``n_movable`` movable masses.

    The paper counts bodies by their movable masses N_mov (N = N_mov + N_fix; brain outputs 2(N_mov − 1),
    readout 20·N_mov states), for the multiple circle as for the double circle. Double circle: N = 2 N_mov − 1
    (M = N_mov − 1 inner masses, as many fixed outer ones, the CMP); multiple circle with c rings: the fixed
    outer ring holds 4(2c − 1) of the 4c² + 1 masses, so N_mov = 4(c − 1)² + 1 (5, 17, 37, 65, 101, ... for
    c = 2, 3, ...) and N = 4c² + 1 (N_mov 17 → 37 masses, 65 → 101); caterpillar: every mass is movable.

    Raises:
        ValueError: no body of that shape has exactly ``n_movable`` movable masses.
    """
    if name == "double_circle":
        if n_movable < 4:
            raise ValueError(f"a double_circle has at least 4 movable masses (7 masses), got n_movable={n_movable}")
        return 2 * n_movable - 1
    if name == "multiple_circle":
        inner = int(round(math.sqrt(max(n_movable - 1, 0) / 4)))  # c − 1
        if inner < 1 or 4 * inner * inner + 1 != n_movable:
            raise ValueError("a multiple_circle has n_movable = 4(c−1)²+1 movable masses with c >= 2 (5, 17, 37, "
                             f"65, 101, ...), got {n_movable}")
        return 4 * (inner + 1) ** 2 + 1
    if name == "caterpillar":
        if n_movable < 2:
            raise ValueError(f"caterpillar needs n_masses >= 2, got n_movable={n_movable}")
        return n_movable
    raise ValueError(f"unknown shape {name!r}; choose one of {', '.join(SHAPES)}")


def build_shape(name: str, n_masses: int, size: float = 4.0, neighbours: int = 3) -> Topology:
    """Build a shape by name; ``size`` is the diameter of circular bodies [m] (at most ``MAX_MASSES`` masses)."""
    if n_masses > MAX_MASSES:
        raise ValueError(f"{n_masses} masses is more than the maximum of {MAX_MASSES} (memory grows as masses²)")
    if not math.isfinite(size) or size <= 0:
        raise ValueError(f"size must be a finite positive diameter [m], got {size}")
    if name == "double_circle":
        return double_circle(n_masses, size)
    if name == "multiple_circle":
        return multiple_circle(n_masses, size)
    if name == "caterpillar":
        return caterpillar(n_masses, neighbours)
    raise ValueError(f"unknown shape {name!r}; choose one of {', '.join(SHAPES)}")
