"""Seeds as an axis: the verdict rule over seeds, the aggregate of planted results, the stored numbers that judge
claims again, and `bptsb reproduce --seeds` with a failing seed, --resume and more seeds."""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from bptsb_ros.cli import main
from bptsb_ros.experiments import measured
from bptsb_ros.experiments.claim_rules import verdict_over_seeds, wilson_interval
from bptsb_ros.experiments.registry import _REGISTRY, Context, experiment, run_experiment
from bptsb_ros.experiments.result import Claim, ResultError, validate_result
from bptsb_ros.experiments.seed_dirs import SeedsError, format_seeds, parse_seeds, sibling_run_dirs
from bptsb_ros.experiments.seeds import (
    aggregate,
    aggregate_claims,
    aggregate_rows,
    rejudge_run,
    run_seeds,
)

# ------------------------------------------------------------------------------------------ the rule


def _wilson_by_hand(k: int, n: int) -> tuple[float, float]:
    """The Wilson score interval written out from its textbook form (z = 1.96), independently of the package."""
    z = 1.96
    p = k / n
    denom = 1 + z * z / n
    centre = p + z * z / (2 * n)
    spread = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (centre - spread) / denom, (centre + spread) / denom


@pytest.mark.parametrize(("k", "n", "lo", "hi"), [
    (5, 10, 0.2366, 0.7634),  # published table values of the 95 % Wilson interval
    (0, 10, 0.0, 0.2775),
    (10, 10, 0.7225, 1.0),
    (3, 3, 0.4385, 1.0),
])
def test_wilson_interval_matches_published_values(k, n, lo, hi):
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)
    assert got == pytest.approx(_wilson_by_hand(k, n), abs=2e-4)


@pytest.mark.parametrize(("holds", "testable", "seeds", "verdict"), [
    (9, 10, 10, "holds"),      # lower bound 0.596 > ½
    (8, 10, 10, "split"),      # lower bound 0.490 < ½ < upper
    (2, 10, 10, "split"),      # upper bound 0.510 > ½
    (1, 10, 10, "fails"),      # upper bound 0.404 < ½
    (0, 10, 10, "fails"),
    (5, 5, 10, "holds"),       # exactly half the seeds could test it: testable; 5 of 5 has lower bound 0.566
    (4, 4, 10, "not_testable"),  # fewer than half could test it
    (4, 5, 5, "split"),
    (3, 3, 3, "split"),        # three seeds cannot settle a claim: 3 of 3 has lower bound 0.439
    (0, 5, 5, "fails"),        # upper bound 0.434
    (1, 5, 5, "split"),        # upper bound 0.624
    (0, 0, 3, "not_testable"),
])
def test_verdict_over_seeds_on_every_side_of_each_boundary(holds, testable, seeds, verdict):
    assert verdict_over_seeds(holds, testable, seeds) == verdict
    if testable:  # the rule as the docs state it, computed from the independent interval
        lo, hi = _wilson_by_hand(holds, testable)
        expected = ("not_testable" if 2 * testable < seeds else "holds" if lo > 0.5 else
                    "fails" if hi < 0.5 else "split")
        assert verdict == expected


@pytest.mark.parametrize("bad", [(3, 2, 5), (-1, 2, 5), (1, 6, 5), (0, 0, 0)])
def test_verdict_refuses_impossible_counts(bad):
    with pytest.raises(ValueError):
        verdict_over_seeds(*bad)
    if bad[1] < 1 or bad[0] > bad[1] or bad[0] < 0:
        with pytest.raises(ValueError):
            wilson_interval(bad[0], bad[1])


# -------------------------------------------------------------------------------------- the aggregate


def _result(seed: int, rows: list[tuple], claims: list[tuple], **extra) -> dict:
    return {"experiment": "toy", "paper_ref": "Fig. 0", "scale": "smoke", "seed": seed, "wall_s": 1.0 + seed,
            "rows": [{"system": s, "metric": m, "unit": u, "ours": o, "paper": p} for s, m, u, o, p in rows],
            "claims": [{"claim": c, "holds": h, "evidence": e} for c, h, e in claims], "figures": [],
            "settings": {"epochs": 3}, **extra}


