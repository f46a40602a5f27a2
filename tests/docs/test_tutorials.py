"""The tutorial notebooks of the docs (docs/tutorials/*.ipynb) run as they are, at a small scale: their first code
cell holds their one parameter (a size, which the test makes small, or a path, which it makes absolute). They are
stored with the outputs of a full run, which the site shows (mkdocs-jupyter, not executed at build time)."""

from __future__ import annotations

import json
import os
import re

import pytest
from conftest import REPO_ROOT as REPO

TUTORIALS = REPO / "docs" / "tutorials"
#: notebook → (its parameter, the value the test runs it with)
SMALL = {"train_lissajous.ipynb": ("SIM_TIME", 100), "live_loop_bag_analysis.ipynb": ("DURATION", 40),
         "paper_result_figure.ipynb": ("RESULT", str(REPO / "reproduction" / "runs" / "lissajous-perturbation-paper"
                                                      / "seed-0" / "result.json"))}
#: the tutorial that runs a live loop (ROS 2 nodes on the session's domain)
LIVE = "live_loop_bag_analysis.ipynb"
#: the marks of a tutorial's run: the live loop needs ROS 2; it and the training take 10 s or more
RUN_MARKS = {LIVE: [pytest.mark.ros, pytest.mark.slow], "train_lissajous.ipynb": [pytest.mark.slow]}


def test_every_tutorial_is_run_here_and_is_in_the_site_navigation():
    import yaml

    assert sorted(p.name for p in TUTORIALS.glob("*.ipynb")) == sorted(SMALL)
    nav = json.dumps(yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"])
    for name in SMALL:
        assert f"tutorials/{name}" in nav


@pytest.mark.parametrize("name", sorted(SMALL))
def test_a_stored_tutorial_shows_the_outputs_of_a_full_run(name):
    nb = json.loads((TUTORIALS / name).read_text())
    cells = [c for c in nb["cells"] if c["cell_type"] == "code"]
    parameter, _ = SMALL[name]
    assert re.match(rf"{parameter} = \S", "".join(cells[0]["source"]))
    assert all(c.get("execution_count") for c in cells), "a code cell was not run"
    assert not [o for c in cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert any(o.get("data", {}).get("image/png") for c in cells for o in c.get("outputs", []))


@pytest.mark.parametrize("name", [pytest.param(n, marks=RUN_MARKS.get(n, ())) for n in sorted(SMALL)])
def test_a_tutorial_runs(name, tmp_path):
    nbformat = pytest.importorskip("nbformat", reason="the docs tools (pip install -e '.[dev]') are not installed")
    nbclient = pytest.importorskip("nbclient", reason="the docs tools (pip install -e '.[dev]') are not installed")
    if name == LIVE:
        pytest.importorskip("rclpy", reason="the live loop needs the ROS 2 wheels (the ros extra)")
    nb = nbformat.read(TUTORIALS / name, as_version=4)
    parameter, small = SMALL[name]
    first = next(c for c in nb.cells if c.cell_type == "code")
    first.source = re.sub(rf"^{parameter} = [^#\n]*", f"{parameter} = {small!r}  ", first.source)
    assert f"{parameter} = {small!r}" in first.source
    os.environ.setdefault("MPLBACKEND", "Agg")
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert errors == []


@pytest.mark.parametrize("name", sorted(SMALL))
def test_a_tutorial_links_no_page_by_a_relative_path(name):
    """The site renders a notebook as it is (no link rewriting): a relative link to a .md page would be dead in
    the site, so the tutorials name pages in words."""
    nb = json.loads((TUTORIALS / name).read_text())
    text = "".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "markdown")
    assert not re.findall(r"\]\((?![a-z]+:)[^)]*\)", text)
