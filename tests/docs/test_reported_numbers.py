"""Every reported number against an independent value: the switching experiment's per-segment error
normalisation, and REPRODUCTION.md's number format and order, on planted inputs with hand-computed answers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bptsb_ros.experiments.lissajous_switching import phase_locked_nmse, segment_errors
from bptsb_ros.experiments.report import _duration, _fmt, build_report, code_versions_lines, find_results


def _circle(n: int, radius: float, centre: tuple[float, float]) -> np.ndarray:
    """(n, 2) one full turn of a circle sampled at n equal steps: mean of cos² and sin² is exactly 1/2."""
    phi = 2 * np.pi * np.arange(n) / n
    return np.stack([centre[0] + radius * np.cos(phi), centre[1] + radius * np.sin(phi)], axis=1)


# -- per-segment NMSE of the switching test ------------------------------------------------------------------------

def test_switching_segments_are_normalised_by_their_own_figure():
    """Three segments with figures of different size and centre (the wind segment's is displaced). Hand values:
    the mean square of a radius-R turn about its centre is R²/2 (mean over both coordinates)."""
    before = _circle(100, 2.0, (0.0, 0.0))  # mean square 2
    wind = _circle(100, 1.0, (10.0, 0.0))  # mean square 0.5, centred 10 m away
    after = _circle(50, 3.0, (0.0, 0.0))  # mean square 4.5
    target = np.concatenate([before, wind, after])
    cmp = np.concatenate([
        before + [0.1, 0.0],  # offset 0.1 m in x: MSE (0.01 + 0) / 2 = 0.005 → 0.005 / 2 = 0.0025
        np.tile([10.0, 0.0], (100, 1)),  # at rest at its figure's centre: MSE = mean square → 1
        0.5 * after,  # half the figure: MSE = 0.25 × 4.5 = 1.125 → 0.25
    ])
    windows = {"before (no wind)": (0, 100), "wind": (100, 200), "after (no wind)": (200, 250)}
    out = segment_errors(cmp, target, windows)
    assert list(out) == list(windows)
    assert [out[k]["steps"] for k in windows] == [100, 100, 50]
    assert [out[k]["mse"] for k in windows] == pytest.approx([0.005, 0.5, 1.125], rel=1e-12)
    assert [out[k]["nmse"] for k in windows] == pytest.approx([0.0025, 1.0, 0.25], rel=1e-12)


def test_switching_segment_uses_only_its_own_steps():
    """A wild excursion outside a window does not reach that window's numbers."""
    target = np.concatenate([_circle(40, 1.0, (0.0, 0.0)), _circle(40, 1.0, (0.0, 0.0))])
    cmp = target.copy()
    cmp[40:] += 100.0  # only the second window is off, by (100, 100): MSE 10⁴, mean square 0.5
    out = segment_errors(cmp, target, {"a": (0, 40), "b": (40, 80)})
    assert out["a"]["mse"] == 0.0 and out["a"]["nmse"] == 0.0
    assert out["b"]["nmse"] == pytest.approx(1e4 / 0.5, rel=1e-12)


@pytest.mark.parametrize("radius, centre, offset, nmse", [
    (2.0, (0.0, 0.0), (0.0, 0.0), 0.0),
    (2.0, (0.0, 0.0), (0.2, 0.0), 0.01),  # MSE (0.04 + 0) / 2 = 0.02, mean square 2
    (1.0, (5.0, -3.0), (0.0, 0.5), 0.25),  # MSE (0 + 0.25) / 2 = 0.125, mean square 0.5
])
def test_phase_locked_nmse_hand_values(radius, centre, offset, nmse):
    target = _circle(64, radius, centre)
    assert phase_locked_nmse(target + offset, target) == pytest.approx(nmse, rel=1e-12, abs=1e-15)


def test_phase_locked_nmse_rest_at_centre_is_one_and_blow_up_is_nan():
    target = _circle(64, 3.0, (1.0, 2.0))
    assert phase_locked_nmse(np.tile([1.0, 2.0], (64, 1)), target) == pytest.approx(1.0, rel=1e-12)
    blown = target.copy()
    blown[7, 0] = np.inf
    assert math.isnan(phase_locked_nmse(blown, target))


# -- REPRODUCTION.md: number format --------------------------------------------------------------------------------

@pytest.mark.parametrize("value, shown", [
    (None, "—"), (0, "0"), (0.0, "0"), (-0.0, "0"),
    (1, "1"), (12, "12"), (0.5, "0.5"), (-0.5, "-0.5"), (1234.5678, "1235"), (0.012344, "0.01234"),
    (0.001, "0.001"), (-0.001, "-0.001"), (0.0009999, "9.999e-04"), (-0.0009999, "-9.999e-04"),
    (9999.4, "9999"), (-9999.4, "-9999"), (1e4, "1.000e+04"), (-1e4, "-1.000e+04"), (123456, "1.235e+05"),
    ("≈ 0.1", "≈ 0.1"), ("8/20", "8/20"), ("*", "\\*"),  # the paper's texts, escaped as data
])
def test_report_number_format(value, shown):
    assert _fmt(value) == shown


@pytest.mark.parametrize("seconds, shown", [
    (0, "0 s"), (4.4, "4 s"), (119.4, "119 s"), (120, "2.0 min"), (612, "10.2 min"), (7199, "120.0 min"),
    (7200, "2.0 h"), (36000, "10.0 h"),
])
def test_report_duration_format(seconds, shown):
    assert _duration(seconds) == shown


# -- REPRODUCTION.md: order ----------------------------------------------------------------------------------------

def _plant(root, directory: str, experiment: str, scale: str, ours: float = 1.0, wall_s: float = 1.0) -> None:
    d = root / directory
    d.mkdir(parents=True)
    data = {"experiment": experiment, "paper_ref": "p", "scale": scale, "seed": 0, "wall_s": wall_s,
            "rows": [{"system": "s", "metric": "m", "unit": "u", "ours": ours, "paper": None}], "claims": [],
            "figures": []}
    (d / "result.json").write_text(json.dumps(data))


# (directory, experiment, scale) planted in no particular order
PLANTED = [
    ("a", "lissajous-closed-loop", "smoke"), ("b", "mnist-pca", "short"), ("c", "mnist-pca", "paper"),
    ("d", "zz-own", "paper"), ("e", "aa-own", "smoke"), ("f", "lissajous-closed-loop", "paper"),
    ("g", "mnist-drawing", "smoke"), ("a2", "mnist-pca", "short"), ("h", "narma-emulation", "short"),
    ("i", "lissajous-closed-loop", "short"),
]
# the paper's order (Fig. 2 MNIST drawing, then its PCA, Fig. 3 NARMA, Fig. 4 Lissajous), then experiments of no
# paper by name; within one experiment paper, short, smoke; then the directory
EXPECTED = ["g", "c", "a2", "b", "h", "f", "i", "a", "e", "d"]


def test_results_in_the_papers_order_then_scale_then_directory(tmp_path):
    for directory, experiment, scale in PLANTED:
        _plant(tmp_path / "runs", directory, experiment, scale)
    found = find_results(tmp_path / "runs")
    assert [p.parent.name for p, _ in found] == EXPECTED


def test_report_page_in_that_order_with_its_numbers(tmp_path):
    for i, (directory, experiment, scale) in enumerate(PLANTED):
        _plant(tmp_path / "runs", directory, experiment, scale, ours=9999.5 + i, wall_s=60.0 * i)
    text = build_report(tmp_path / "runs", tmp_path / "R.md").read_text()
    by_dir = {d: (e, s, i) for i, (d, e, s) in enumerate(PLANTED)}
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert headings == [f"## {by_dir[d][0]} ({by_dir[d][1]}, seed 0)" for d in EXPECTED]
    summary = [line.split(" | ")[0] for line in text.splitlines() if line.startswith("| [")]
    assert summary == [f"| [{by_dir[d][0]}](#{by_dir[d][0]}-{by_dir[d][1]}-seed-0)" for d in EXPECTED]
    sections = dict(zip(EXPECTED, text.split("\n## ")[1:], strict=True))
    # planted: ours = 9999.5 + i, wall time 60 s × i, i the directory's index in PLANTED (hand-formatted below)
    shown = {"a": ("1.000e+04", "0 s"), "b": ("1.000e+04", "60 s"), "c": ("1.000e+04", "2.0 min"),
             "d": ("1.000e+04", "3.0 min"), "e": ("1.000e+04", "4.0 min"), "f": ("1.000e+04", "5.0 min"),
             "g": ("1.001e+04", "6.0 min"), "a2": ("1.001e+04", "7.0 min"), "h": ("1.001e+04", "8.0 min"),
             "i": ("1.001e+04", "9.0 min")}
    for d, (ours, wall) in shown.items():
        assert f"| s | m | {ours} | — | u |" in sections[d] and f"Wall time {wall}." in sections[d], d


def _run(experiment: str, commit: str | None) -> dict:
    return {"experiment": experiment, **({"provenance": {"git_commit": commit}} if commit is not None else {})}


def test_code_versions_name_each_commit_with_its_experiments_and_what_dirty_means():
    runs = [_run("narma-ipc", "def5678-dirty"), _run("mnist-pca", "abc1234"), _run("target-ipc", "abc1234"),
            _run("memory-task", None), _run("mnist-pca", "abc1234")]  # the most used commit is named first
    assert code_versions_lines(runs) == ["", (
        "Code versions: the runs on this page come from 3 versions of the code (the commit each run recorded; its "
        "section names it): `abc1234`: mnist-pca, target-ipc; `def5678-dirty`: narma-ipc; no commit recorded: "
        "memory-task. Runs of different commits differ wherever the code changed between them; rerunning them "
        "from one commit puts them on one version. A commit ending in `-dirty` means the run was made from a "
        "working tree with uncommitted changes: that commit alone does not reproduce it. A run without a commit "
        "recorded none (it ran outside a git checkout, or an older version wrote it).")]


def test_code_versions_say_nothing_when_every_run_is_one_clean_commit_and_speak_of_one_dirty_one():
    assert code_versions_lines([_run("mnist-pca", "abc1234"), _run("target-ipc", "abc1234")]) == []
    dirty = code_versions_lines([_run("mnist-pca", "abc1234-dirty")])
    assert dirty[1].startswith("Code versions: the runs on this page come from 1 version of the code")
    assert "`abc1234-dirty`: mnist-pca" in dirty[1] and "uncommitted changes" in dirty[1]


def test_the_page_shows_its_code_versions_under_the_summary(tmp_path):
    for directory, commit in (("a", "abc1234"), ("b", "def5678")):
        _plant(tmp_path / "runs", directory, "target-ipc" if directory == "a" else "mnist-pca", "paper")
        path = tmp_path / "runs" / directory / "result.json"
        data = json.loads(path.read_text())
        path.write_text(json.dumps({**data, "provenance": {"git_commit": commit, "command": "bptsb reproduce x"}}))
    text = build_report(tmp_path / "runs", tmp_path / "R.md").read_text()
    summary_end = text.index("\n\n", text.index("| [target-ipc]"))
    assert text[summary_end:].lstrip().startswith("Code versions: the runs on this page come from 2 versions")


def test_paper_order_does_not_depend_on_which_experiment_module_was_imported_first():
    """Another test (or a user's script) may import an experiment module before the registry lists them all."""
    import subprocess
    import sys

    code = ("import importlib\n"
            "for m in ('locomotion_headwind', 'narma_ipc', 'lissajous_switching', 'mnist_readout'):\n"
            "    importlib.import_module('bptsb_ros.experiments.' + m)\n"
            "from bptsb_ros.experiments.registry import experiments\n"
            "print(' '.join(experiments()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    # the paper's order, typed from its figures (Fig. 2 MNIST, Fig. 3 time series, Fig. 4 Lissajous, locomotion)
    assert out == ["mnist-drawing", "mnist-pca", "mnist-labelmap", "mnist-specific100", "mnist-readout",
                   "narma-emulation", "narma-ipc", "memory-task", "target-ipc", "msdn-nonlinearity",
                   "lissajous-closed-loop", "lissajous-perturbation", "lissajous-switching", "lissajous-bifurcation",
                   "lissajous-timing", "closed-loop-schemes", "locomotion-closed-loop-20", "locomotion-perturbation",
                   "locomotion-headwind"]
