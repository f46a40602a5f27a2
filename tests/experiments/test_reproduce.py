"""`bptsb reproduce` / `bptsb report`: the result.json schema, the runner, the report page, and a smoke run."""

from __future__ import annotations

import json
import time
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from bptsb_ros.cli import main
from bptsb_ros.experiments import ExperimentError, ResultError, read_result, run_experiment, validate_result
from bptsb_ros.experiments.registry import _REGISTRY, Context, experiment
from bptsb_ros.experiments.report import build_report
from bptsb_ros.experiments.result import Claim


def _planted(ctx: Context) -> None:
    """A toy experiment with known numbers: ours = 2·seed + 1, the claim "ours > paper" with paper = 2."""
    ours = 2 * ctx.seed + 1
    ctx.row("toy", "value", "m", ours, 2.0)
    ctx.claim("ours exceeds the paper's 2", ours > 2, f"ours = {ours}")
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, ours])
    fig.savefig(ctx.out_dir / "toy.png")
    plt.close(fig)
    ctx.figure(ctx.out_dir / "toy.png")


@pytest.fixture
def toy_experiment():
    experiment("toy-planted", paper_ref="Table 0", summary="planted numbers")(_planted)
    yield "toy-planted"
    _REGISTRY.pop("toy-planted", None)


def test_claim_refuses_anything_but_a_bool():
    with pytest.raises(ResultError, match="computed bool"):
        Claim("x", "yes", "e")  # type: ignore[arg-type]
    assert Claim("x", 1 > 0, "e").holds is True


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("claims"), "missing key 'claims'"),
    (lambda d: d.update(scale="huge"), "scale must be one of"),
    (lambda d: d["claims"][0].update(holds="true"), r"claims\[0\].holds"),
    (lambda d: d["rows"][0].update(ours="1.0"), r"rows\[0\].ours"),
    (lambda d: d["figures"].append("/etc/passwd"), "inside the run directory"),
    (lambda d: d["figures"].append("../x.png"), "inside the run directory"),
    (lambda d: d.update(seed=True), "seed has the wrong type"),
])
def test_schema_rejects_bad_results(mutate, message):
    good = {"experiment": "e", "paper_ref": "Fig. 1", "scale": "smoke", "seed": 0, "wall_s": 1.0,
            "rows": [{"system": "s", "metric": "m", "unit": "1", "ours": 1.0, "paper": None}],
            "claims": [{"claim": "c", "holds": True, "evidence": "e"}], "figures": []}
    validate_result(good)
    mutate(good)
    with pytest.raises(ResultError, match=message):
        validate_result(good)