def test_rows_are_matched_by_key_and_occurrence_with_mean_sd_range():
    per_seed = [
        _result(0, [("a", "err", "m", 1.0, 2.5), ("a", "err", "m", 10.0, None), ("b", "n", "1", 4.0, "> 1")], []),
        _result(1, [("a", "err", "m", 2.0, 2.5), ("a", "err", "m", 20.0, None)], []),
        _result(2, [("a", "err", "m", 3.0, 2.5), ("a", "err", "m", None, None), ("c", "x", "s", 7.0, 7.0)], []),
    ]
    rows = aggregate_rows(per_seed)
    assert [(r["system"], r["metric"]) for r in rows] == [("a", "err"), ("a", "err"), ("b", "n"), ("c", "x")]
    first, second, b, c = rows
    assert first["per_seed"] == [1.0, 2.0, 3.0] and first["n"] == 3
    assert first["ours"] == pytest.approx(2.0) and first["ours_sd"] == pytest.approx(1.0)  # sample sd of 1, 2, 3
    assert (first["ours_min"], first["ours_max"]) == (1.0, 3.0)
    assert first["paper_in_range"] is True  # 2.5 lies in [1, 3]
    assert second["per_seed"] == [10.0, 20.0, None] and second["ours"] == pytest.approx(15.0)
    assert second["ours_sd"] == pytest.approx(math.sqrt(50.0)) and second["paper_in_range"] is None
    assert b["per_seed"] == [4.0, None, None] and b["ours_sd"] == 0.0 and b["paper_in_range"] is None  # text paper
    assert c["paper_in_range"] is True and c["per_seed"] == [None, None, 7.0]


def test_paper_value_outside_our_range_is_said():
    per_seed = [_result(s, [("a", "err", "m", v, 5.0)], []) for s, v in enumerate([1.0, 2.0])]
    assert aggregate_rows(per_seed)[0]["paper_in_range"] is False


def test_claims_count_seeds_that_hold_of_those_that_could_test():
    per_seed = [_result(s, [], [("X holds", v, f"seed {s}"), ("Y", True, "")]) for s, v in
                enumerate([True, True, False, None, True])]
    per_seed[4]["claims"] = per_seed[4]["claims"][:1]  # seed 4 made no claim Y
    claims = {c["claim"]: c for c in aggregate_claims(per_seed)}
    x, y = claims["X holds"], claims["Y"]
    assert x["per_seed"] == [True, True, False, None, True]
    assert x["holds_in"] == [3, 4] and x["not_testable_in"] == 1
    assert x["verdict"] == "split" and x["interval"] == pytest.approx(list(_wilson_by_hand(3, 4)), abs=2e-4)
    assert "3 of 4" in x["evidence"] and "e.g. seed 3" in x["evidence"]  # the not-testable seed's reason is named
    assert y["per_seed"] == [True, True, True, True, None] and y["holds_in"] == [4, 4]
    assert "made no such claim" in y["per_seed_evidence"][4]


def _aggregate_of(verdicts: list[bool | None]) -> dict:
    per_seed = [_result(s, [("a", "err", "m", float(s), 1.0)], [("C", v, "e")]) for s, v in enumerate(verdicts)]
    return aggregate(per_seed, list(range(len(verdicts))), wall_s=9.0)


def test_aggregate_is_valid_and_refuses_tampering():
    data = _aggregate_of([True] * 9 + [False])
    validate_result(data)
    assert data["claims"][0]["verdict"] == "holds" and data["claims"][0]["holds_in"] == [9, 10]
    for path, value, message in [
        (("claims", 0, "verdict"), "fails", "not what the rule gives"),
        (("claims", 0, "verdict"), "maybe", "verdict must be one of"),
        (("claims", 0, "holds_in"), [10, 10], "holds_in must be"),
        (("claims", 0, "per_seed"), [True] * 9, "for each of the 10 seeds"),
        (("rows", 0, "ours"), 99.0, "between ours_min and ours_max"),
        (("rows", 0, "n"), 3, "count the seeds"),
        (("rows", 0, "per_seed"), [1.0] * 10 + [2.0], "for each of the 10 seeds"),
        (("seeds",), [0, 0, 1, 2, 3, 4, 5, 6, 7, 8], "distinct"),
    ]:
        bad = json.loads(json.dumps(data))
        target = bad
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
        with pytest.raises(ResultError, match=message):
            validate_result(bad)


