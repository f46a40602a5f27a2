"""Every figure of the package in the one style: PNG + PDF, the style's resolution and fonts, a unit on every
axis, legends off the data and off the text, fonts large enough to read.

Each plot function is called on small planted data (tests/figure_cases.py); the figure it builds is caught at
``plt.close`` (which :func:`bptsb_ros.analysis.style.save` calls after writing) and inspected. The checks are
checked themselves on figures made wrong on purpose (``test_checks_catch_*``).
"""

from __future__ import annotations

import re
from pathlib import Path

import figure_cases
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import LineCollection, PathCollection
from matplotlib.container import BarContainer
from matplotlib.image import AxesImage
from PIL import Image

from bptsb_ros.analysis import style

UNIT = re.compile(r"\[[^\]]+\]|\(dimensionless\)")
MIN_FONT_PT = 5.0


# ---------------------------------------------------------------------------------------------- the checks


def _is_colorbar(ax) -> bool:
    return ax.get_label() == "<colorbar>"


def _number(text: str) -> bool:
    if text.startswith("$"):  # mathtext: a log axis's 10^k
        return True
    try:
        float(text.replace("\u2212", "-"))
    except ValueError:
        return False
    return True


def _categorical(axis) -> bool:
    """Ticks named by words (``set_xticks(x, names)``, bars over names): the axis lists categories, it has no
    unit to give."""
    texts = [t.get_text() for t in axis.get_ticklabels() if t.get_text().strip()]
    return bool(texts) and not all(_number(t) for t in texts)


def _label(ax, which: str) -> str:
    """The axis label shown for ``ax``: its own or, in a shared grid, that of an axes it shares the axis with."""
    own = ax.get_xlabel() if which == "x" else ax.get_ylabel()
    if own:
        return own
    group = ax.get_shared_x_axes() if which == "x" else ax.get_shared_y_axes()
    for other in group.get_siblings(ax):
        text = other.get_xlabel() if which == "x" else other.get_ylabel()
        if text:
            return text
    return ""


def label_problems(fig) -> list[str]:
    """Axes whose x or y label is missing or names no unit (categorical axes need a name only); call it on a
    drawn figure (tick labels exist once drawn)."""
    problems = []
    for i, ax in enumerate(fig.axes):
        if not ax.axison or not ax.get_visible():
            continue
        if _is_colorbar(ax):
            text = ax.get_ylabel() or ax.get_xlabel()
            if not UNIT.search(text):
                problems.append(f"colorbar {i}: label {text!r} names no unit")
            continue
        for which, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            text = _label(ax, which)
            if not text.strip():
                problems.append(f"axes {i} ({ax.get_title()!r}): no {which} label")
            elif not _categorical(axis) and not UNIT.search(text):
                problems.append(f"axes {i} ({ax.get_title()!r}): {which} label {text!r} names no unit")
    return problems


