"""Draw a body layout to an image: fixed and movable masses, the CMP, springs, and their indices."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bptsb_ros.body.shapes import Topology
from bptsb_ros.files.safe_write import atomic_writer

FIXED_COLOR = "#5f5f5f"
MOVABLE_COLOR = "#0072B2"  # the style's blue, vermillion and green (Okabe-Ito: colour-blind safe)
CMP_COLOR = "#D55E00"
SPRING_COLOR = "#9a9a9a"
SPRING_LABEL_COLOR = "#007350"


def render_topology(
    topology: Topology,
    path: str | Path,
    *,
    mass_labels: bool = True,
    spring_labels: bool = True,
    title: str | None = None,
    dpi: int | None = None,
) -> Path:
    """Write a labelled drawing of ``topology`` (positions in metres) to ``path`` (PNG, SVG or PDF), in the
    package's figure style (:mod:`bptsb_ros.analysis.style`; ``dpi`` default its :data:`~bptsb_ros.analysis.style.DPI`).

    Masses are drawn as grey squares (fixed), blue circles (movable) and a red star (CMP), each with
    its index; springs as lines with their index (green, at the midpoint).
    """
    from bptsb_ros.analysis.style import DPI, RC, plt

    with plt.rc_context(RC):
        return _render(topology, Path(path), mass_labels, spring_labels, title, DPI if dpi is None else dpi)


def _render(topology: Topology, path: Path, mass_labels: bool, spring_labels: bool, title: str | None,
            dpi: int) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.lines import Line2D

    pos = np.asarray(topology.positions, dtype=float)
    springs = np.asarray(topology.springs)
    fixed = np.asarray(topology.fixed, dtype=bool)
    cmp = topology.cmp_index
    extent = float(np.ptp(pos, axis=0).max()) or 1.0
    crowd = max(topology.n_masses, topology.n_springs / 2)
    font = float(np.clip(300.0 / crowd, 5.0, 9.0))
    side = float(np.clip(5.0 + crowd / 12.0, 6.0, 12.0))

    fig, ax = plt.subplots(figsize=(side, side * 0.9 if topology.name != "caterpillar" else side * 0.6))
    segments = pos[springs]
    ax.add_collection(LineCollection(segments, colors=SPRING_COLOR, linewidths=1.2, zorder=1))
    if spring_labels:
        label_dir = _label_directions(pos)
        for e, (x, y) in enumerate(_spring_label_positions(pos, springs, label_dir, 0.06 * extent)):
            ax.text(x, y, str(e), fontsize=font * 0.85, color=SPRING_LABEL_COLOR, ha="center", va="center",
                    zorder=2, bbox={"boxstyle": "round,pad=0.12", "fc": "white", "ec": "none", "alpha": 0.85})
    movable = ~fixed
    is_cmp = np.zeros_like(fixed)
    if cmp >= 0:
        is_cmp[cmp] = True
    marker_size = float(np.clip(2400.0 / crowd, 30.0, 160.0))
    ax.scatter(*pos[fixed].T, marker="s", s=marker_size, c=FIXED_COLOR, zorder=3, edgecolors="black")
    ax.scatter(*pos[movable & ~is_cmp].T, marker="o", s=marker_size, c=MOVABLE_COLOR, zorder=3, edgecolors="black")
    if cmp >= 0:
        ax.scatter(*pos[cmp], marker="*", s=marker_size * 2.2, c=CMP_COLOR, zorder=4, edgecolors="black")
    if mass_labels:
        offset = 0.5 * marker_size**0.5 + font * 0.6  # just outside the marker [points]
        for i, ((x, y), (dx, dy)) in enumerate(zip(pos, _label_directions(pos))):
            ax.annotate(str(i), (x, y), xytext=(offset * dx, offset * dy), textcoords="offset points",
                        fontsize=font, fontweight="bold", color="black", ha="center", va="center", zorder=5)

    handles = []
    if fixed.any():
        handles.append(Line2D([], [], marker="s", ls="", color=FIXED_COLOR, mec="black",
                              label=f"fixed mass ({int(fixed.sum())})"))
    handles.append(Line2D([], [], marker="o", ls="", color=MOVABLE_COLOR, mec="black",
                          label=f"movable mass ({int((movable & ~is_cmp).sum())})"))
    if cmp >= 0:
        handles.append(Line2D([], [], marker="*", ls="", ms=12, color=CMP_COLOR, mec="black",
                              label=f"centre mass point (CMP, mass {cmp})"))
    handles.append(Line2D([], [], color=SPRING_COLOR, lw=1.5, label=f"spring ({topology.n_springs})"))
    if spring_labels:
        handles.append(Line2D([], [], ls="", marker="$e$", color=SPRING_LABEL_COLOR, label="spring index"))
    if mass_labels:
        handles.append(Line2D([], [], ls="", marker="$i$", color="black", label="mass index"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=9)

    pad = 0.08 * extent
    ax.set_xlim(pos[:, 0].min() - pad, pos[:, 0].max() + pad)
    ax.set_ylim(pos[:, 1].min() - pad, pos[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3, alpha=0.5)
    n_mov = int(movable.sum())
    ax.set_title(title or f"{topology.name}: {topology.n_masses} masses ({n_mov} movable), "
                 f"{topology.n_springs} springs")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path) as f:
        fig.savefig(f, format=path.suffix[1:] or "png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def _label_directions(pos: np.ndarray) -> np.ndarray:
    """(N, 2) unit vectors pointing away from the layout's centre (up-right at the centre): where mass
    indices go, between the springs that come from further out."""
    rel = pos - pos.mean(axis=0)
    norm = np.linalg.norm(rel, axis=1, keepdims=True)
    default = np.full_like(rel, np.sqrt(0.5))
    return np.where(norm > 1e-9 * max(float(norm.max()), 1.0), rel / np.maximum(norm, 1e-300), default)


def _spring_label_positions(pos: np.ndarray, springs: np.ndarray, label_dir: np.ndarray,
                            clearance: float) -> np.ndarray:
    """(E, 2) label anchors on each spring: the midpoint, or the nearest point along the spring that
    keeps ``clearance`` [m] from masses, mass labels and earlier spring labels."""
    taken = list(pos) + list(pos + 0.8 * clearance * label_dir)
    out = np.zeros((len(springs), 2))
    for e, (i, j) in enumerate(springs):
        best, best_gap = None, -1.0
        for t in (0.5, 0.4, 0.6, 0.32, 0.68, 0.25, 0.75):
            p = pos[i] + t * (pos[j] - pos[i])
            gap = float(np.min(np.linalg.norm(np.asarray(taken) - p, axis=1)))
            if gap >= clearance:
                best = p
                break
            if gap > best_gap:
                best, best_gap = p, gap
        out[e] = best
        taken.append(best)
    return out