def test_aggregate_refuses_results_of_other_settings_or_seeds():
    a, b = _result(0, [], []), _result(1, [], [])
    b["settings"] = {"epochs": 4}
    with pytest.raises(ResultError, match="settings"):
        aggregate([a, b], [0, 1], wall_s=1)
    with pytest.raises(ResultError, match="made with seed 0"):
        aggregate([a, _result(1, [], [])], [5, 1], wall_s=1)


@pytest.mark.parametrize(("text", "seeds"), [("0-9", list(range(10))), ("0,3,5", [0, 3, 5]),
                                             (" 0-2 , 5 ", [0, 1, 2, 5]), ("7", [7])])
def test_parse_seeds(text, seeds):
    assert parse_seeds(text) == seeds
    assert parse_seeds(format_seeds(seeds)) == seeds


@pytest.mark.parametrize(("text", "message"), [("3-1", "backwards"), ("a", "not a seed"), ("0,0", "twice"),
                                               ("", "needs seeds"), ("0-5000", "at most"), ("2000000", "go up to")])
def test_parse_seeds_refuses_bad_lists(text, message):
    with pytest.raises(SeedsError, match=message):
        parse_seeds(text)


# ------------------------------------------------------------------------------ numbers stored, judged again


@dataclass(frozen=True)
class Inner:
    share: float
    n: int


@dataclass(frozen=True)
class Planted:
    errors: np.ndarray
    flags: np.ndarray
    by_pair: dict[tuple[str, int], float]
    by_wind: dict[float, Inner]
    names: tuple[str, ...]
    note: str = ""


@measured.judge("test-planted")
def planted_claims(n: Planted, bound: float = 0.5) -> list[Claim]:
    """A claim function over every kind of value a result may store."""
    mean = float(np.nanmean(n.errors))
    return [Claim("mean error below the bound", mean < bound, f"mean {mean}"),
            Claim("some flag set", bool(n.flags.any()), str(n.flags.tolist())),
            Claim("pairs", None if not n.by_pair else n.by_pair[("a", 1)] > 0, "no pairs" if not n.by_pair else "")]


def _planted() -> Planted:
    return Planted(np.array([0.1, np.nan, 0.3], dtype=np.float32), np.array([False, True]),
                   {("a", 1): 2.0, ("b", 2): -np.inf}, {0.5: Inner(0.25, 3), -1.0: Inner(float("nan"), 0)},
                   ("x", "y"), "ok")


def test_stored_numbers_decode_to_equal_values():
    value = _planted()
    data = json.loads(json.dumps(measured.encode(value), allow_nan=False))  # valid strict JSON
    back = measured.decode(data, measured.dataclasses_of(planted_claims))
    assert isinstance(back, Planted) and back.errors.dtype == np.float32 and back.flags.dtype == bool
    np.testing.assert_array_equal(back.errors, value.errors)
    np.testing.assert_array_equal(back.flags, value.flags)
    assert back.by_pair[("a", 1)] == 2.0 and back.by_pair[("b", 2)] == -np.inf
    assert back.by_wind[0.5] == Inner(0.25, 3) and math.isnan(back.by_wind[-1.0].share)
    assert back.names == ("x", "y") and back.note == "ok"


def test_a_run_is_judged_again_from_its_numbers_and_a_changed_number_changes_the_verdict():
    entry = measured.record(planted_claims, [_planted()], {"bound": 0.5}, label="[v] ")
    again = measured.rejudge([json.loads(json.dumps(entry))])
    assert again == [Claim("[v] " + c.claim, c.holds, c.evidence) for c in planted_claims(_planted(), bound=0.5)]
    assert again[0].holds is True  # nanmean of 0.1, 0.3 = 0.2 < 0.5
    entry["kwargs"]["bound"] = 0.1
    assert measured.rejudge([entry])[0].holds is False