def _data_points(ax) -> np.ndarray:
    """(P, 2) display coordinates of the data drawn in ``ax`` (lines densely sampled, segments, scatter points,
    bar corners, image corners), only those inside the axes (what is clipped away covers nothing)."""
    pts = []
    for line in ax.lines:
        xy = np.asarray(line.get_xydata(), dtype=float)
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy) == 0:
            continue
        if len(xy) > 1:  # 8 points per segment: a line crossing a legend between two vertices still counts
            f = np.linspace(0, 1, 8, endpoint=False)[None, :, None]
            xy = np.concatenate([(xy[:-1, None] + f * (xy[1:, None] - xy[:-1, None])).reshape(-1, 2), xy[-1:]])
        pts.append(line.get_transform().transform(xy))
    for coll in ax.collections:
        if isinstance(coll, LineCollection):
            segs = [np.asarray(s) for s in coll.get_segments() if len(s)]
            if segs:
                pts.append(coll.get_transform().transform(np.concatenate(segs)))
        elif isinstance(coll, PathCollection) and len(coll.get_offsets()):
            pts.append(coll.get_offset_transform().transform(np.asarray(coll.get_offsets(), dtype=float)))
    for cont in ax.containers:
        if isinstance(cont, BarContainer):
            for patch in cont.patches:
                b = patch.get_window_extent()
                if b.width > 0 and b.height > 0:
                    pts.append(np.array([[b.x0, b.y0], [b.x1, b.y1], [b.x0, b.y1], [b.x1, b.y0],
                                         [(b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2]]))
    for im in ax.images:
        if isinstance(im, AxesImage):
            b = im.get_window_extent()
            pts.append(np.array([[b.x0, b.y0], [b.x1, b.y1], [(b.x0 + b.x1) / 2, (b.y0 + b.y1) / 2]]))
    if not pts:
        return np.zeros((0, 2))
    pts = np.concatenate(pts)
    box = ax.get_window_extent()
    inside = (pts[:, 0] >= box.x0) & (pts[:, 0] <= box.x1) & (pts[:, 1] >= box.y0) & (pts[:, 1] <= box.y1)
    return pts[inside]


def _texts(fig) -> list:
    """Every text ``fig`` draws, legends' own texts aside: titles, axis labels, tick labels within the view,
    annotations, figure titles and labels."""
    out = list(fig.texts) + [t for t in (fig._suptitle, fig._supxlabel, fig._supylabel) if t is not None]
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        out += [ax.title, ax._left_title, ax._right_title, *ax.texts]
        if not ax.axison:
            continue
        for axis in (ax.xaxis, ax.yaxis):
            out.append(axis.label)
            lo, hi = sorted(axis.get_view_interval())
            eps = 1e-9 * max(abs(lo), abs(hi), 1.0)
            for tick in axis.get_major_ticks():
                if lo - eps <= tick.get_loc() <= hi + eps:
                    out += [lab for lab in (tick.label1, tick.label2) if lab.get_visible()]
    return [t for t in out if t.get_visible() and t.get_text().strip()]


def _legends(fig) -> list:
    return [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)


def legend_problems(fig) -> list[str]:
    """Legends that cover data of any axes or any text (titles, labels, tick labels) of the drawn figure."""
    renderer = fig.canvas.get_renderer()
    problems = []
    for lg in _legends(fig):
        if not lg.get_visible():
            continue
        box = lg.get_window_extent(renderer).shrunk(0.98, 0.98)  # a 1 % margin: touching is not covering
        for i, ax in enumerate(fig.axes):
            pts = _data_points(ax)
            hit = (pts[:, 0] > box.x0) & (pts[:, 0] < box.x1) & (pts[:, 1] > box.y0) & (pts[:, 1] < box.y1)
            if hit.any():
                problems.append(f"legend {[t.get_text() for t in lg.get_texts()][:2]} covers {int(hit.sum())} "
                                f"data points of axes {i} ({ax.get_title()!r})")
        for t in _texts(fig):
            tb = t.get_window_extent(renderer)
            if tb.width and tb.overlaps(box):
                problems.append(f"legend {[x.get_text() for x in lg.get_texts()][:2]} covers text {t.get_text()!r}")
    return problems


def font_problems(fig) -> list[str]:
    """Texts smaller than :data:`MIN_FONT_PT` (unreadable in print at the figure's own size)."""
    return [f"text {t.get_text()!r} at {t.get_fontsize():.1f} pt" for t in fig.findobj(matplotlib.text.Text)
            if t.get_visible() and t.get_text().strip() and t.get_fontsize() < MIN_FONT_PT]


def file_problems(png: Path) -> list[str]:
    """The PNG at the style's DPI (its pHYs chunk) and a PDF beside it with TrueType (not Type 3) fonts."""
    problems = []
    pdf = png.with_suffix(".pdf")
    if not png.is_file():
        return [f"{png.name} missing"]
    with Image.open(png) as im:
        dpi = im.info.get("dpi", (0, 0))
        width_in = im.size[0] / max(dpi[0], 1)
    if abs(dpi[0] - style.DPI) > 0.5:
        problems.append(f"{png.name}: {dpi[0]:.0f} dpi, not {style.DPI}")
    if width_in > style.DOUBLE * 1.35:  # the figure's own width plus outside legends and colorbars
        problems.append(f"{png.name}: {width_in:.1f} in wide, more than a page's width")
    if not pdf.is_file():
        problems.append(f"{pdf.name} missing beside {png.name}")
    else:
        data = pdf.read_bytes()
        if not data.startswith(b"%PDF") or b"/Type3" in data:
            problems.append(f"{pdf.name}: not a PDF with embedded TrueType fonts")
    return problems


@pytest.fixture
def caught(monkeypatch):
    """Figures passed to plt.close are kept open for inspection (closed at the end)."""
    figs = []
    real_close = plt.close

    def keep(fig=None):
        if isinstance(fig, matplotlib.figure.Figure):
            figs.append(fig)
        else:
            real_close(fig)

    monkeypatch.setattr(plt, "close", keep)
    yield figs
    for f in figs:
        real_close(f)


# ---------------------------------------------------------------------------------------------- every figure


@pytest.fixture(autouse=True)
def _small(monkeypatch):
    """Fewer panels, and the default formats (the test session asks for PNG only: tests/conftest.py)."""
    monkeypatch.setattr(figure_cases, "SMALL", True)
    monkeypatch.delenv(style.FORMATS_ENV, raising=False)


#: cases whose files are written for real and read back (rendering is most of a figure's cost: the others record
#: what they would write, see ``recorded``)
WRITTEN = ("gaits", "loss", "spring_lengths")


@pytest.fixture
def recorded(monkeypatch):
    """Figure.savefig records (path, dpi, pdf.fonttype in force) instead of rendering."""
    calls = []

    def record(self, fname, **kwargs):
        if hasattr(fname, "write"):  # the temporary file of safe_files.atomic_writer: .NAME.<random>.tmp
            tmp = Path(fname.name)
            fname = tmp.with_name(tmp.name[1:].rsplit(".", 2)[0])
        calls.append((Path(fname), kwargs.get("dpi"), matplotlib.rcParams["pdf.fonttype"]))

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", record)
    return calls


def _check_figure(name: str, fig, png: Path) -> list[str]:
    assert png.suffix == ".png", f"{name}: returns the PNG"
    assert fig.get_size_inches()[0] <= style.DOUBLE + 1e-9, f"{name}: wider than the text ({style.DOUBLE} in)"
    fig.canvas.draw()
    return label_problems(fig) + legend_problems(fig) + font_problems(fig)


@pytest.mark.parametrize("name", sorted(set(figure_cases.CASES) - set(WRITTEN)))
def test_figure(name, tmp_path, caught, recorded):
    before = dict(matplotlib.rcParams)
    png = figure_cases.CASES[name](tmp_path)
    assert len(caught) == 1, f"{name}: one figure made and closed"
    assert recorded == [(png, style.DPI, 42), (png.with_suffix(".pdf"), style.DPI, 42)], \
        f"{name}: PNG and PDF at {style.DPI} dpi with TrueType fonts"
    problems = _check_figure(name, caught[0], png)
    assert not problems, f"{name}:\n" + "\n".join(problems)
    after = dict(matplotlib.rcParams)
    assert {k: v for k, v in after.items() if before.get(k) != v and k != "backend"} == {}, \
        f"{name}: changed the caller's rcParams"


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "gaits" else n for n in WRITTEN])
def test_figure_files(name, tmp_path, caught):
    png = figure_cases.CASES[name](tmp_path)
    problems = file_problems(png) + _check_figure(name, caught[0], png)
    assert not problems, f"{name}:\n" + "\n".join(problems)


