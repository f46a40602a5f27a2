"""Draw three figures on planted data with whichever bptsb_ros is on PYTHONPATH: before or after the shared style.

The before/after pairs in docs/figures/before-after/ were made with this script, once with PYTHONPATH at a checkout
of the commit before the shared figure style (``15b3980~1``) and once at the current code:

    git worktree add ../before 15b3980~1
    PYTHONPATH=../before python scripts/figure_before_after.py before docs/figures/before-after
    PYTHONPATH=$PWD      python scripts/figure_before_after.py after  docs/figures/before-after

Both runs draw the same planted arrays (the same as tests/figure_cases.py: ``gaits``, ``spring_lengths``,
``loss``; copied here because tests/figure_cases.py imports modules the old code lacks). The old code drew
gaits.png inside the closed-loop locomotion experiment from gait.npz files, so ``before`` writes those files
into a temporary folder and calls that function. Each PNG is then stored with a 256-colour palette and, only
where that is still over 300 kB, downscaled (Pillow, Lanczos), so the pages stay light; the script prints each
figure's own size and DPI and what was stored.
"""

from __future__ import annotations

import inspect
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from bptsb_ros.analysis import plots as P
from bptsb_ros.body.shapes import build_shape

MAX_BYTES = 300_000
RNG_SEED = 3
DT = 0.01


def planted_gaits() -> tuple[dict, dict]:
    """20 agents on the 10-segment caterpillar, seed 13 failed (as tests/figure_cases.py ``gaits``)."""
    rng = np.random.default_rng(RNG_SEED)
    topo = build_shape("caterpillar", 10)
    rest, springs = np.asarray(topo.positions), np.asarray(topo.springs)
    steps = np.arange(0, 101)[:, None, None]
    gaits, results = {}, {}
    for seed in range(20):
        v = 0.5 + 0.5 * rng.random()
        wave = 0.3 * np.sin(0.2 * steps + rest[None, :, :1])
        r = rest[None] + np.concatenate([v * steps * 0.02 + wave, np.abs(wave)], axis=2)
        gaits[seed] = None if seed == 13 else {"r": r, "springs": springs, "dt": 0.02}
        results[seed] = {"open_speed": v, "ratio": 0.5 + rng.random(), "success": bool(seed % 3)}
    return gaits, results


def planted_spring_lengths() -> tuple[np.ndarray, np.ndarray]:
    """5 s of 48 springs [m] (as tests/figure_cases.py ``spring_lengths``)."""
    t = np.arange(0, 5, DT)
    e = np.arange(48)
    return t, 0.5 + 0.05 * e / 48 + 0.02 * np.sin(np.outer(t, 1 + e / 10))


def planted_loss() -> np.ndarray:
    """400 updates of a decaying loss (as tests/figure_cases.py ``loss``)."""
    return np.exp(-np.arange(400) / 80) + 0.05 * np.random.default_rng(RNG_SEED).random(400) + 0.01


def draw_gaits(path: Path, old: bool) -> Path:
    gaits, results = planted_gaits()
    if not old:
        from bptsb_ros.analysis import locomotion_plots as L

        return L.plot_gaits(path, gaits, results, 2.0)
    from bptsb_ros.experiments.locomotion_closed_loop import _plot_gaits

    with tempfile.TemporaryDirectory() as sweep:
        for seed, g in gaits.items():
            if g is not None:
                job = Path(sweep) / "jobs" / f"seed-{seed}"
                job.mkdir(parents=True)
                np.savez(job / "gait.npz", r=g["r"], springs=g["springs"])
        return _plot_gaits(path, Path(sweep), list(gaits),
                           {f"seed-{s}": r for s, r in results.items() if gaits[s] is not None}, 2.0)


def draw_loss(path: Path, old: bool) -> Path:
    if old:
        return P.plot_loss(path, planted_loss(), "lissajous")
    return P.plot_loss(path, planted_loss(), "trajectory MSE [m²]", "lissajous")


def to_palette(img: Image.Image) -> Image.Image:
    """``img`` with 256 colours chosen by median cut, not dithered (Pillow's dithering tints the white background);
    a smooth colour ramp such as a colorbar shows faint bands."""
    return img.convert("RGB").quantize(256, method=Image.Quantize.MEDIANCUT)


def shrink(path: Path) -> None:
    """Make the PNG at ``path`` smaller than ``MAX_BYTES``: first a 256-colour palette at full resolution, then,
    if still too big, downscale in 10 % steps (Lanczos)."""
    img = Image.open(path).convert("RGB")
    to_palette(img).save(path, optimize=True)
    scale = 1.0
    while path.stat().st_size > MAX_BYTES:
        scale *= 0.9
        to_palette(img.resize((round(img.width * scale), round(img.height * scale)), Image.LANCZOS)).save(
            path, optimize=True)


def main(which: str, out_dir: Path) -> None:
    if which not in ("before", "after"):
        raise SystemExit(f"first argument must be 'before' or 'after', got {which!r}")
    old = "loss_label" not in inspect.signature(P.plot_loss).parameters
    if old != (which == "before"):
        raise SystemExit(f"asked for {which!r} but PYTHONPATH's bptsb_ros ({P.__file__}) is the "
                         f"{'old' if old else 'current'} code")
    out_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        drawn = {"gaits": draw_gaits(Path(tmp) / "gaits.png", old),
                 "spring-lengths": P.plot_spring_lengths(Path(tmp) / "spring_lengths.png", *planted_spring_lengths()),
                 "loss": draw_loss(Path(tmp) / "loss.png", old)}
        for name, src in drawn.items():
            dst = out_dir / f"{name}-{which}.png"
            img = Image.open(src)
            dpi = img.info.get("dpi", (0, 0))[0]
            print(f"{dst}: {img.width}x{img.height} px at {dpi:.0f} dpi, {Path(src).stat().st_size // 1000} kB")
            img.save(dst)
            shrink(dst)
            small = Image.open(dst)
            print(f"  written as a 256-colour PNG, {small.width}x{small.height} px, {dst.stat().st_size // 1000} kB"
                  + (" (downscaled)" if small.width != img.width else ""))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: figure_before_after.py before|after OUT_DIR")
    main(sys.argv[1], Path(sys.argv[2]))
