"""A failed `bptsb reproduce` never blocks the same command: a run that failed before it made anything leaves
nothing behind, one that made something says how to continue it (--resume) or start again (--force); the summary
it prints holds no Python reprs and cuts no text."""

from __future__ import annotations

import pytest

from bptsb_ros.cli import main
from bptsb_ros.cli.reproduce_cmd import summary_table
from bptsb_ros.experiments.registry import _REGISTRY, RUN_MARKER, Context, experiment

STATE = {"fail": True, "write_first": False}


def _toy(ctx: Context) -> None:
    if STATE["write_first"]:
        (ctx.out_dir / "trained.txt").write_text("half of the work")
    if STATE["fail"]:
        raise RuntimeError("planted failure")
    ctx.row("toy system", "a metric with a long name: error / target mean square", "1", 0.0123456, None)
    ctx.claim("ours > 1 (qualitative)", False, "ours = 0.0123")


@pytest.fixture
def toy():
    experiment("toy-retry", paper_ref="Table 0", summary="fails on demand")(_toy)
    STATE.update(fail=True, write_first=False)
    yield "toy-retry"
    _REGISTRY.pop("toy-retry", None)


def test_a_run_that_failed_before_making_anything_leaves_nothing_and_reruns_as_it_is(toy, tmp_path, capsys):
    out = tmp_path / "runs" / "toy"
    args = ["reproduce", toy, "--scale", "smoke", "--out", str(out), "--no-progress"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "planted failure" in err and "--resume" not in err
    assert not out.exists() and (tmp_path / "runs").exists()
    STATE["fail"] = False
    assert main(args) == 0  # the same command, no --force
    assert (out / "result.json").is_file()


def test_an_existing_empty_folder_is_left_as_it_was(toy, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    assert main(["reproduce", toy, "--scale", "smoke", "--out", str(out), "--no-progress"]) == 1
    assert out.is_dir() and list(out.iterdir()) == []


def test_a_run_that_made_something_says_how_to_continue_it(toy, tmp_path, capsys):
    out = tmp_path / "run"
    STATE["write_first"] = True
    args = ["reproduce", toy, "--scale", "smoke", "--out", str(out), "--no-progress"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert f"the unfinished run stays in {out}: add --resume to continue it, or --force to start again" in err
    assert (out / "trained.txt").is_file() and (out / RUN_MARKER).is_file()
    STATE["fail"] = False
    assert main([*args, "--resume"]) == 0


def test_the_printed_summary_has_no_repr_and_cuts_nothing(toy, tmp_path, capsys):
    STATE["fail"] = False
    assert main(["reproduce", toy, "--scale", "smoke", "--out", str(tmp_path / "r"), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "None" not in out
    assert "a metric with a long name: error / target mean square" in out
    assert "ours > 1 (qualitative)" in out
    assert "0.01235" in out


def test_summary_table_aligns_whole_cells():
    rows = [{"system": "FL (closed loop)", "metric": "error / target mean square", "unit": "1", "ours": 0.123456,
             "paper": None},
            {"system": "SWG", "metric": "periods", "unit": "", "ours": 12345678.0, "paper": "> 1 (qualitative)"}]
    lines = summary_table(rows)
    assert lines[0].split() == ["system", "metric", "ours", "paper", "unit"]
    assert "0.1235" in lines[1] and "—" in lines[1]
    assert "1.235e+07" in lines[2] and "> 1 (qualitative)" in lines[2]
    assert len({line.index("metric") if i == 0 else line.index(r["metric"]) for i, (line, r) in
                enumerate(zip(lines, [rows[0], *rows]))}) == 1
    assert summary_table([]) == []