def test_every_plot_function_has_a_case():
    """A new plot function without planted data here fails: every public plot_* of the plotting modules."""
    from bptsb_ros.analysis import autonomy_plots, locomotion_plots, mnist_plots, plots, seed_plots, timeseries_plots

    names = {n for m in (autonomy_plots, locomotion_plots, mnist_plots, plots, seed_plots, timeseries_plots)
             for n in dir(m)
             if n.startswith("plot_") and getattr(m, n).__module__ == m.__name__}
    covered = {f"plot_{c}" for c in figure_cases.CASES}
    assert names <= covered, f"plot functions without a case in tests/figure_cases.py: {sorted(names - covered)}"


# ---------------------------------------------------------------------------------------------- particulars


def test_spring_plot_shows_every_spring_in_its_own_colour(tmp_path, caught):
    figure_cases.spring_lengths(tmp_path)
    ax = caught[0].axes[0]
    assert len(ax.lines) == 48 and "48 of 48" in ax.get_title()
    colours = {tuple(np.round(matplotlib.colors.to_rgba(line.get_color()), 3)) for line in ax.lines}
    assert len(colours) == 48


def test_spring_plot_names_the_chosen_springs(tmp_path, caught):
    from bptsb_ros.analysis.plots import plot_spring_lengths

    t = np.arange(10) * 0.1
    plot_spring_lengths(tmp_path / "s.png", t, np.ones((10, 30)) + t[:, None], springs=[3, 7])
    ax = caught[0].axes[0]
    assert len(ax.lines) == 2 and "2 of 30 springs (springs 3, 7)" in ax.get_title()
    assert ax.get_legend() is not None and [t.get_text() for t in ax.get_legend().get_texts()] == ["spring 3",
                                                                                                   "spring 7"]
    with pytest.raises(ValueError, match="0..29"):
        plot_spring_lengths(tmp_path / "s.png", t, np.ones((10, 30)), springs=[30])


