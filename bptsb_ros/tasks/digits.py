"""Target trajectories of the CMP for the digits 0-9 (the MNIST drawing task).

The authors never published theirs; the paper only says the targets, "including stroke orders and times to
finish drawing, were set in advance" and that every drawing starts at the CMP's fixed position. Ours are
designed here and shipped as data (``digit_targets.json`` beside this module, written by
``python -m bptsb_ros.tasks.digits``; a test checks the file equals what this code makes).

Design (see docs/experiments/mnist.md, "Target digits"):

* **one pen stroke per digit**, in the order a person writes it; where a person lifts the pen (the bar of a
  4) the CMP cannot, so the stroke retraces the shortest way (4: down, across, up the right bar, down).
  Each digit is a polyline of key points with circular arcs, in a box of height ``height`` (default
  size/8 = 0.5 m, the published scaling) and width 0.6·height, y up.
* **start at the CMP**: each digit is translated so its first pen point is the origin, the CMP's rest
  position, so every target starts where the body starts.
* **timing**: the pen moves along the stroke with a minimum-jerk profile s(t) = L·(10τ³ − 15τ⁴ + 6τ⁵),
  τ = t/T: it starts and ends at rest, as a body released from rest must. T = max(T_min, L / v̄) with mean
  speed v̄ = 1 m/s and T_min = 0.6 s, rounded to whole steps of dt = 0.01 s, so longer digits take longer
  (a 1 takes 60 steps, an 8 about 180).

Each target is an array (T_j + 1, 2) [m]: row t is the CMP position at time t·dt; row 0 is (0, 0).
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from bptsb_ros.files.safe_write import write_atomic

DATA_FILE = Path(__file__).with_name("digit_targets.json")
#: digit height [m]: size/8 for the paper's size-4 bodies (the published scaling)
HEIGHT = 0.5
MEAN_SPEED = 1.0  # m/s
MIN_DURATION = 0.6  # s
DT = 0.01  # s


def _arc(cx: float, cy: float, r: float, a0: float, a1: float, n: int = 24) -> list[tuple[float, float]]:
    """Points on a circle (centre, radius) from angle a0 to a1 (degrees; counter-clockwise if a1 > a0)."""
    angles = np.radians(np.linspace(a0, a1, n))
    return [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in angles]


def _ellipse(cx: float, cy: float, rx: float, ry: float, a0: float, a1: float, n: int = 32):
    angles = np.radians(np.linspace(a0, a1, n))
    return [(cx + rx * math.cos(a), cy + ry * math.sin(a)) for a in angles]


def stroke_outlines() -> dict[int, list[tuple[float, float]]]:
    """Each digit as one pen stroke in a unit box: x in [0, 0.6], y in [0, 1], in writing order."""
    w = 0.6
    s: dict[int, list[tuple[float, float]]] = {}
    # 0: from the top, counter-clockwise round the oval, back to the top
    s[0] = _ellipse(w / 2, 0.5, w / 2, 0.5, 90, 450, 48)
    # 1: a short up-stroke to the top, then straight down
    s[1] = [(0.15, 0.8), (0.35, 1.0), (0.35, 0.0)]
    # 2: the hook over the top (clockwise), the diagonal down to bottom-left, the base to the right
    s[2] = _arc(w / 2, 0.72, 0.28, 160, -20, 20) + [(0.0, 0.0), (w, 0.0)]
    # 3: upper bowl (clockwise) to the middle, lower bowl (clockwise) to bottom-left
    s[3] = _arc(0.3, 0.76, 0.24, 150, -90, 20) + _arc(0.3, 0.26, 0.26, 90, -150, 22)
    # 4: down the left, across, up the right bar (pen-lift retraced), down the right bar
    s[4] = [(0.1, 1.0), (0.0, 0.35), (w, 0.35), (0.45, 0.35), (0.45, 1.0), (0.45, 0.0)]
    # 5: the top bar right-to-left, down to the middle, the belly (clockwise) to bottom-left
    s[5] = [(w, 1.0), (0.05, 1.0), (0.0, 0.55)] + _arc(0.3, 0.3, 0.3, 125, -150, 24)
    # 6: from top-right down the left side, round the bottom loop (counter-clockwise) and close it
    s[6] = _arc(0.45, 0.55, 0.45, 75, 180, 10) + _arc(0.3, 0.28, 0.28, 180, 540, 32)
    # 7: the top bar, then the long diagonal down
    s[7] = [(0.0, 1.0), (w, 1.0), (0.2, 0.0)]
    # 8: from the top, the upper loop counter-clockwise into an S down, the lower loop, back up
    s[8] = (_arc(0.3, 0.75, 0.25, 90, 270, 16) + _arc(0.3, 0.25, 0.25, 90, -270, 40)
            + _arc(0.3, 0.75, 0.25, 270, 450, 16))
    # 9: from the right of the head, round it counter-clockwise, then the stem straight down
    s[9] = _arc(0.3, 0.72, 0.28, 0, 360, 32) + [(0.58, 0.0)]
    return s


def _resample(points: np.ndarray, n_steps: int) -> np.ndarray:
    """Minimum-jerk walk along the polyline: (n_steps + 1, 2), starting and ending at rest."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    tau = np.linspace(0.0, 1.0, n_steps + 1)
    s = arc[-1] * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    return np.stack([np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])], axis=1)


