"""The one figure style of bptsb_ros: sizes, fonts, colour-blind-safe colours, resolution, file formats.

Every plotting function of the package runs under :func:`styled` (an ``rc_context`` of :data:`RC`: the
user's own matplotlib settings are untouched outside it) and writes its figure with :func:`save`: a PNG at
:data:`DPI` (for pages and the report) and a PDF beside it (vector, fonts embedded as TrueType, for a
paper). Widths follow a two-column paper: :data:`SINGLE` (one column) and :data:`DOUBLE` (the full text
width), in inches; fonts are 8 pt at that size, so a figure placed at its own width reads like the text.

Colours: :data:`PALETTE` is the Okabe-Ito set (distinguishable with any colour-vision deficiency), the
default colour cycle; :data:`DIGIT_COLOURS` are Paul Tol's ten "muted" colours, one per MNIST label;
sequential quantities (time, a size) use ``viridis``, many similar lines a colormap (:func:`colours`).

Units: every axis label names its unit in brackets, ``[-]`` for a dimensionless quantity; a loss names the
loss and its unit (``"MSE [m²]"``).
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec, TypeVar

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import cycler  # noqa: E402

from bptsb_ros.files.safe_write import atomic_writer  # noqa: E402

#: PNG resolution [dots per inch]
DPI = 200
#: pyplot keeps global state and is not thread-safe: threads that make figures (the trainings of a gang,
#: ``bptsb_ros/jobs/gang.py``) make them one at a time, under this lock
FIGURES = threading.RLock()
#: figure widths [in]: one column and the full text width of a two-column paper
SINGLE = 3.4
DOUBLE = 7.0
#: base font size [pt]
FONT_SIZE = 8.0
#: the formats :func:`save` writes, the first one being the path it returns
FORMATS = ("png", "pdf")
#: environment variable choosing other formats: "png" first, then any of pdf, svg (e.g. "png,svg"; "png" alone
#: skips the vector copy, which takes about half of a figure's time)
FORMATS_ENV = "BPTSB_FIGURE_FORMATS"
_KNOWN = ("png", "pdf", "svg")

#: Okabe-Ito colours (Okabe & Ito 2008), without black (kept for targets): blue, vermillion, bluish green,
#: orange, reddish purple, sky blue, yellow
BLUE, VERMILLION, GREEN, ORANGE, PURPLE, SKY, YELLOW = (
    "#0072B2", "#D55E00", "#009E73", "#E69F00", "#CC79A7", "#56B4E9", "#F0E442")
PALETTE = (BLUE, VERMILLION, GREEN, ORANGE, PURPLE, SKY, YELLOW)
#: one colour per digit 0-9 (Paul Tol's "muted" scheme with its pale grey)
DIGIT_COLOURS = ("#332288", "#88CCEE", "#44AA99", "#117733", "#999933", "#DDCC77", "#CC6677", "#882255",
                 "#AA4499", "#DDDDDD")
#: the target curve / reference line in every figure
TARGET = "black"
#: colormap of time and of other ordered quantities
SEQUENTIAL = "viridis"

RC: dict[str, object] = {
    "figure.dpi": 100,
    "savefig.dpi": DPI,
    "savefig.bbox": "tight",
    "savefig.pad_inches": 0.03,
    "font.family": "sans-serif",
    "font.sans-serif": ["DejaVu Sans"],
    "mathtext.fontset": "dejavusans",
    "font.size": FONT_SIZE,
    "axes.titlesize": FONT_SIZE,
    "axes.labelsize": FONT_SIZE,
    "xtick.labelsize": FONT_SIZE - 1,
    "ytick.labelsize": FONT_SIZE - 1,
    "legend.fontsize": FONT_SIZE - 1,
    "legend.title_fontsize": FONT_SIZE - 1,
    "legend.framealpha": 0.85,
    "legend.edgecolor": "0.8",
    "figure.titlesize": FONT_SIZE + 1,
    "figure.labelsize": FONT_SIZE,
    "axes.prop_cycle": cycler(color=PALETTE),
    "axes.grid": False,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "lines.markersize": 3.5,
    "xtick.major.width": 0.6,
    "ytick.major.width": 0.6,
    "image.cmap": SEQUENTIAL,
    "pdf.fonttype": 42,  # TrueType in the PDF: text stays text (journals refuse Type 3 fonts)
    "svg.fonttype": "none",
}

P = ParamSpec("P")
R = TypeVar("R")


def styled(fn: Callable[P, R]) -> Callable[P, R]:
    """Run the plotting function ``fn`` under :data:`RC` (the caller's rcParams are restored after it)."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        with plt.rc_context(RC):
            return fn(*args, **kwargs)

    return wrapper


def size(width: float = DOUBLE, aspect: float = 0.45) -> tuple[float, float]:
    """(width, height) [in] of a figure ``width`` inches wide and ``aspect`` × as high."""
    return width, width * aspect


def colours(n: int, cmap: str = SEQUENTIAL) -> list[tuple[float, float, float, float]]:
    """``n`` distinguishable colours for many similar lines: the :data:`PALETTE` where it suffices, else
    evenly spaced samples of the colormap ``cmap`` (its light end left out, for a white background)."""
    if n <= len(PALETTE):
        return [matplotlib.colors.to_rgba(c) for c in PALETTE[:n]]
    return [tuple(c) for c in plt.get_cmap(cmap)(np.linspace(0.0, 0.9, n))]


def formats() -> tuple[str, ...]:
    """The formats :func:`save` writes: :data:`FORMATS`, or those listed in :data:`FORMATS_ENV`."""
    raw = os.environ.get(FORMATS_ENV, "").strip()
    if not raw:
        return FORMATS
    chosen = tuple(f.strip().lower().lstrip(".") for f in raw.split(","))
    if chosen[0] != "png" or any(f not in _KNOWN for f in chosen) or len(set(chosen)) != len(chosen):
        raise ValueError(f"{FORMATS_ENV} must list png first, then any of pdf, svg once each, got {raw!r}")
    return chosen


def siblings(path: str | Path) -> list[Path]:
    """Every file :func:`save` writes for ``path``: one per :func:`formats`, the first one ``path`` itself."""
    path = Path(path)
    return [path] + [path.with_suffix(f".{ext}") for ext in formats()[1:]]


def save(fig, path: str | Path) -> Path:
    """Write ``fig`` as ``path`` (PNG, :data:`DPI`) and a PDF beside it (the :func:`formats`); close it; return
    ``path``.

    A figure made without a layout engine is laid out with ``tight_layout`` first (one made with
    ``layout="constrained"``, e.g. for a colorbar beside several axes, keeps its own). The PDF carries no
    creation date, so a rerun writes the same bytes.
    """
    from bptsb_ros import __version__

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"figure path must end in .png (the PDF is written beside it), got {path}")
    files = siblings(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with plt.rc_context(RC):
        if fig.get_layout_engine() is None:
            fig.tight_layout()
        software = f"bptsb_ros {__version__}"
        for out in files:
            meta = {".png": {"Software": software}, ".pdf": {"Creator": software, "CreationDate": None},
                    ".svg": {"Creator": software, "Date": None}}[out.suffix]
            with atomic_writer(out) as f:  # a regular file only, never through a planted link
                fig.savefig(f, format=out.suffix[1:], dpi=DPI, metadata=meta)
    plt.close(fig)
    return path


def legend_outside(ax, where: str = "right", **kwargs):
    """A legend beside ``ax`` (``where`` "right"), below it, under its tick labels and axis label ("below"), or
    above it ("above", over the title's place): never over the data."""
    if where == "right":
        kw = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "borderaxespad": 0.0}
    elif where == "below":  # the gap in font sizes: tick labels and a one-line axis label fit above it
        kw = {"loc": "upper center", "bbox_to_anchor": (0.5, 0.0), "ncol": 2, "borderaxespad": 4.6}
    elif where == "above":
        kw = {"loc": "lower center", "bbox_to_anchor": (0.5, 1.02), "ncol": 3, "borderaxespad": 0.0}
    else:
        raise ValueError(f"legend place must be right, below or above, got {where!r}")
    kw["frameon"] = False
    kw.update(kwargs)
    return ax.legend(**kw)