def test_save_refuses_a_path_that_is_not_png(tmp_path):
    fig = plt.figure()
    with pytest.raises(ValueError, match=r"\.png"):
        style.save(fig, tmp_path / "x.pdf")
    plt.close(fig)


def test_the_formats_can_be_chosen_and_a_bad_choice_is_named(tmp_path, monkeypatch):
    monkeypatch.setenv(style.FORMATS_ENV, "png, svg")
    png = figure_cases.loss(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loss.png", "loss.svg"]
    assert b"<svg" in png.with_suffix(".svg").read_bytes()
    for bad in ("pdf", "png,jpg", "png,pdf,pdf"):
        monkeypatch.setenv(style.FORMATS_ENV, bad)
        with pytest.raises(ValueError, match=f"{style.FORMATS_ENV} must list png first.*{bad!r}"):
            style.formats()


def test_running_median_matches_a_loop():
    from bptsb_ros.analysis.plots import running_median

    y = np.random.default_rng(0).standard_normal(301)
    for w in (1, 5, 40):
        ref = [np.median(y[max(0, i - w + 1): i + 1]) for i in range(len(y))]
        assert np.allclose(running_median(y, w), ref)


def test_palette_is_distinct_and_digit_colours_are_ten():
    rgb = np.array([matplotlib.colors.to_rgb(c) for c in style.PALETTE])
    gaps = np.linalg.norm(rgb[:, None] - rgb[None], axis=2)[np.triu_indices(len(rgb), 1)]
    assert gaps.min() > 0.2
    assert len(set(style.DIGIT_COLOURS)) == 10


def test_every_task_names_its_loss_with_a_unit():
    from bptsb_ros.tasks.lissajous import LissajousTask
    from bptsb_ros.tasks.locomotion import LocomotionTask
    from bptsb_ros.tasks.narma import NarmaTask

    labels = {t.loss_label for t in (LissajousTask, LocomotionTask, NarmaTask)}
    assert labels == {"trajectory MSE [m²]", "speed MSE [m²/s²]", "output MSE [m²]"}


# ---------------------------------------------------------------------------------------------- the checks fail


def _bad_figure(tmp_path: Path, *, legend_inside: bool = False, unit: bool = True, pdf: bool = True,
                font: float = 8.0) -> tuple[Path, matplotlib.figure.Figure]:
    t = np.linspace(0, 10, 200)
    with plt.rc_context(style.RC):
        fig, ax = plt.subplots(figsize=(4, 3))
        ax.plot(t, np.sin(3 * t), label="a sine")
        ax.plot(t, np.cos(3 * t), label="a cosine")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position [m]" if unit else "position")
        ax.set_title("planted", fontsize=font)
        if legend_inside:
            ax.legend(loc="upper left")
        else:
            style.legend_outside(ax, "right")
        png = tmp_path / "bad.png"
        fig.savefig(png, dpi=style.DPI)
        if pdf:
            fig.savefig(png.with_suffix(".pdf"))
    fig.canvas.draw()
    return png, fig


def test_checks_pass_a_good_figure(tmp_path):
    png, fig = _bad_figure(tmp_path)
    assert file_problems(png) + label_problems(fig) + legend_problems(fig) + font_problems(fig) == []
    plt.close(fig)


def test_checks_catch_a_legend_over_the_data(tmp_path):
    png, fig = _bad_figure(tmp_path, legend_inside=True)
    assert any("covers" in p and "data points" in p for p in legend_problems(fig))
    plt.close(fig)


def test_checks_catch_a_legend_over_text(tmp_path):
    png, fig = _bad_figure(tmp_path)
    fig.axes[0].set_ylabel("a long label\nover two lines [m]")
    lg = fig.axes[0].legend(loc="center right", bbox_to_anchor=(0.0, 0.5))  # left of the axes: on the y label
    fig.canvas.draw()
    assert lg is not None and any("covers text" in p for p in legend_problems(fig))
    plt.close(fig)


def test_checks_catch_a_label_without_unit_a_missing_pdf_small_text_and_the_wrong_dpi(tmp_path):
    png, fig = _bad_figure(tmp_path, unit=False, pdf=False, font=4.0)
    assert label_problems(fig) == ["axes 0 ('planted'): y label 'position' names no unit"]
    assert font_problems(fig) == ["text 'planted' at 4.0 pt"]
    assert file_problems(png) == ["bad.pdf missing beside bad.png"]
    fig.savefig(png, dpi=90)
    assert file_problems(png)[0] == f"bad.png: 90 dpi, not {style.DPI}"
    plt.close(fig)