def test_runner_writes_result_and_never_overwrites(tmp_path, toy_experiment):
    path, data = run_experiment(toy_experiment, scale="smoke", seed=3, out_dir=tmp_path / "a", progress=False)
    on_disk = json.loads(path.read_text())
    assert on_disk == data
    assert on_disk["rows"] == [{"system": "toy", "metric": "value", "unit": "m", "ours": 7.0, "paper": 2.0}]
    assert on_disk["claims"][0]["holds"] is True and on_disk["figures"] == ["toy.png"]
    assert on_disk["seed"] == 3 and on_disk["scale"] == "smoke" and on_disk["wall_s"] >= 0
    with pytest.raises(ExperimentError, match="exists"):
        run_experiment(toy_experiment, scale="smoke", seed=0, out_dir=tmp_path / "a", progress=False)
    _, again = run_experiment(toy_experiment, scale="smoke", seed=0, out_dir=tmp_path / "a", force=True,
                              progress=False)
    assert again["claims"][0]["holds"] is False  # ours = 1 < 2
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "checkpoint.pt").write_bytes(b"an earlier run")
    with pytest.raises(ExperimentError, match="used exists"):
        run_experiment(toy_experiment, scale="smoke", out_dir=tmp_path / "used", progress=False)
    assert (tmp_path / "used" / "checkpoint.pt").read_bytes() == b"an earlier run"
    with pytest.raises(ExperimentError, match="not one"):  # --force never deletes what is not a reproduce run
        run_experiment(toy_experiment, scale="smoke", out_dir=tmp_path / "used", force=True, progress=False)
    assert (tmp_path / "used" / "checkpoint.pt").read_bytes() == b"an earlier run"
    (tmp_path / "a" / "stale-job.json").write_text("{}")  # e.g. a job of another scale
    run_experiment(toy_experiment, scale="smoke", seed=3, out_dir=tmp_path / "a", force=True, progress=False)
    assert not (tmp_path / "a" / "stale-job.json").exists()
    # --resume: only an unfinished reproduce run (marker, no result.json), continued in place
    with pytest.raises(ExperimentError, match="finished"):
        run_experiment(toy_experiment, scale="smoke", out_dir=tmp_path / "a", resume=True, progress=False)
    with pytest.raises(ExperimentError, match="not one"):
        run_experiment(toy_experiment, scale="smoke", out_dir=tmp_path / "used", resume=True, progress=False)
    (tmp_path / "a" / "result.json").unlink()  # as a run that was killed before it finished leaves it
    (tmp_path / "a" / "finished-job.json").write_text("{}")
    _, resumed = run_experiment(toy_experiment, scale="smoke", seed=3, out_dir=tmp_path / "a", resume=True,
                                progress=False)
    assert (tmp_path / "a" / "finished-job.json").exists() and resumed["provenance"]["command"].endswith("--resume")
    with pytest.raises(ExperimentError, match="unknown experiment"):
        run_experiment("no-such-experiment", out_dir=tmp_path / "b")
    with pytest.raises(ExperimentError, match="scale"):
        run_experiment(toy_experiment, scale="large", out_dir=tmp_path / "c")


def test_report_page_has_tables_claims_and_figures(tmp_path, toy_experiment):
    runs = tmp_path / "runs"
    run_experiment(toy_experiment, scale="smoke", seed=3, out_dir=runs / "held", progress=False)
    run_experiment(toy_experiment, scale="short", seed=0, out_dir=runs / "failed", progress=False)
    page = build_report(runs, tmp_path / "docs" / "REPRODUCTION.md")
    text = page.read_text()
    assert "| toy | value | 7 | 2 | m |" in text and "| toy | value | 1 | 2 | m |" in text
    assert "- ✓ ours exceeds the paper's 2 — ours = 7" in text
    assert "- ✗ ours exceeds the paper's 2 — ours = 1" in text
    assert "| smoke | 1 (3) | 1 | 0 | 0 | 0 |" in text and "| short | 1 (0) | 0 | 1 | 0 | 0 |" in text  # ✓ ✗ split ∅
    links = [line[line.index("](") + 2:-1] for line in text.splitlines() if line.startswith("![")]
    assert len(links) == 2 and all((page.parent / link).is_file() for link in links)
    assert all(link.startswith("REPRODUCTION_figures/") for link in links)  # copied beside the page
    beside = build_report(runs, tmp_path / "R.md")  # the runs lie under the page's folder: linked, not copied
    links = [line[line.index("](") + 2:-1] for line in beside.read_text().splitlines() if line.startswith("![")]
    assert sorted(links) == ["runs/failed/toy.png", "runs/held/toy.png"] and not (tmp_path / "R_figures").exists()


def test_report_names_a_broken_result(tmp_path):
    bad = tmp_path / "runs" / "x" / "result.json"
    bad.parent.mkdir(parents=True)
    bad.write_text('{"experiment": "x"}')
    with pytest.raises(ResultError, match="missing key"):
        build_report(tmp_path / "runs", tmp_path / "R.md")
    assert main(["report", str(tmp_path / "runs"), "--out", str(tmp_path / "R.md")]) == 1
    with pytest.raises(ResultError, match="no result.json"):
        build_report(tmp_path / "empty", tmp_path / "R.md")


