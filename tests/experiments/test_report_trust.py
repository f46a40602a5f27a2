"""`bptsb report` against hostile or careless input: it never deletes or overwrites what it did not write,
never writes or copies outside where it should, renders data as text, refuses non-finite numbers, and shows
the third claim state (not testable) as its own."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bptsb_ros.analysis.markdown import md_text
from bptsb_ros.cli import main
from bptsb_ros.experiments import ResultError, read_result, run_experiment, validate_result
from bptsb_ros.experiments.registry import _REGISTRY, Context, experiment, experiments
from bptsb_ros.experiments.report import ReportError, build_report
from bptsb_ros.experiments.result import Claim, ExperimentResult, Row, write_result
from bptsb_ros.files.owned_folder import MANIFEST

FIG = b"\x89PNG planted figure bytes"


def _result(**over) -> dict:
    data = {"experiment": "toy-trust", "paper_ref": "Fig. 1", "scale": "smoke", "seed": 0, "wall_s": 1.0,
            "rows": [{"system": "s", "metric": "m", "unit": "1", "ours": 1.0, "paper": None}],
            "claims": [{"claim": "c", "holds": True, "evidence": "e"}], "figures": ["fig.png"]}
    data.update(over)
    return data


def _plant(run_dir: Path, data: dict, figures: dict[str, bytes] | None = None) -> Path:
    run_dir.mkdir(parents=True, exist_ok=True)
    for rel, content in ({"fig.png": FIG} if figures is None else figures).items():
        (run_dir / rel).parent.mkdir(parents=True, exist_ok=True)
        (run_dir / rel).write_bytes(content)
    (run_dir / "result.json").write_text(json.dumps(data))
    return run_dir


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative path → bytes), to compare folders byte for byte."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _report(runs: Path, out: Path, capsys) -> tuple[int, str]:
    capsys.readouterr()
    rc = main(["report", str(runs), "--out", str(out)])
    return rc, capsys.readouterr().err


# --- 1. the figures folder and the page belong to the report, nothing else does ------------------------

def test_a_foreign_figures_folder_is_refused_and_left_intact(tmp_path, capsys):
    runs = tmp_path / "runs"
    _plant(runs / "a", _result())
    mine = tmp_path / "docs" / "R_figures"
    (mine / "sub").mkdir(parents=True)
    (mine / "thesis.tex").write_bytes(b"\\section{my own work}")
    (mine / "sub" / "data.bin").write_bytes(bytes(range(256)))
    before = _tree(mine)
    rc, err = _report(runs, tmp_path / "docs" / "R.md", capsys)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "R_figures" in err and "not made by" in err
    assert _tree(mine) == before and not (tmp_path / "docs" / "R.md").exists()


def test_a_symlinked_figures_folder_is_refused(tmp_path, capsys):
    runs = tmp_path / "runs"
    _plant(runs / "a", _result())
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "R_figures").symlink_to(elsewhere)
    rc, err = _report(runs, tmp_path / "docs" / "R.md", capsys)
    assert rc == 1 and "symbolic link" in err and list(elsewhere.iterdir()) == []


def test_an_owned_folder_is_reused_and_a_hand_added_file_kept(tmp_path, capsys):
    runs, page = tmp_path / "runs", tmp_path / "docs" / "R.md"
    _plant(runs / "a", _result(figures=["fig.png", "old.png"]), {"fig.png": FIG, "old.png": b"old figure"})
    assert _report(runs, page, capsys)[0] == 0
    figs = page.parent / "R_figures"
    assert json.loads((figs / MANIFEST).read_text())["files"] == ["toy-trust-smoke-seed0/fig.png",
                                                                   "toy-trust-smoke-seed0/old.png"]
    (figs / "notes.md").write_bytes(b"my notes")
    (figs / "toy-trust-smoke-seed0" / "annotated.png").write_bytes(b"my annotated copy")
    # the rerun: the run now has a new figure and no longer the old one
    _plant(runs / "a", _result(figures=["fig.png", "new.png"]), {"fig.png": b"fig v2", "new.png": b"new"})
    (runs / "a" / "old.png").unlink()
    assert _report(runs, page, capsys)[0] == 0
    assert _tree(figs) == {MANIFEST: (figs / MANIFEST).read_bytes(), "notes.md": b"my notes",
                           "toy-trust-smoke-seed0/annotated.png": b"my annotated copy",
                           "toy-trust-smoke-seed0/fig.png": b"fig v2", "toy-trust-smoke-seed0/new.png": b"new"}
    links = re.findall(r"^!\[[^\]]*\]\(([^)]*)\)$", page.read_text(), re.M)
    assert sorted(links) == ["R_figures/toy-trust-smoke-seed0/fig.png", "R_figures/toy-trust-smoke-seed0/new.png"]


def test_a_hand_made_file_where_the_report_would_write_is_refused_by_name(tmp_path, capsys):
    runs, page = tmp_path / "runs", tmp_path / "docs" / "R.md"
    _plant(runs / "a", _result())
    assert _report(runs, page, capsys)[0] == 0
    figs = page.parent / "R_figures"
    (figs / "toy-trust-smoke-seed0" / "b.png").write_bytes(b"the user's b.png")
    _plant(runs / "a", _result(figures=["fig.png", "b.png"]), {"fig.png": FIG, "b.png": b"the run's b.png"})
    before, page_before = _tree(figs), page.read_bytes()
    rc, err = _report(runs, page, capsys)
    assert rc == 1 and "b.png" in err and "not written by bptsb report" in err
    assert _tree(figs) == before and page.read_bytes() == page_before


def test_a_tampered_manifest_cannot_point_outside(tmp_path, capsys):
    runs, page = tmp_path / "runs", tmp_path / "docs" / "R.md"
    _plant(runs / "a", _result())
    assert _report(runs, page, capsys)[0] == 0
    victim = tmp_path / "victim.txt"
    victim.write_bytes(b"keep me")
    manifest = page.parent / "R_figures" / MANIFEST
    manifest.write_text(json.dumps({"written_by": "bptsb report", "files": ["../../victim.txt"], "dirs": []}))
    rc, err = _report(runs, page, capsys)
    assert rc == 1 and "victim.txt" in err and victim.read_bytes() == b"keep me"


def test_a_page_not_written_by_the_report_is_not_overwritten(tmp_path, capsys):
    runs = tmp_path / "runs"
    _plant(runs / "a", _result())
    notes = tmp_path / "docs" / "R.md"
    notes.parent.mkdir()
    notes.write_bytes(b"# My reproduction notes\n\nhand-written\n")
    rc, err = _report(runs, notes, capsys)
    assert rc == 1 and len(err.strip().splitlines()) == 1 and "not written by bptsb report" in err
    assert notes.read_bytes() == b"# My reproduction notes\n\nhand-written\n"
    assert not (notes.parent / "R_figures").exists()
    # its own page (the marker line), and a page from before the marker (title + "Made by" line), are replaced
    own = tmp_path / "own.md"
    assert _report(runs, own, capsys)[0] == 0 and _report(runs, own, capsys)[0] == 0
    legacy = tmp_path / "legacy.md"
    legacy.write_text("# Reproduction of the paper's experiments\n\nMade by `bptsb report` from the `result.json` "
                      "of each `bptsb reproduce` run.\n")
    assert _report(runs, legacy, capsys)[0] == 0 and "toy-trust" in legacy.read_text()
    link = tmp_path / "link.md"
    link.symlink_to(own)
    assert _report(runs, link, capsys)[0] == 1


# --- 2. names from files are data: no path traversal, no symlinked figure ---------------------------------

@pytest.mark.parametrize("name", ["a", "9", "lissajous-closed-loop", "x_1", "a" * 100, *experiments()])
def test_experiment_slugs_accepted(name):
    validate_result(_result(experiment=name))


@pytest.mark.parametrize("name", ["../../../escaped", "a/b", "", "-a", "_a", "A", "aB", "a b", "a.b", "a\n",
                                  "a" * 101, "é"])
def test_experiment_names_just_outside_the_slug_refused(name):
    with pytest.raises(ResultError, match="experiment must be a name"):
        validate_result(_result(experiment=name))


def test_an_experiment_is_registered_only_under_a_slug():
    with pytest.raises(ValueError, match="not a slug"):
        experiment("../escaped", paper_ref="-", summary="-")
    assert "../escaped" not in _REGISTRY


def test_a_traversing_experiment_name_writes_nothing_outside(tmp_path, capsys):
    page = tmp_path / "a" / "b" / "c" / "R.md"
    _plant(tmp_path / "runs" / "x", _result(experiment="../../../escaped"))
    rc, err = _report(tmp_path / "runs", page, capsys)
    assert rc == 1 and "experiment must be a name" in err
    assert list(tmp_path.rglob("escaped*")) == [] and not page.exists()


def test_a_symlinked_figure_is_not_copied(tmp_path, capsys):
    secret = tmp_path / "secret.txt"
    secret.write_bytes(b"SECRET-TOKEN")
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "x.png").write_bytes(b"SECRET-DIR")
    run = _plant(tmp_path / "runs" / "a", _result(figures=["fig.png", "leak.png", "sub/x.png"]))
    (run / "leak.png").symlink_to(secret)
    (run / "sub").symlink_to(tmp_path / "outside", target_is_directory=True)
    page = tmp_path / "docs" / "R.md"
    rc, err = _report(tmp_path / "runs", page, capsys)
    assert rc == 0 and "leak.png is a symbolic link" in err and "sub is a symbolic link" in err
    copied = _tree(page.parent)
    assert not any(b"SECRET" in content for content in copied.values())
    assert copied["R_figures/toy-trust-smoke-seed0/fig.png"] == FIG
    assert "leak.png: not shown" in page.read_text()


# --- 3. data renders as text; numbers are finite ----------------------------------------------------------

HOSTILE = ["<script>alert(1)</script>", "[click](javascript:alert(1))", "![x](http://evil.example/t.png)",
           "a | b\n# injected heading", "<img src=x onerror=alert(1)>", "*bold* _it_ `code` ~~s~~ $x$ \\",
           "- item", "1. item", "&lt;script&gt;", "N_mov 17 (x < y) & E/E_orig"]


def _unescape(markdown: str) -> str:
    """What CommonMark shows for a line of text: backslash escapes and entities resolved (independent)."""
    return re.sub(r"\\([!-/:-@\[-`{-~])|&(amp|lt|gt);",
                  lambda m: m.group(1) or {"amp": "&", "lt": "<", "gt": ">"}[m.group(2)], markdown)


@pytest.mark.parametrize("text", HOSTILE)
def test_md_text_renders_as_the_same_text(text):
    out = md_text(text)
    assert "\n" not in out and "<" not in out and "](" not in out and "![" not in out
    assert not re.search(r"(?<!\\)[|`*\[\]#~$]", out)  # every structural character escaped
    assert _unescape(out) == text.replace("\n", " ")


def test_the_page_carries_no_markup_from_the_data(tmp_path):
    bad = " ".join(HOSTILE)
    data = _result(paper_ref=bad, rows=[{"system": bad, "metric": bad, "unit": bad, "ours": 1.0, "paper": bad}],
                   claims=[{"claim": bad, "holds": True, "evidence": bad}],
                   provenance={"command": bad, "machine": bad, "git_commit": bad, bad: bad})
    _plant(tmp_path / "runs" / "a", data)
    text = build_report(tmp_path / "runs", tmp_path / "docs" / "R.md").read_text()
    assert "<script" not in text and "<img" not in text and "](javascript:" not in text
    assert not re.search(r"!\[[^\]]*\]\(http", text) and "\n# injected" not in text
    table = [line for line in text.splitlines() if line.startswith("| ") and "evil" in line]
    assert sorted(len(re.findall(r"(?<!\\)\|", line)) for line in table) == [6, 10]  # the row, the summary


@pytest.mark.parametrize("mutate", [
    lambda d: d["rows"][0].update(ours=float("nan")),
    lambda d: d["rows"][0].update(ours=float("inf")),
    lambda d: d["rows"][0].update(ours=-float("inf")),
    lambda d: d["rows"][0].update(ours=10 ** 400),
    lambda d: d["rows"][0].update(paper=float("nan")),
    lambda d: d.update(wall_s=float("inf")),
    lambda d: d.update(wall_s=float("nan")),
    lambda d: d.update(wall_s=-1e-9),
    lambda d: d.update(provenance=["not", "an", "object"]),
])
def test_non_finite_numbers_and_non_objects_refused(mutate):
    data = _result()
    mutate(data)
    with pytest.raises(ResultError):
        validate_result(data)


@pytest.mark.parametrize("mutate", [
    lambda d: d["rows"][0].update(ours=1.7976931348623157e308),
    lambda d: d["rows"][0].update(ours=-5e-324, paper=2),
    lambda d: d["rows"][0].update(ours=None, paper="≈ 0.5"),
    lambda d: d.update(wall_s=0),
])
def test_finite_numbers_accepted(mutate):
    data = _result()
    mutate(data)
    validate_result(data)


@pytest.mark.parametrize("literal, ok", [("NaN", False), ("Infinity", False), ("-Infinity", False),
                                         ("1e999", False), ("1e308", True)])
def test_read_result_refuses_nan_and_infinity_in_the_file(tmp_path, literal, ok):
    path = tmp_path / "result.json"
    path.write_text(json.dumps(_result()).replace('"wall_s": 1.0', f'"wall_s": {literal}'))
    if ok:
        assert read_result(path)["wall_s"] == float(literal)
    else:
        with pytest.raises(ResultError, match=re.escape(str(path))):
            read_result(path)


def test_report_of_a_nan_wall_time_is_refused(tmp_path, capsys):
    run = _plant(tmp_path / "runs" / "a", _result())
    (run / "result.json").write_text((run / "result.json").read_text().replace('"wall_s": 1.0', '"wall_s": NaN'))
    rc, err = _report(tmp_path / "runs", tmp_path / "R.md", capsys)
    assert rc == 1 and "result.json" in err and not (tmp_path / "R.md").exists()


# --- 4. the third claim state: not testable ------------------------------------------------------------

def test_claim_states():
    assert Claim("c", np.bool_(True), "e").holds is True and Claim("c", False, "e").holds is False
    nt = Claim.not_testable("the LIL beats the MLP", "the MLP training diverged at update 11")
    assert nt.holds is None and nt.evidence == "the MLP training diverged at update 11"
    for bad in ("yes", 1, 0.0, "null"):
        with pytest.raises(ResultError, match="computed bool"):
            Claim("c", bad, "e")  # type: ignore[arg-type]
    for empty in ("", "   "):
        with pytest.raises(ResultError, match="failed premise"):
            Claim.not_testable("c", empty)


@pytest.mark.parametrize("holds, evidence, ok", [(True, "", True), (False, "e", True), (None, "premise failed", True),
                                                 (None, "", False), (None, " ", False), (1, "e", False),
                                                 ("true", "e", False), ("missing", "e", False)])
def test_schema_holds_true_false_or_null_with_a_premise(holds, evidence, ok):
    claim = {"claim": "c", "evidence": evidence} | ({} if holds == "missing" else {"holds": holds})
    data = _result(claims=[claim])
    if ok:
        validate_result(data)
    else:
        with pytest.raises(ResultError, match=r"claims\[0\]"):
            validate_result(data)


def test_not_testable_round_trips_and_is_shown_and_counted_apart(tmp_path):
    res = ExperimentResult("toy-trust", "Fig. 1", "smoke", 0, 1.0, [Row("s", "m", "1", 1.0)],
                           [Claim("A holds", True, "a"), Claim("B holds", False, "b"),
                            Claim.not_testable("C holds", "the baseline diverged")], [])
    run = tmp_path / "runs" / "a"
    run.mkdir(parents=True)
    assert [c["holds"] for c in read_result(write_result(run, res))["claims"]] == [True, False, None]
    text = build_report(tmp_path / "runs", tmp_path / "R.md").read_text()
    assert "| smoke | 1 (0) | 1 | 1 | 0 | 1 |" in text  # ✓ 1, ✗ 1, split 0, not testable 1
    assert "- ∅ not testable: C holds — the baseline diverged" in text
    assert "- ✓ A holds — a" in text and "- ✗ B holds — b" in text


def _premise_failed(ctx: Context) -> None:
    ctx.row("toy", "value", "m", 1.0)
    ctx.claim("computed", True, "ours = 1")
    assert ctx.claim("passed as None", None, "the training diverged") is None
    ctx.not_testable("by the helper", "no periodic orbit to compare with")


def test_reproduce_prints_the_not_testable_state(tmp_path, capsys):
    experiment("toy-premise", paper_ref="Table 0", summary="planted")(_premise_failed)
    try:
        assert main(["reproduce", "toy-premise", "--out", str(tmp_path / "r"), "--no-progress"]) == 0
        out = capsys.readouterr().out
        assert "✓ computed (ours = 1)" in out
        assert "∅ not testable passed as None (the training diverged)" in out
        assert "∅ not testable by the helper (no periodic orbit to compare with)" in out
        _, data = run_experiment("toy-premise", out_dir=tmp_path / "r2", progress=False)
        assert [c["holds"] for c in data["claims"]] == [True, None, None]
    finally:
        _REGISTRY.pop("toy-premise", None)


def test_report_error_for_the_api(tmp_path):
    _plant(tmp_path / "runs" / "a", _result())
    (tmp_path / "R_figures").mkdir()
    with pytest.raises(ReportError, match="not made by bptsb report"):
        build_report(tmp_path / "runs", tmp_path / "R.md")


@pytest.mark.parametrize(("command", "shown"), [
    ("bptsb reproduce mnist-pca --data /srv/lab/data/mnist", "bptsb reproduce mnist-pca --data …/mnist"),
    ("bptsb reproduce x --out runs/x --data data/mnist", "bptsb reproduce x --out runs/x --data data/mnist"),
    ("bptsb train /home/u/a.yaml --out /tmp/r", "bptsb train …/a.yaml --out …/r"),
    ("bptsb reproduce x --set a=1/2", "bptsb reproduce x --set a=1/2"),
])
def test_report_shows_commands_without_absolute_paths(command: str, shown: str) -> None:
    from bptsb_ros.experiments.report import portable_command

    assert portable_command(command) == shown


def test_a_figures_pdf_sibling_travels_with_it_under_the_same_checks(tmp_path, capsys):
    """bptsb_ros.analysis.style.save writes a PDF beside each PNG: the report copies it and links it after the
    image; a PNG without one is shown alone; a PDF reached through a symbolic link is neither copied nor linked."""
    runs, page = tmp_path / "runs", tmp_path / "docs" / "R.md"
    secret = tmp_path / "secret.pdf"
    secret.write_bytes(b"%PDF SECRET")
    run = _plant(runs / "a", _result(figures=["fig.png", "alone.png", "leak.png"]),
                 {"fig.png": FIG, "fig.pdf": b"%PDF planted", "alone.png": FIG, "leak.png": FIG})
    (run / "leak.pdf").symlink_to(secret)
    rc, err = _report(runs, page, capsys)
    assert rc == 0, err
    figs = page.parent / "R_figures" / "toy-trust-smoke-seed0"
    assert sorted(p.name for p in figs.iterdir()) == ["alone.png", "fig.pdf", "fig.png", "leak.png"]
    assert (figs / "fig.pdf").read_bytes() == b"%PDF planted"
    lines = [ln for ln in page.read_text().splitlines() if ln.startswith("![")]
    assert lines == ["![fig](R_figures/toy-trust-smoke-seed0/fig.png) ([PDF](R_figures/toy-trust-smoke-seed0/fig.pdf))",
                     "![alone](R_figures/toy-trust-smoke-seed0/alone.png)",
                     "![leak](R_figures/toy-trust-smoke-seed0/leak.png)"]
    assert b"SECRET" not in b"".join(p.read_bytes() for p in (page.parent / "R_figures").rglob("*") if p.is_file())
