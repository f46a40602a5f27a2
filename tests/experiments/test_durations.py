"""``bptsb reproduce --list``: the measured times are data (experiments/durations.yaml), complete, and printed as
a table that cuts nothing."""

from __future__ import annotations

import math

import pytest

from bptsb_ros.experiments.durations import (
    Duration,
    DurationsError,
    SeedsDuration,
    durations,
    format_seconds,
    parse_durations,
    reproduce_table,
    seed_plan,
    seeds_seconds,
)


def _entry(seconds=5.0, measured="2026-12-06 on 2 cores"):
    return {"seconds": seconds, "measured": measured}


def _valid():
    return {"toy": {"smoke": _entry(3), "short": _entry(75), "paper": _entry(8399), "seeds": {"n": 5}}}


def test_a_valid_file_is_read_as_given():
    table, seeds = parse_durations(_valid())
    assert table == {"toy": {"smoke": Duration(3.0, "2026-12-06 on 2 cores"),
                             "short": Duration(75.0, "2026-12-06 on 2 cores"),
                             "paper": Duration(8399.0, "2026-12-06 on 2 cores")}}
    assert seeds == {"toy": SeedsDuration(5)}


def test_a_measured_seed_run_and_its_arguments_are_read_as_given():
    data = _valid()
    data["toy"]["seeds"] = {"n": 3, "seconds": 120, "measured": "2026-12-07", "args": " --set n_seeds=1 ",
                            "share": 0.5}
    assert parse_durations(data)[1]["toy"] == SeedsDuration(3, Duration(120.0, "2026-12-07"), "--set n_seeds=1", 0.5)


@pytest.mark.parametrize("break_it", [
    lambda d: d["toy"].pop("short"),
    lambda d: d["toy"].update(huge=_entry()),
    lambda d: d["toy"].update(smoke=_entry(0)),
    lambda d: d["toy"].update(smoke=_entry(-1)),
    lambda d: d["toy"].update(smoke=_entry(math.nan)),
    lambda d: d["toy"].update(smoke=_entry(True)),
    lambda d: d["toy"].update(smoke=_entry("5 s")),
    lambda d: d["toy"].update(smoke=_entry(None)),
    lambda d: d["toy"].update(smoke=_entry(5, "  ")),
    lambda d: d["toy"].update(smoke=5),
    lambda d: d.update(toy=["smoke"]),
    lambda d: d["toy"].pop("seeds"),
    lambda d: d["toy"].update(seeds={"n": 0}),
    lambda d: d["toy"].update(seeds={"n": 1001}),
    lambda d: d["toy"].update(seeds={"n": 2.5}),
    lambda d: d["toy"].update(seeds={"n": True}),
    lambda d: d["toy"].update(seeds={"n": 3, "seconds": 10}),  # a time says when it was measured
    lambda d: d["toy"].update(seeds={"n": 3, "measured": "today"}),
    lambda d: d["toy"].update(seeds={"n": 3, "share": 0}),
    lambda d: d["toy"].update(seeds={"n": 3, "share": 1.5}),
    lambda d: d["toy"].update(seeds={"n": 3, "args": 7}),
    lambda d: d["toy"].update(seeds={"n": 3, "workers": 2}),
    lambda d: d["toy"].update(seeds=3),
    lambda d: d["toy"].update(seeds={"n": 3, "upper_bound": True}),  # a bound of no measured time
    lambda d: d["toy"].update(seeds={"n": 3, "seconds": 10, "measured": "then", "upper_bound": "yes"}),
])
def test_a_broken_entry_is_one_error_naming_it(break_it):
    data = _valid()
    break_it(data)
    with pytest.raises(DurationsError, match="toy"):
        parse_durations(data)


def test_the_packaged_file_times_every_experiment_at_every_scale():
    from bptsb_ros.experiments.registry import MODULES, experiments

    ours = {name for name, e in experiments().items() if e.run.__module__ in MODULES}
    assert len(ours) == 19
    assert set(durations()) == ours
    plan = seed_plan()
    assert set(plan) == ours
    # the seed counts verdicts are drawn from at paper scale: at least 10, 5 or 3 by the experiment's cost
    assert all(plan[name].n >= 10 for name in ours if name.startswith(("lissajous", "locomotion", "closed-loop")))
    assert min(plan[name].n for name in ours) >= 3


@pytest.mark.parametrize(("seeds", "parallel", "expected"), [
    (SeedsDuration(10), False, (500.0, False)),  # seeds side by side on 2 workers: 10 / 2 × 100 s
    (SeedsDuration(10), True, (1000.0, False)),  # each seed takes both workers: 10 × 100 s
    (SeedsDuration(5, share=0.2), True, (100.0, False)),  # one of five trainings per seed
    (SeedsDuration(10, Duration(42.0, "then")), False, (42.0, True)),  # a measurement wins
])
def test_the_seed_run_time_is_measured_or_estimated_from_one_seed(seeds, parallel, expected):
    assert seeds_seconds(100.0, seeds, parallel) == expected