def test_every_listed_experiment_is_registered(capsys):
    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    assert "lissajous-closed-loop" in out and "Fig. 4(a)" in out


def test_lissajous_closed_loop_smoke(tmp_path):
    out = tmp_path / "lcl"
    assert main(["reproduce", "lissajous-closed-loop", "--scale", "smoke", "--out", str(out), "--no-progress"]) == 0
    data = read_result(out / "result.json")
    rows = {(r["system"], r["metric"]): r["ours"] for r in data["rows"]}
    open_err = rows[("SWG (open loop)", "trajectory MSE, min over shifts")]
    closed_err = rows[("FL (closed loop)", "trajectory MSE, min over shifts")]
    assert rows[("FL / SWG", "error ratio")] == pytest.approx(closed_err / open_err)
    # the "larger" claim is the computed comparison of the two rows, testable when both loops draw the curve
    both_draw = all(rows[(system, "error / target mean square")] < 0.1
                    for system in ("SWG (open loop)", "FL (closed loop)"))
    assert data["claims"][0]["holds"] == ((closed_err > open_err) if both_draw else None)
    swg_draws = rows[("SWG (open loop)", "error / target mean square")] < 0.1
    assert data["claims"][1]["holds"] == ((rows[("FL (closed loop)", "error / target mean square")] < 0.1)
                                          if swg_draws else None)
    assert all((out / f).is_file() for f in data["figures"]) and len(data["figures"]) == 2
    assert main(["reproduce", "lissajous-closed-loop", "--scale", "smoke", "--out", str(out)]) == 1
    assert Path(out / "agent" / "checkpoint.pt").is_file()


def _fails_first(ctx: Context) -> None:
    """A toy experiment that fails unless ``go`` exists in its directory (as a run killed half-way, after it wrote
    its first file)."""
    (ctx.out_dir / "half-way.txt").write_text("")
    time.sleep(0.3)
    if not (ctx.out_dir / "go").exists():
        raise RuntimeError("planted failure")
    ctx.row("toy", "value", "m", 1.0, None)


@pytest.fixture
def flaky_experiment():
    experiment("toy-fails-first", paper_ref="Table 0", summary="fails once")(_fails_first)
    yield "toy-fails-first"
    _REGISTRY.pop("toy-fails-first", None)


def test_provenance_names_versions_out_and_the_wall_time_of_every_attempt(flaky_experiment, tmp_path):
    from importlib.metadata import version

    import bptsb_ros

    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="planted failure"):
        run_experiment(flaky_experiment, scale="smoke", out_dir=out, progress=False)
    (out / "go").write_text("")
    _, res = run_experiment(flaky_experiment, scale="smoke", out_dir=out, resume=True, progress=False)
    prov = res["provenance"]
    assert prov["command"] == f"bptsb reproduce toy-fails-first --scale smoke --seed 0 --out {out} --resume"
    assert prov["package_version"] == bptsb_ros.__version__
    assert prov["versions"]["numpy"] == version("numpy") and prov["versions"]["torch"] == version("torch")
    attempts = prov["attempts"]
    assert [a["resume"] for a in attempts] == [False, True]
    assert all(a["wall_s"] >= 0.3 for a in attempts)  # each attempt sleeps 0.3 s
    assert res["wall_s"] == pytest.approx(attempts[0]["wall_s"] + attempts[1]["wall_s"], abs=0.011)
    assert res["wall_s"] >= 0.6