@pytest.mark.parametrize(("mutate", "message"), [
    (lambda e: e["args"][0].update({"@dataclass": "Exploit"}), "not a type this claim function takes"),
    (lambda e: e.update({"judge": "os.system"}), "no claim function is registered"),
    (lambda e: e["args"][0]["fields"]["errors"].update({"shape": [4]}), "holds 3 values"),
    (lambda e: e["args"][0]["fields"]["errors"].update({"dtype": "object"}), "known dtype"),
    (lambda e: e["args"][0]["fields"].update({"extra": 1}), "has no field"),
    (lambda e: e["args"][0]["fields"].update({"note": {"@eval": "1"}}), "unknown form"),
    (lambda e: e["args"][0]["fields"]["errors"]["@array"].__setitem__(0, "x"), "not a number"),
])
def test_tampered_numbers_are_one_line_errors(mutate, message):
    entry = json.loads(json.dumps(measured.record(planted_claims, [_planted()], {})))
    mutate(entry)
    with pytest.raises(ResultError, match=message):
        measured.rejudge([entry])


def test_deep_nesting_is_refused():
    deep: object = 0
    for _ in range(40):
        deep = [deep]
    with pytest.raises(ResultError, match="nested deeper"):
        measured.decode(deep, {})


def test_an_unregistered_function_cannot_be_recorded():
    with pytest.raises(ValueError, match="not a registered judge"):
        measured.record(lambda: [], [], {})


# -------------------------------------------------------------------------------- running over seeds


@measured.judge("test-toy-seeds")
def toy_claims(value: float) -> list[Claim]:
    return [Claim("value above 2", value > 2, f"value {value}"),
            Claim("value even", None if value > 6 else value % 2 == 0, "too large to tell" if value > 6 else "")]


#: seeds whose next run fails once (planted by a test)
FAIL_ONCE: set[int] = set()


def _toy_run(ctx: Context) -> None:
    """ours = seed; a seed in FAIL_ONCE fails once; each run leaves ``ran-SEED`` beside its folder."""
    if ctx.seed in FAIL_ONCE:
        FAIL_ONCE.discard(ctx.seed)
        raise RuntimeError("planted failure")
    (ctx.out_dir.parent / f"ran-{ctx.seed}").touch()
    ctx.row("toy", "value", "1", float(ctx.seed), 2.0)
    ctx.judge(toy_claims, float(ctx.seed))


@pytest.fixture
def toy_seeds():
    experiment("toy-seeds", paper_ref="Table 0", summary="planted")(_toy_run)
    yield "toy-seeds"
    _REGISTRY.pop("toy-seeds", None)


def test_a_failed_seed_loses_nothing_and_resume_finishes_it(toy_seeds, tmp_path):
    out = tmp_path / "run"
    FAIL_ONCE.add(3)
    logs: list[str] = []
    with pytest.raises(SeedsError, match=r"1 of 5 seeds failed \(seed 3: RuntimeError: planted failure"):
        run_seeds(toy_seeds, [0, 1, 2, 3, 4], out_dir=out, workers=0, log=logs.append)
    assert not (out / "result.json").exists()
    assert sorted(p.name for p in out.glob("ran-*")) == ["ran-0", "ran-1", "ran-2", "ran-4"]
    for p in out.glob("ran-*"):
        p.unlink()
    path, data = run_seeds(toy_seeds, [0, 1, 2, 3, 4], out_dir=out, workers=0, resume=True, log=logs.append)
    assert [p.name for p in out.glob("ran-*")] == ["ran-3"]  # only the failed seed ran again
    assert data["seeds"] == [0, 1, 2, 3, 4] and json.loads(path.read_text()) == data
    row = data["rows"][0]
    assert row["per_seed"] == [0.0, 1.0, 2.0, 3.0, 4.0] and row["ours"] == pytest.approx(2.0)
    assert row["paper_in_range"] is True
    above, even = data["claims"]
    assert above["per_seed"] == [False, False, False, True, True] and above["verdict"] == "split"
    assert even["holds_in"] == [3, 5]
    assert "seeds.png" in data["figures"]
    with pytest.raises(Exception, match="that run finished"):
        run_seeds(toy_seeds, [0, 1, 2, 3, 4], out_dir=out, workers=0, resume=True, log=logs.append)
    # more seeds extend the finished run: only the new ones run
    _, more = run_seeds(toy_seeds, [0, 1, 2, 3, 4, 7, 8], out_dir=out, workers=0, resume=True, log=logs.append)
    assert sorted(p.name for p in out.glob("ran-*")) == ["ran-3", "ran-7", "ran-8"]
    assert more["claims"][1]["not_testable_in"] == 2  # 7 and 8: too large to tell
    assert more["claims"][0]["holds_in"] == [4, 7] and more["claims"][0]["verdict"] == "split"


