"""Animate a simulated trajectory as a GIF: springs coloured by strain, masses, and the CMP's trail."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bptsb_ros.files.safe_write import atomic_writer
from bptsb_ros.sim.trajectory import Trajectory

STRAIN_LIMIT = 0.3  # colour scale saturates at ±30 % strain


def frame_indices(steps: int, max_frames: int) -> np.ndarray:
    """Rows of a (steps+1)-row trajectory to draw: every ``stride``-th row, the last one included."""
    if max_frames < 2:
        raise ValueError(f"max_frames must be >= 2, got {max_frames}")
    stride = max(1, math.ceil((steps + 1) / max_frames))
    rows = np.arange(0, steps + 1, stride)
    return rows if rows[-1] == steps else np.append(rows, steps)


def animate_trajectory(
    traj: Trajectory,
    path: str | Path,
    *,
    fps: int = 25,
    max_frames: int = 200,
    trail: bool = True,
    dpi: int = 80,
    title: str | None = None,
) -> Path:
    """Write an animated GIF of ``traj`` to ``path``.

    At most ``max_frames`` frames are drawn (rows are subsampled evenly). Springs are coloured by
    strain (L − l)/l against the rest length in force (blue compressed, red stretched); the trail
    is the CMP's path, or the centre of all masses for shapes without a CMP.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from PIL import Image

    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"animation path must end in .gif, got {path}")
    rows = frame_indices(traj.steps, max_frames)
    pos = traj.positions
    springs = traj.springs
    strain = traj.spring_lengths() / np.maximum(traj.rest_length, 1e-12) - 1.0
    ref = traj.reference_point()
    fixed = traj.fixed
    has_ground = traj.ground_c > 0 or traj.ground_clamp or traj.gravity[1] != 0

    lo, hi = pos.reshape(-1, 2).min(axis=0), pos.reshape(-1, 2).max(axis=0)
    pad = 0.08 * float(max(hi - lo).max() or 1.0)
    lo, hi = lo - pad, hi + pad
    if has_ground:
        lo[1] = min(lo[1], -pad)
    aspect = (hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-9)
    width = 6.0
    fig, ax = plt.subplots(figsize=(width + 1.2, float(np.clip(width * aspect, 2.5, 8.0)) + 0.6), dpi=dpi)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if has_ground:
        ax.axhspan(lo[1], 0.0, color="#d9c9a3", zorder=0)
        ax.axhline(0.0, color="#8c7a52", lw=1.0, zorder=0)
    cmap = plt.get_cmap("coolwarm")
    outline = LineCollection(pos[0][springs], colors="#505050", linewidths=2.8, zorder=1)
    ax.add_collection(outline)
    lines = LineCollection(pos[0][springs], cmap=cmap, linewidths=1.6, zorder=1)
    lines.set_clim(-STRAIN_LIMIT, STRAIN_LIMIT)
    lines.set_array(strain[0])
    ax.add_collection(lines)
    fig.colorbar(lines, ax=ax, shrink=0.7, label="strain (L − l)/l")
    ax.scatter(*pos[0][fixed].T, marker="s", s=30, c="#5f5f5f", edgecolors="black", zorder=3)
    movable_pts = ax.scatter(*pos[0][~fixed].T, marker="o", s=25, c="#1f77b4", edgecolors="black", zorder=3)
    trail_line = ax.plot([], [], color="#d62728", lw=1.2, alpha=0.8, zorder=2,
                         label="CMP trail" if traj.cmp_index >= 0 else "centre-of-masses trail")[0]
    ref_pt = ax.plot(*ref[0], marker="*", ms=12, color="#d62728", mec="black", ls="", zorder=4)[0]
    if trail:
        ax.legend(loc="upper right", fontsize=8, frameon=False)
    clock = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=9)
    ax.set_title(title or f"{traj.shape or 'body'}: {traj.n_masses} masses, {traj.n_springs} springs, "
                 f"{traj.integrator}", fontsize=10)
    fig.tight_layout()

    dynamic = [outline, lines, movable_pts, trail_line, ref_pt, clock]
    for artist in dynamic:
        artist.set_animated(True)
    canvas = fig.canvas
    canvas.draw()  # static parts once; each frame restores them and draws only the moving artists
    background = canvas.copy_from_bbox(fig.bbox)
    frames = []
    palette = None
    for t in rows:
        outline.set_segments(pos[t][springs])
        lines.set_segments(pos[t][springs])
        lines.set_array(strain[t])
        movable_pts.set_offsets(pos[t][~fixed])
        if trail:
            trail_line.set_data(ref[: t + 1, 0], ref[: t + 1, 1])
        ref_pt.set_data([ref[t, 0]], [ref[t, 1]])
        clock.set_text(f"t = {t * traj.dt:.2f} s  (step {t})")
        canvas.restore_region(background)
        for artist in dynamic:
            fig.draw_artist(artist)
        canvas.blit(fig.bbox)
        image = Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3].copy())
        # One palette for all frames (from the first): per-frame median cut would dominate the run time.
        palette = palette or image.quantize(colors=128, method=Image.Quantize.MEDIANCUT)
        frames.append(image.quantize(palette=palette, dither=Image.Dither.NONE))
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path) as f:
        frames[0].save(f, format="GIF", save_all=True, append_images=frames[1:], duration=int(round(1000 / fps)),
                       loop=0)
    return path
