"""`bptsb report` never replaces a page made from other runs without --force, never mixes scales on a page unless
asked, and by default writes beside the runs it reads: with no arguments in a clone REPRODUCTION.md is untouched."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

from bptsb_ros.analysis.report_guard import page_sources, sources_line
from bptsb_ros.cli import main


def _plant(runs: Path, experiment: str, scale: str, seed: int = 0) -> Path:
    run_dir = runs / f"{experiment}-{scale}-{seed}"
    run_dir.mkdir(parents=True)
    (run_dir / "result.json").write_text(json.dumps({
        "experiment": experiment, "paper_ref": "Fig. 1", "scale": scale, "seed": seed, "wall_s": 1.0,
        "rows": [{"system": "s", "metric": "m", "unit": "1", "ours": 1.0, "paper": None}],
        "claims": [{"claim": "c", "holds": True, "evidence": "e"}], "figures": []}))
    return run_dir


def _report(capsys, *args: str) -> tuple[int, str]:
    capsys.readouterr()
    rc = main(["report", *args])
    return rc, capsys.readouterr().err


def test_the_page_records_its_results_and_they_read_back():
    results = [{"experiment": "narma-ipc", "scale": "paper", "seed": 0},
               {"experiment": "memory-task", "scale": "paper", "seed": 3}]
    line = sources_line(results)
    assert line == "<!-- bptsb report results: memory-task/paper/3 narma-ipc/paper/0 -->"
    assert page_sources(f"<!-- marker -->\n{line}\n# Title\n") == {"memory-task/paper/3", "narma-ipc/paper/0"}


def test_a_page_from_before_the_record_is_read_by_its_headings():
    text = ("# Reproduction\n\n## narma-ipc (paper, seed 0)\n\ntext\n\n## memory-task (short, seed 2)\n\n"
            "## target-ipc (paper, 4 seeds: 0-2,7)\n\n## msdn-nonlinearity (paper, 3 seeds: 5-1)\n")
    assert page_sources(text) == {"narma-ipc/paper/0", "memory-task/short/2", "target-ipc/paper/0",
                                  "target-ipc/paper/1", "target-ipc/paper/2", "target-ipc/paper/7"}
    committed = page_sources((REPO / "REPRODUCTION.md").read_text(encoding="utf-8"))
    assert len(committed) >= 19 and all(k.split("/")[1] == "paper" for k in committed)


def test_the_same_runs_replace_their_page_and_other_runs_do_not(tmp_path, capsys):
    paper, smoke = tmp_path / "paper_runs", tmp_path / "smoke_runs"
    _plant(paper, "narma-ipc", "paper")
    _plant(paper, "memory-task", "paper")
    _plant(smoke, "narma-ipc", "smoke")
    page = tmp_path / "RESULTS.md"
    assert _report(capsys, str(paper), "--out", str(page))[0] == 0
    before = page.read_text()
    assert _report(capsys, str(paper), "--out", str(page))[0] == 0  # the same runs: replaced
    assert page.read_text() == before

    rc, err = _report(capsys, str(smoke), "--out", str(page))
    assert rc == 1 and len(err.strip().splitlines()) == 1
    assert "made from other runs" in err and "memory-task/paper/0" in err and "--force" in err
    assert page.read_text() == before

    shutil.rmtree(paper / "memory-task-paper-0")  # one result fewer is a result lost, too
    assert _report(capsys, str(paper), "--out", str(page))[0] == 1
    assert page.read_text() == before

    assert _report(capsys, str(smoke), "--out", str(page), "--force")[0] == 0
    assert "narma-ipc (smoke, seed 0)" in page.read_text()


def test_a_page_with_more_runs_replaces_one_with_fewer(tmp_path, capsys):
    runs = tmp_path / "runs"
    _plant(runs, "narma-ipc", "paper")
    page = tmp_path / "R.md"
    assert _report(capsys, str(runs), "--out", str(page))[0] == 0
    _plant(runs, "memory-task", "paper")
    assert _report(capsys, str(runs), "--out", str(page))[0] == 0
    assert page_sources(page.read_text()) == {"narma-ipc/paper/0", "memory-task/paper/0"}


def test_scales_are_not_mixed_unless_asked(tmp_path, capsys):
    runs = tmp_path / "runs"
    _plant(runs, "narma-ipc", "paper")
    _plant(runs, "narma-ipc", "smoke")
    page = tmp_path / "R.md"
    rc, err = _report(capsys, str(runs), "--out", str(page))
    assert rc == 1 and "paper, smoke" in err and "--mix-scales" in err
    assert not page.exists()
    assert _report(capsys, str(runs), "--out", str(page), "--mix-scales")[0] == 0
    assert page_sources(page.read_text()) == {"narma-ipc/paper/0", "narma-ipc/smoke/0"}


def test_report_without_arguments_writes_beside_the_runs_not_over_reproduction_md(tmp_path, capsys, monkeypatch):
    clone = tmp_path / "clone"
    clone.mkdir()
    shutil.copy(REPO / "REPRODUCTION.md", clone / "REPRODUCTION.md")
    committed = (clone / "REPRODUCTION.md").read_bytes()
    _plant(clone / "runs" / "reproduce", "lissajous-closed-loop", "smoke")
    monkeypatch.chdir(clone)
    assert _report(capsys)[0] == 0
    assert (clone / "REPRODUCTION.md").read_bytes() == committed
    assert "lissajous-closed-loop (smoke, seed 0)" in (clone / "runs" / "reproduce" / "REPORT.md").read_text()
    # told to write over the committed page of paper runs, it refuses without --force
    rc, err = _report(capsys, "runs/reproduce", "--out", "REPRODUCTION.md")
    assert rc == 1 and "made from other runs" in err
    assert (clone / "REPRODUCTION.md").read_bytes() == committed


@pytest.mark.parametrize("line", [
    "<!-- bptsb report results: ../../etc/passwd/paper/0 -->",
    "<!-- bptsb report results: a/b -->",
])
def test_a_record_that_is_not_keys_records_nothing(line):
    assert page_sources(f"x\n{line}\n") == set()


def test_an_aggregate_over_seeds_records_each_seed():
    from bptsb_ros.analysis.report_guard import result_keys

    assert result_keys({"experiment": "narma-ipc", "scale": "paper", "seeds": [0, 1, 2]}) == {
        "narma-ipc/paper/0", "narma-ipc/paper/1", "narma-ipc/paper/2"}
    assert result_keys({"experiment": "narma-ipc", "scale": "paper", "seed": 4}) == {"narma-ipc/paper/4"}