def test_a_killed_multi_seed_attempt_counts_until_the_last_file_its_seeds_wrote(toy_seeds, tmp_path):
    import os

    from bptsb_ros.experiments.registry import ATTEMPTS_FILE

    out = tmp_path / "run"
    FAIL_ONCE.add(2)
    with pytest.raises(SeedsError):
        run_seeds(toy_seeds, [0, 1, 2], out_dir=out, workers=0, log=lambda m: None)
    # as if killed: the attempt recorded its start, never its time; everything it wrote is dated into its first
    # 40 s, seed 1's result last (the resume rewrites the seeds marker and adds locks in the folders: they do not count)
    start = time.time() - 1000.0
    (out / ATTEMPTS_FILE).write_text(json.dumps([{"started": "x", "started_unix": start, "resume": False}]))
    for path in [out, *out.rglob("*")]:
        os.utime(path, (start + 20.0, start + 20.0))
    os.utime(out / "seed-1" / "result.json", (start + 40.0, start + 40.0))
    os.utime(out / "seed-0", (start + 60.0, start + 60.0))  # a folder tidied after the kill: not the attempt's work
    _, data = run_seeds(toy_seeds, [0, 1, 2], out_dir=out, workers=0, resume=True, log=lambda m: None)
    killed, this = data["provenance"]["attempts"]
    assert killed["wall_s"] == pytest.approx(40.0, abs=0.01) and killed["wall_s_estimated"] is True
    assert data["wall_s"] == pytest.approx(40.0 + this["wall_s"], abs=0.011)


def test_resume_needs_the_same_settings_and_force_only_replaces_a_run(toy_seeds, tmp_path):
    out = tmp_path / "run"
    run_seeds(toy_seeds, [0, 1], out_dir=out, workers=0, log=lambda m: None)
    with pytest.raises(Exception, match="exists; choose another --out"):
        run_seeds(toy_seeds, [0, 1], out_dir=out, workers=0, log=lambda m: None)
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(Exception, match="not one"):
        run_seeds(toy_seeds, [0], out_dir=other, workers=0, force=True, log=lambda m: None)
    assert (other / "notes.txt").read_text() == "mine"


def test_rejudge_recomputes_every_seed_and_the_aggregate(toy_seeds, tmp_path):
    out = tmp_path / "run"
    run_seeds(toy_seeds, [0, 1, 2], out_dir=out, workers=0, log=lambda m: None)
    seed2 = out / "seed-2" / "result.json"
    data = json.loads(seed2.read_text())
    data["claims"][0]["holds"] = True  # a stale verdict: the claim code judges 2 > 2 as False
    data["measured"][0]["args"][0] = 5.0  # and a planted number the rejudging must read
    seed2.write_text(json.dumps(data))
    new = rejudge_run(out, log=lambda m: None)
    assert json.loads(seed2.read_text())["claims"][0] == {"claim": "value above 2", "holds": True,
                                                         "evidence": "value 5.0"}
    assert new["claims"][0]["per_seed"] == [False, False, True]
    judged = json.loads(seed2.read_text())["judged"]
    assert judged["rejudged"] is True and judged["at_run"]["rejudged"] is False
    first = judged["at_run"]
    rejudge_run(out, log=lambda m: None)  # judged a second time: the run's own judgement stays in at_run
    assert json.loads(seed2.read_text())["judged"]["at_run"] == first