def test_a_killed_attempt_counts_until_the_newest_file_it_wrote(flaky_experiment, tmp_path):
    import os

    from bptsb_ros.experiments.registry import ATTEMPTS_FILE, RUN_MARKER

    out = tmp_path / "run"
    out.mkdir()
    (out / RUN_MARKER).write_text("bptsb reproduce toy-fails-first\n")
    start = time.time() - 100.0
    # a killed attempt records its start but never its time; its last file was written 40 s after the start,
    # and an older file (before the attempt) must not count
    (out / ATTEMPTS_FILE).write_text(json.dumps([{"started": "x", "started_unix": start, "resume": False}]))
    (out / "go").write_text("")
    os.utime(out / "go", (start + 40.0, start + 40.0))
    (out / "old").write_text("")
    os.utime(out / "old", (start - 50.0, start - 50.0))
    _, res = run_experiment(flaky_experiment, scale="smoke", out_dir=out, resume=True, progress=False)
    killed, this = res["provenance"]["attempts"]
    assert killed["wall_s"] == pytest.approx(40.0, abs=0.01) and killed["wall_s_estimated"] is True
    assert "wall_s_estimated" not in this and this["wall_s"] >= 0.3
    assert res["wall_s"] == pytest.approx(40.0 + this["wall_s"], abs=0.011)


def test_a_fresh_run_and_force_forget_earlier_attempts(flaky_experiment, tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError):
        run_experiment(flaky_experiment, scale="smoke", out_dir=out, progress=False)
    (out / "go").write_text("")
    with pytest.raises(RuntimeError):  # --force clears the run directory, "go" included
        run_experiment(flaky_experiment, scale="smoke", out_dir=out, force=True, progress=False)
    (out / "go").write_text("")
    _, res = run_experiment(flaky_experiment, scale="smoke", out_dir=out, resume=True, progress=False)
    assert len(res["provenance"]["attempts"]) == 2  # the forced attempt and the resume, not the first


def test_report_lists_versions_and_attempts_in_words():
    from bptsb_ros.experiments.report import _provenance_lines

    lines = _provenance_lines({"command": "bptsb reproduce x --scale smoke", "versions": {"numpy": "2.0", "numba": None,
                                                                                        "torch": "2.13.0"},
                               "attempts": [{"wall_s": 150.0, "wall_s_estimated": True}, {"wall_s": 30.0}]})
    assert "- versions: numpy 2.0, torch 2.13.0" in lines
    assert "- attempts: 2 (2.5 min (killed; at least, from the files it wrote) + 30 s)" in lines
    assert "- attempts: 30 s" in _provenance_lines({"attempts": [{"wall_s": 30.0}]})


def test_an_estimate_that_reaches_the_next_attempt_is_an_upper_bound():
    from bptsb_ros.experiments.report import _provenance_lines, _wall_legend, _wall_text

    def run(*walls: float, estimated: tuple[bool, ...] = (True, False)) -> dict:
        # attempts started 500 s apart; an estimated time of ~500 s reached the next start
        attempts = [{"started_unix": 1000.0 + 500.0 * i, "wall_s": w} for i, w in enumerate(walls)]
        for att, est in zip(attempts, estimated, strict=False):
            if est:
                att["wall_s_estimated"] = True
        return {"wall_s": sum(walls), "provenance": {"attempts": attempts}}

    reaches, short = run(499.5, 30.0), run(300.0, 30.0)
    assert "- attempts: 2 (8.3 min (killed; at most: counted until the run resumed) + 30 s)" in \
        _provenance_lines(reaches["provenance"])
    assert "- attempts: 2 (5.0 min (killed; at least, from the files it wrote) + 30 s)" in \
        _provenance_lines(short["provenance"])
    assert _wall_text(reaches, "table") == "≤ 8.8 min" and _wall_text(reaches, "text") == "at most 8.8 min"
    assert _wall_text(short, "table") == "≥ 5.5 min" and _wall_text(short, "text") == "at least 5.5 min"
    # an upper and a lower bound added up: neither
    mixed = run(499.5, 300.0, 30.0, estimated=(True, True, False))
    assert _wall_text(mixed, "table") == "~ 13.8 min" and _wall_text(mixed, "text") == "about 13.8 min"
    # a measured time is exact even where it reaches the next start; a last attempt, a next entry that is no
    # attempt or a start that is no number leave an estimate a lower bound
    assert _wall_text(run(500.0, 30.0, estimated=(False,)), "table") == "8.8 min"
    assert _wall_text(run(30.0, 499.5, estimated=(False, True)), "table") == "≥ 8.8 min"
    broken = run(499.5, 30.0)
    broken["provenance"]["attempts"][1]["started_unix"] = True
    assert _wall_text(broken, "table") == "≥ 8.8 min"
    broken["provenance"]["attempts"][1] = "damaged"
    assert _wall_text(broken, "table") == "≥ 8.8 min"
    assert _wall_text({"wall_s": 30.0}, "table") == "30 s"
    # the summary table's legend names the marks it uses, and only those
    assert _wall_legend([{"wall_s": 30.0}, run(500.0, 30.0, estimated=(False,))]) == []
    assert _wall_legend([reaches, {"wall_s": 1.0}]) == \
        ["", "Wall time: ≤ at most (a killed attempt counted until the run resumed)."]
    legend = _wall_legend([reaches, short, mixed])[1]
    assert legend.startswith("Wall time: ≤ at most") and "; ≥ at least" in legend and "; ~ about" in legend


