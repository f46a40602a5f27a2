"""REPRODUCTION.md: every reproduced experiment's numbers beside the paper's, its claims and its figures.

:func:`build_report` gathers every ``result.json`` under a runs directory and writes one Markdown page: a
summary table, then per experiment the command, the table ours-beside-paper, the claims with ✓/✗ and the
figures. Figures that already lie under the page's folder are linked where they are; others are copied next
to the page (``<page stem>_figures/<experiment>-<scale>/``), so the page and its figures can be committed.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from bptsb_ros.experiments.result import RESULT_FILE, ResultError, read_result


def _fmt(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, str):
        return value
    if value == 0:
        return "0"
    if abs(value) >= 1e4 or abs(value) < 1e-3:
        return f"{value:.3e}"
    return f"{value:.4g}"


def find_results(runs_dir: Path) -> list[tuple[Path, dict[str, Any]]]:
    """Every valid result.json under ``runs_dir`` (invalid ones raise ResultError naming the file)."""
    found = [(p, read_result(p)) for p in sorted(runs_dir.rglob(RESULT_FILE))]
    order = _paper_order()
    scales = {"paper": 0, "short": 1, "smoke": 2}
    found.sort(key=lambda pr: (order.get(pr[1]["experiment"], len(order)), pr[1]["experiment"],
                               scales.get(pr[1]["scale"], 3), str(pr[0])))
    return found


def _paper_order() -> dict[str, int]:
    from bptsb_ros.experiments.registry import experiments

    return {name: i for i, name in enumerate(experiments())}


def build_report(runs_dir: str | Path, out: str | Path) -> Path:
    """Write the Markdown page ``out`` from the results under ``runs_dir``; returns its path."""
    runs_dir, out = Path(runs_dir), Path(out)
    results = find_results(runs_dir)
    if not results:
        raise ResultError(f"no {RESULT_FILE} under {runs_dir} (run `bptsb reproduce NAME` first)")
    fig_root = out.parent / f"{out.stem}_figures"
    if fig_root.exists():
        shutil.rmtree(fig_root)
    lines = ["# Reproduction of the paper's experiments", "",
             "Made by `bptsb report` from the `result.json` of each `bptsb reproduce` run. *ours* is measured by "
             "the command shown; *paper* is the paper's value (— where the paper gives no number). A claim's ✓/✗ "
             "is computed from our numbers by the experiment's code, never written by hand.", "",
             "| experiment | paper | scale | seed | claims holding | wall time |", "|---|---|---|---|---|---|"]
    for _, r in results:
        held = sum(c["holds"] for c in r["claims"])
        lines.append(f"| [{r['experiment']}](#{_anchor(r)}) | {r['paper_ref']} | {r['scale']} | {r['seed']} | "
                     f"{held}/{len(r['claims'])} | {_duration(r['wall_s'])} |")
    for path, r in results:
        lines += ["", f"## {r['experiment']} ({r['scale']}, seed {r['seed']})", "",
                  f"Paper: {r['paper_ref']}. Wall time {_duration(r['wall_s'])}."]
        prov = r.get("provenance") or {}
        if prov.get("command"):
            commit = f" at commit `{prov['git_commit']}`" if prov.get("git_commit") else ""
            lines += ["", f"```\n{prov['command']}\n```", f"({prov.get('machine', '')}{commit}.)"]
        for key, value in prov.items():
            if key not in ("command", "git_commit", "machine", "python"):
                lines.append(f"- {key}: {value}")
        if r["rows"]:
            lines += ["", "| system | metric | ours | paper | unit |", "|---|---|---|---|---|"]
            lines += [f"| {row['system']} | {row['metric']} | {_fmt(row['ours'])} | {_fmt(row['paper'])} | "
                      f"{row['unit']} |" for row in r["rows"]]
        if r["claims"]:
            lines += ["", "Claims of the paper:", ""]
            lines += [f"- {'✓' if c['holds'] else '✗'} {c['claim']} — {c['evidence']}" for c in r["claims"]]
        figs = _copy_figures(path.parent, r, fig_root, out.parent)
        if figs:
            lines += [""] + [f"![{Path(f).stem}]({f})" for f in figs]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out


def _anchor(r: dict[str, Any]) -> str:
    return f"{r['experiment']}-{r['scale']}-seed-{r['seed']}".lower()


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def _copy_figures(run_dir: Path, r: dict[str, Any], fig_root: Path, page_dir: Path) -> list[str]:
    dest = fig_root / f"{r['experiment']}-{r['scale']}-seed{r['seed']}"
    links = []
    for rel in r["figures"]:
        src = run_dir / rel
        if not src.is_file():
            links.append(f"{rel} (missing)")
            continue
        if src.resolve().is_relative_to(page_dir.resolve()):  # already beside the page: link it where it is
            links.append(os.path.relpath(src, page_dir))
            continue
        target = dest / rel.replace(os.sep, "_")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target)
        links.append(os.path.relpath(target, page_dir))
    return links