def test_cli_seeds_and_rejudge(toy_seeds, tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["reproduce", toy_seeds, "--scale", "smoke", "--seeds", "0-2", "--out", str(out),
                 "--workers", "0", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "0/3 of 3 seeds: value above 2" in text
    with pytest.raises(SystemExit) as usage:  # one or the other
        main(["reproduce", toy_seeds, "--seeds", "0-2", "--seed", "1"])
    assert usage.value.code == 2
    assert main(["reproduce", toy_seeds, "--rejudge", "--out", str(out)]) == 0
    assert main(["reproduce", toy_seeds, "--scale", "smoke", "--seeds", "2-1", "--out", str(tmp_path / "x")]) == 1
    assert "backwards" in capsys.readouterr().err


def test_single_run_records_its_judge_and_numbers(toy_seeds, tmp_path):
    _, data = run_experiment(toy_seeds, seed=4, out_dir=tmp_path / "one", progress=False)
    assert data["measured"] == [{"judge": "test-toy-seeds", "args": [4.0], "kwargs": {}, "label": ""}]
    assert data["judged"]["complete"] is True and len(data["judged"]["code_digest"]) == 12


def test_sibling_runs_are_the_same_seed_of_the_runs_beside(tmp_path):
    from bptsb_ros.experiments.seed_dirs import SEEDS_MARKER

    for exp in ("a", "b", "c"):
        for s in (0, 1):
            (tmp_path / exp / f"seed-{s}").mkdir(parents=True)
        (tmp_path / exp / SEEDS_MARKER).write_text("{}")
    assert sibling_run_dirs(tmp_path / "a" / "seed-1") == [tmp_path / "b" / "seed-1", tmp_path / "c" / "seed-1"]
    (tmp_path / "single").mkdir()
    assert sibling_run_dirs(tmp_path / "single") == [tmp_path / e for e in ("a", "b", "c")]
    ctx = Context("smoke", 1, tmp_path / "a" / "seed-1", None)  # type: ignore[arg-type]
    assert ctx.sibling_run("mnist-drawing") == tmp_path / "mnist-drawing" / "seed-1"
    assert Context("smoke", 0, tmp_path / "single", None).sibling_run("x") == tmp_path / "x"  # type: ignore[arg-type]
    assert Path(tmp_path / "a" / "seed-1").is_dir()


def test_report_shows_k_of_n_strips_and_means_not_the_seeds_alone(toy_seeds, tmp_path):
    from bptsb_ros.experiments.report import build_report

    runs = tmp_path / "runs"
    run_seeds(toy_seeds, [0, 1, 2, 3], out_dir=runs / "toy", workers=0, log=lambda m: None)
    text = build_report(runs, tmp_path / "R.md").read_text()
    # one section for the aggregate; the seeds' own results are in it, not beside it
    assert text.count("\n## ") == 1 and "## toy-seeds (smoke, 4 seeds: 0-3)" in text
    assert "| [toy-seeds](#toy-seeds-smoke-4-seeds-0-3) |" in text and "| smoke | 4 (0-3) | 0 | 0 | 2 | 0 |" in text
    assert "| toy | value | 1.5 ± 1.291 (0–3, 4) | 2 | yes | 1 |" in text  # mean and sample sd of 0, 1, 2, 3
    assert "- **split** 1/4 `✗✗✗✓` value above 2" in text
    assert "- **split** 2/4 `✓✗✓✗` value even" in text
    assert "![seeds](runs/toy/seeds.png)" in text


def test_a_run_copied_without_its_marker_is_still_one_section(toy_seeds, tmp_path):
    """Results and figures copied elsewhere (a results repository) leave the run's marker behind: the aggregate's
    seed_runs still say which folders are its seeds; a stray result beside them is its own section."""
    from bptsb_ros.experiments.report import find_results
    from bptsb_ros.experiments.seeds import SEEDS_MARKER

    runs = tmp_path / "runs"
    run_seeds(toy_seeds, [0, 1, 2], out_dir=runs / "toy", workers=0, log=lambda m: None)
    (runs / "toy" / SEEDS_MARKER).unlink()
    shutil.copytree(runs / "toy" / "seed-1", runs / "toy" / "seed-7")  # not one of the aggregate's seeds
    assert [p.relative_to(runs).as_posix() for p, _ in find_results(runs)] == ["toy/result.json",
                                                                               "toy/seed-7/result.json"]


def test_python_api_runs_seeds(toy_seeds, tmp_path):
    import bptsb_ros as bp

    data = bp.run_experiment(toy_seeds, seeds=[0, 5], out=tmp_path / "api", log=lambda m: None)
    assert data["seeds"] == [0, 5] and data["rows"][0]["per_seed"] == [0.0, 5.0]
    assert (tmp_path / "api" / "seed-5" / "result.json").is_file()
    gone = bp.run_experiment(toy_seeds, seeds=[1, 2], log=lambda m: None)  # a temporary directory
    assert gone["rows"][0]["ours"] == pytest.approx(1.5) and gone["figures"] == []
