"""``bptsb reproduce --list``: the measured times are data (experiments/durations.yaml), complete, and printed as
a table that cuts nothing."""

from __future__ import annotations

import math

import pytest

from bptsb_ros.experiments.durations import (
    Duration,
    DurationsError,
    durations,
    format_seconds,
    parse_durations,
    reproduce_table,
)


def _entry(seconds=5.0, measured="2026-12-06 on 2 cores"):
    return {"seconds": seconds, "measured": measured}


def _valid():
    return {"toy": {"smoke": _entry(3), "short": _entry(75), "paper": _entry(8399)}}


def test_a_valid_file_is_read_as_given():
    table = parse_durations(_valid())
    assert table == {"toy": {"smoke": Duration(3.0, "2026-12-06 on 2 cores"),
                             "short": Duration(75.0, "2026-12-06 on 2 cores"),
                             "paper": Duration(8399.0, "2026-12-06 on 2 cores")}}


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


@pytest.mark.parametrize(("seconds", "text"), [
    (3.2, "3 s"), (59.4, "59 s"), (75, "1.2 min"), (252, "4.2 min"), (3172.09, "53 min"), (8399.33, "2.3 h"),
])
def test_times_are_written_in_a_unit_that_fits(seconds, text):
    assert format_seconds(seconds) == text


def test_the_table_aligns_its_columns_and_cuts_nothing():
    times = parse_durations(_valid())
    ref = "supplement 'Behavioral switching' (locomotion), Fig. S(a), (c), (e)"
    lines = reproduce_table([("toy", ref), ("no-time", "Fig. 1")], times)
    assert lines[0].split() == ["experiment", "smoke", "short", "paper", "paper", "figure"]
    assert lines[2].split()[:4] == ["toy", "3", "s", "1.2"]
    assert lines[2].endswith(ref)  # the whole text, last
    assert lines[3].split()[:4] == ["no-time", "—", "—", "—"]
    # every row's paper figure starts in the same column
    assert len({line.index(cell) for line, cell in ((lines[2], ref), (lines[3], "Fig. 1"))}) == 1


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