def design_targets(height: float = HEIGHT, dt: float = DT, mean_speed: float = MEAN_SPEED,
                   min_duration: float = MIN_DURATION) -> list[np.ndarray]:
    """The ten targets (digit 0..9), each (T_j + 1, 2) [m] starting at the origin (see the module doc)."""
    out = []
    for digit, outline in sorted(stroke_outlines().items()):
        pts = np.asarray(outline, dtype=np.float64) * height
        pts = pts - pts[0]  # the pen starts at the CMP's rest position
        length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
        steps = int(round(max(min_duration, length / mean_speed) / dt))
        out.append(_resample(pts, steps))
        assert digit == len(out) - 1
    return out


def write_targets(path: Path = DATA_FILE) -> Path:
    """Write the designed targets to JSON (positions rounded to 1e-6 m)."""
    targets = design_targets()
    doc = {"description": "CMP target trajectories for the digits 0-9; made by bptsb_ros/tasks/digits.py",
           "dt": DT, "height_m": HEIGHT, "mean_speed_m_per_s": MEAN_SPEED, "min_duration_s": MIN_DURATION,
           "targets": {str(d): np.round(t, 6).tolist() for d, t in enumerate(targets)}}
    write_atomic(path, json.dumps(doc, separators=(",", ":")) + "\n")
    return path


@lru_cache(maxsize=1)
def _load() -> tuple[float, tuple[np.ndarray, ...]]:
    doc = json.loads(DATA_FILE.read_text())
    return float(doc["dt"]), tuple(np.asarray(doc["targets"][str(d)], dtype=np.float64) for d in range(10))


def load_targets(dt: float = DT) -> list[np.ndarray]:
    """The shipped targets, each (T_j + 1, 2) [m]; ``dt`` must be the file's step (0.01 s)."""
    file_dt, targets = _load()
    if abs(dt - file_dt) > 1e-12:
        raise ValueError(f"the digit targets are sampled every {file_dt} s; the body steps every {dt} s")
    return [t.copy() for t in targets]


def padded_targets(targets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Stack targets to (10, T_max + 1, 2), padded by holding the last point, and lengths (10,) = T_j."""
    t_max = max(len(t) for t in targets) - 1
    out = np.zeros((len(targets), t_max + 1, 2))
    for i, t in enumerate(targets):
        out[i, : len(t)] = t
        out[i, len(t):] = t[-1]
    return out, np.asarray([len(t) - 1 for t in targets], dtype=np.int64)


if __name__ == "__main__":
    print(write_targets())