def test_a_phase_is_one_line_naming_the_experiment(tmp_path):
    from bptsb_ros.experiments.registry import Context
    from bptsb_ros.experiments.result import ExperimentResult

    lines: list[str] = []
    ctx = Context("smoke", 0, tmp_path, ExperimentResult("toy-phase", "", "smoke", 0), log=lines.append)
    ctx.phase("plotting the return rates")
    assert lines == ["toy-phase: plotting the return rates ..."]
    ctx.progress = False  # --no-progress
    ctx.phase("plotting the return rates")
    assert len(lines) == 1


def test_report_names_the_experiments_it_has_no_run_of(tmp_path, toy_experiment):
    from bptsb_ros.experiments.registry import MODULES
    from bptsb_ros.experiments.report import missing_experiments

    assert missing_experiments(["narma-ipc", "toy-planted"])[:3] == ["mnist-drawing", "mnist-pca", "mnist-labelmap"]
    assert "narma-ipc" not in missing_experiments(["narma-ipc"])
    # planted: the 19 experiments of the paper and the toy one, the page holds only the toy one
    everyone = missing_experiments([])
    assert len(everyone) == 20 and everyone[-1] == "toy-planted" and len(MODULES) == 17
    run_experiment(toy_experiment, scale="smoke", out_dir=tmp_path / "runs" / "toy", progress=False)
    text = build_report(tmp_path / "runs", tmp_path / "R.md").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("Not on this page"))
    assert "mnist-drawing, mnist-pca," in line and "locomotion-headwind." in line and "toy-planted" not in line


def test_an_odd_attempts_record_counts_for_nothing_and_an_estimate_stays_marked(flaky_experiment, tmp_path):
    from bptsb_ros.experiments.registry import ATTEMPTS_FILE, RUN_MARKER

    out = tmp_path / "run"
    out.mkdir()
    (out / RUN_MARKER).write_text("bptsb reproduce toy-fails-first\n")
    (out / "go").write_text("")
    now = time.time()
    planted = [{"started_unix": now - 50, "wall_s": 7.0, "wall_s_estimated": True},   # an earlier estimate: kept
               {"started_unix": now - 40, "wall_s": 1e308 * 10},                        # infinite (JSON Infinity)
               {"started_unix": -1e18, "wall_s": 5.0},                                  # a start before 1970
               {"started_unix": now + 1e6, "wall_s": 5.0},                              # a start in the future
               {"started_unix": True, "wall_s": 5.0},                                   # a bool is no time
               {"started_unix": now - 30, "wall_s": float("nan")}]
    (out / ATTEMPTS_FILE).write_text(json.dumps(planted))
    _, res = run_experiment(flaky_experiment, scale="smoke", out_dir=out, resume=True, progress=False)
    earlier, this = res["provenance"]["attempts"]
    assert earlier["wall_s"] == 7.0 and earlier["wall_s_estimated"] is True
    assert res["wall_s"] == pytest.approx(7.0 + this["wall_s"], abs=0.011)