@pytest.mark.parametrize(("seconds", "text"), [
    (3.2, "3 s"), (59.4, "59 s"), (75, "1.2 min"), (252, "4.2 min"), (3172.09, "53 min"), (8399.33, "2.3 h"),
])
def test_times_are_written_in_a_unit_that_fits(seconds, text):
    assert format_seconds(seconds) == text


def test_the_table_aligns_its_columns_and_cuts_nothing():
    times, seeds = parse_durations(_valid())
    ref = "supplement 'Behavioral switching' (locomotion), Fig. S(a), (c), (e)"
    lines = reproduce_table([("toy", ref, False), ("no-time", "Fig. 1", False)], times, seeds)
    assert lines[0].split() == ["experiment", "smoke", "short", "paper", "seeds", "paper", "×", "seeds", "paper",
                                "figure"]
    assert lines[2].split()[:10] == ["toy", "3", "s", "1.2", "min", "2.3", "h", "5", "≈", "5.8"]  # 5/2 × 8399 s
    assert lines[2].endswith(ref)  # the whole text, last
    assert lines[3].split()[:4] == ["no-time", "—", "—", "—"]
    # every row's paper figure starts in the same column
    assert len({line.index(cell) for line, cell in ((lines[2], ref), (lines[3], "Fig. 1"))}) == 1
    assert lines[-1] == "all experiments at paper scale over their seeds: ≈ 5.8 h on 2 cores (≈: estimated from " \
                        "the one-seed time)"


def test_the_total_is_measured_only_when_every_seed_run_is():
    times, seeds = parse_durations(_valid())
    seeds["toy"] = SeedsDuration(5, Duration(3600.0, "then"))
    lines = reproduce_table([("toy", "Fig. 1", True)], times, seeds)
    assert lines[2].split()[7:10] == ["5", "1.0", "h"]
    assert lines[-1] == "all experiments at paper scale over their seeds: 1.0 h on 2 cores"


def test_an_upper_bound_is_marked_in_its_row_and_the_total():
    data = _valid()
    data["toy"]["seeds"] = {"n": 5, "seconds": 7200, "measured": "then", "upper_bound": True}
    data["other"] = {**_valid()["toy"], "seeds": {"n": 2, "seconds": 1800, "measured": "then", "upper_bound": False}}
    times, seeds = parse_durations(data)
    assert seeds["toy"].upper_bound is True and seeds["other"].upper_bound is False
    lines = reproduce_table([("toy", "Fig. 1", True), ("other", "Fig. 2", True)], times, seeds)
    assert lines[2].split()[7:11] == ["5", "≤", "2.0", "h"] and lines[3].split()[7:10] == ["2", "30", "min"]
    assert lines[-1] == "all experiments at paper scale over their seeds: ≤ 2.5 h on 2 cores (≤: at most, a killed " \
                        "attempt counted until the run resumed)"
    del data["other"]
    data["toy"]["seeds"] = {"n": 5}  # an estimate beside the bound: the total is an estimate
    data["bound"] = {**_valid()["toy"], "seeds": {"n": 2, "seconds": 1800, "measured": "then", "upper_bound": True}}
    times, seeds = parse_durations(data)
    assert reproduce_table([("toy", "Fig. 1", False), ("bound", "Fig. 2", True)], times, seeds)[-1] == \
        "all experiments at paper scale over their seeds: ≈ 6.3 h on 2 cores (≈: estimated from the one-seed time; " \
        "≤: at most, a killed attempt counted until the run resumed)"


def test_reproduce_list_prints_the_table(capsys):
    from bptsb_ros.cli import main
    from bptsb_ros.experiments.registry import MODULES, experiments

    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    for exp in experiments().values():
        if exp.run.__module__ in MODULES:
            row = next(line for line in out.splitlines() if line.startswith(exp.name + " "))
            assert row.endswith(exp.paper_ref), row
    assert "None" not in out


def test_each_measured_seed_run_time_is_its_committed_run():
    """A multi-seed time in durations.yaml is the wall time of the committed run its text names, and it is marked an
    upper bound exactly where that run's page says "at most"."""
    import json
    import re

    from conftest import REPO_ROOT

    from bptsb_ros.experiments.report import _wall_kinds

    checked = 0
    for name, plan in seed_plan().items():
        if plan.measured is None:
            continue
        found = re.match(r"the run (\S+-paper) over seeds ", plan.measured.measured)
        assert found, f"{name}: the seeds time names no committed run"
        run = json.loads((REPO_ROOT / "reproduction" / "runs" / found.group(1) / "result.json").read_text())
        assert run["experiment"] == name and run["seeds"] == list(range(plan.n)), name
        assert run["wall_s"] == pytest.approx(plan.measured.seconds, abs=0.005), name
        assert plan.upper_bound == (_wall_kinds(run) == frozenset({"upper"})), name
        checked += 1
    assert checked >= 15
