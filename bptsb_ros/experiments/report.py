"""REPRODUCTION.md: every reproduced experiment's numbers beside the paper's, its claims and its figures.

:func:`build_report` gathers every ``result.json`` under a runs directory and writes one Markdown page: a
summary table (claims ✓ holding, ✗ not holding, ∅ not testable), then per experiment the command, the table
ours-beside-paper, the claims and the figures. Figures that already lie under the page's folder are linked
where they are; others are copied next to the page (``<page stem>_figures/<experiment>-<scale>-seed<N>/``),
so the page and its figures can be committed.

What it writes it owns, and nothing else: the page starts with :data:`PAGE_MARKER` and an existing page
without it is refused; the figures folder is an :class:`~bptsb_ros.files.owned_folder.OwnedFolder`
(its manifest lists the files the report wrote; a folder without one is refused, files added by hand are
kept). A result.json is data: its texts are escaped (:mod:`bptsb_ros.analysis.markdown`), and a figure is
copied only if it is a regular file inside its run directory reached through no symbolic link.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Callable, Iterable
from pathlib import Path, PurePosixPath
from typing import Any

from bptsb_ros.analysis.markdown import md_link_target, md_pre, md_text
from bptsb_ros.analysis.report_guard import sources_line
from bptsb_ros.experiments.result import RESULT_FILE, ResultError, claim_mark, read_result
from bptsb_ros.files.owned_folder import OwnedFolder, OwnedFolderError
from bptsb_ros.files.safe_write import write_text_atomic

#: the first line of every page the report writes (an HTML comment: invisible when rendered)
PAGE_MARKER = "<!-- written by bptsb report: rerunning `bptsb report` replaces this page -->"
TITLE = "# Reproduction of the paper's experiments"
# pages written before the marker existed start with the title and this line (accepted as ours)
_LEGACY_MADE_BY = "Made by `bptsb report` from the `result.json`"
_GIT_SHA = re.compile(r"[0-9a-f]{4,64}")


class ReportError(RuntimeError):
    """The report cannot be written where asked (a page or folder that is not the report's); one line."""


def _fmt(value: Any) -> str:
    """A table cell: — for None, a text escaped, 0, else 4 significant digits: plain in [10⁻³, 10⁴) and
    scientific (``1.235e+05``) outside, and for the values just below 10⁴ that round to it (9999.5 → 1.000e+04,
    not 4-digit ``g``'s ``1e+04``)."""
    if value is None:
        return "—"
    if isinstance(value, str):
        return md_text(value)
    if value == 0:
        return "0"
    plain = f"{value:.4g}"
    if abs(value) >= 1e4 or abs(value) < 1e-3 or "e" in plain:
        return f"{value:.3e}"
    return plain


#: a seed's folder as an aggregate names it (a name, never a path)
_SEED_FOLDER = re.compile(r"seed-\d+")


def find_results(runs_dir: Path) -> list[tuple[Path, dict[str, Any]]]:
    """Every valid result.json under ``runs_dir`` (invalid ones raise ResultError naming the file)."""
    from bptsb_ros.experiments.seed_dirs import in_multi_seed_run

    # a seed's own result of a multi-seed run is part of that run's aggregate, not a page section of its own: known
    # by the run's marker, or (a run copied without it: results and figures only) by the aggregate's seed_runs
    read = [(p, read_result(p)) for p in sorted(runs_dir.rglob(RESULT_FILE)) if not in_multi_seed_run(p.parent)]
    seed_runs = [(p.parent, result.get("seed_runs")) for p, result in read]
    seed_dirs = {run / folder for run, folders in seed_runs if isinstance(folders, dict)
                 for folder in folders.values() if isinstance(folder, str) and _SEED_FOLDER.fullmatch(folder)}
    found = [(p, result) for p, result in read if p.parent not in seed_dirs]
    order = _paper_order()
    scales = {"paper": 0, "short": 1, "smoke": 2}
    found.sort(key=lambda pr: (order.get(pr[1]["experiment"], len(order)), pr[1]["experiment"],
                               scales.get(pr[1]["scale"], 3), str(pr[0])))
    return found


def _paper_order() -> dict[str, int]:
    from bptsb_ros.experiments.registry import experiments

    return {name: i for i, name in enumerate(experiments())}


def missing_experiments(present: Iterable[str]) -> list[str]:
    """The registered experiments (in the paper's order) with no result among ``present``."""
    have = set(present)
    return [name for name in _paper_order() if name not in have]


def claim_counts(claims: list[dict[str, Any]]) -> tuple[int, int, int]:
    """(holding, not holding, not testable) among result.json claims."""
    held = sum(c["holds"] is True for c in claims)
    failed = sum(c["holds"] is False for c in claims)
    return held, failed, len(claims) - held - failed


def _warn(message: str) -> None:
    print(f"bptsb report: warning: {message}", file=sys.stderr)


def build_report(runs_dir: str | Path, out: str | Path, warn: Callable[[str], None] = _warn,
                 check: Callable[[list[dict[str, Any]]], None] | None = None) -> Path:
    """Write the Markdown page ``out`` from the results under ``runs_dir``; returns its path.

    ``check(results)`` runs before anything is written and may refuse the page by raising
    (:mod:`~bptsb_ros.analysis.report_guard`); the page's second line records the results it shows.

    Raises ResultError for a result.json that breaks the schema, ReportError (nothing written) where ``out``
    or its figures folder is not the report's to overwrite; ``warn`` gets one line per figure skipped.
    """
    runs_dir, out = Path(runs_dir), Path(out)
    results = find_results(runs_dir)
    if not results:
        raise ResultError(f"no {RESULT_FILE} under {runs_dir} (run `bptsb reproduce NAME` first)")
    if check is not None:
        check([r for _, r in results])
    _check_page(out)
    try:
        figures = OwnedFolder.open(out.parent / f"{out.stem}_figures")
    except OwnedFolderError as err:
        raise ReportError(str(err)) from None
    lines = [PAGE_MARKER, sources_line(r for _, r in results), TITLE, "",
             "Made by `bptsb report` from the `result.json` of each `bptsb reproduce` run. *ours* is measured by "
             "the command shown; *paper* is the paper's value (— where the paper gives no number). A claim's "
             "verdict is computed from our numbers by the experiment's code, never written by hand: ✓ holds, "
             "✗ does not hold, ∅ not testable (a premise of the claim failed, named in its evidence, so our "
             "numbers say nothing about it either way).", ""]
    if any("seeds" in r for _, r in results):
        lines += [_SEEDS_METHOD, ""]
    lines += ["| experiment | paper | scale | seeds | claims ✓ | ✗ | split | ∅ not testable | wall time |",
              "|---|---|---|---|---|---|---|---|---|"]
    for _, r in results:
        held, failed, split, untestable = verdict_counts(r)
        seeds = f"{len(r['seeds'])} ({_seed_range(r['seeds'])})" if "seeds" in r else f"1 ({r['seed']})"
        lines.append(f"| [{r['experiment']}](#{_anchor(r)}) | {md_text(r['paper_ref'])} | {r['scale']} | "
                     f"{seeds} | {held} | {failed} | {split} | {untestable} | {_wall_text(r, 'table')} |")
    lines += _wall_legend([r for _, r in results])
    lines += code_versions_lines([r for _, r in results])
    missing = missing_experiments(r["experiment"] for _, r in results)
    if missing:
        lines += ["", f"Not on this page (no run under the runs directory): {', '.join(missing)}. "
                  "`bptsb reproduce NAME --scale SCALE` runs one; `bptsb reproduce --list` gives each one's time."]
    copies: dict[str, Path] = {}
    used_dirs: set[str] = set()
    for path, r in results:
        if "seeds" in r:
            lines += _aggregate_lines(r)
        else:
            lines += _single_lines(r)
        dest = _unique_dir(f"{r['experiment']}-{r['scale']}-{_seed_slug(r)}", used_dirs)
        figure_lines = _figure_lines(path.parent, r["figures"], dest, figures.root, out.parent, copies, warn)
        if figure_lines:
            lines += [""] + figure_lines
    try:
        figures.write(copies)
    except OwnedFolderError as err:
        raise ReportError(str(err)) from None
    _write_page(out, "\n".join(lines) + "\n")
    return out


def code_versions_lines(results: list[dict[str, Any]]) -> list[str]:
    """The code versions the page's runs come from, where they are not all one clean commit: each commit (as the
    run recorded it) with its experiments, in the page's order, the most used first; a ``-dirty`` commit (a working
    tree with uncommitted changes) and a run without a commit are said to be what they are. Nothing when every run
    names the same clean commit."""
    by_commit: dict[str, list[str]] = {}
    for r in results:
        commit = str((r.get("provenance") or {}).get("git_commit") or "")
        names = by_commit.setdefault(commit, [])
        if r["experiment"] not in names:
            names.append(r["experiment"])
    if len(by_commit) == 1 and next(iter(by_commit)) and not next(iter(by_commit)).endswith("-dirty"):
        return []
    parts = []
    for commit, names in sorted(by_commit.items(), key=lambda item: -len(item[1])):
        clean = _GIT_SHA.fullmatch(commit.removesuffix("-dirty"))
        label = f"`{commit}`" if clean else (md_text(commit) if commit else "no commit recorded")
        parts.append(f"{label}: {', '.join(names)}")
    text = (f"Code versions: the runs on this page come from {len(by_commit)} "
            f"{'versions' if len(by_commit) > 1 else 'version'} of the code (the commit each run recorded; its "
            f"section names it): {'; '.join(parts)}. Runs of different commits differ wherever the code changed "
            "between them; rerunning them from one commit puts them on one version.")
    if any(commit.endswith("-dirty") for commit in by_commit):
        text += (" A commit ending in `-dirty` means the run was made from a working tree with uncommitted "
                 "changes: that commit alone does not reproduce it.")
    if "" in by_commit:
        text += " A run without a commit recorded none (it ran outside a git checkout, or an older version wrote it)."
    return ["", text]


_SEEDS_METHOD = (
    "One run is one draw, so an experiment is run once per seed (`bptsb reproduce NAME --seeds …`, each seed an "
    "independent draw of every training, evaluation and noise) and each claim is judged in every seed. *k/n*: the "
    "claim holds in k of the n seeds that could test it; the strip shows each seed in order (✓ holds, ✗ fails, "
    "∅ not testable). The verdict over seeds: **✓** when the 95 % Wilson interval of k/n lies above ½, **✗** when "
    "it lies below ½, **split** when it contains ½ (the seeds do not settle it), **∅** when fewer than half the "
    "seeds could test it. Rows give the mean ± sample standard deviation over the seeds with a value, their range "
    "and how many; *in range* says whether the paper's number lies within our seeds' range.")


def verdict_counts(r: dict[str, Any]) -> tuple[int, int, int, int]:
    """(✓, ✗, split, ∅) among a result's claims: an aggregate's verdicts over seeds, or one seed's verdicts."""
    if "seeds" in r:
        verdicts = [c["verdict"] for c in r["claims"]]
        return tuple(verdicts.count(v) for v in ("holds", "fails", "split", "not_testable"))  # type: ignore[return-value]
    held, failed, untestable = claim_counts(r["claims"])
    return held, failed, 0, untestable


def _seed_range(seeds: list[int]) -> str:
    from bptsb_ros.experiments.seed_dirs import format_seeds

    return format_seeds(seeds)


def _seed_slug(r: dict[str, Any]) -> str:
    return f"seeds{_seed_range(r['seeds'])}" if "seeds" in r else f"seed{r['seed']}"


def _strip(per_seed: list[bool | None]) -> str:
    return "".join("✓" if v is True else "✗" if v is False else "∅" for v in per_seed)


def _mean_text(row: dict[str, Any]) -> str:
    """``mean ± sd (min–max, n)`` of an aggregate row; — without values."""
    if row["ours"] is None:
        return "—"
    if row["n"] == 1:
        return f"{_fmt(row['ours'])} (1 seed)"
    return f"{_fmt(row['ours'])} ± {_fmt(row['ours_sd'])} ({_fmt(row['ours_min'])}–{_fmt(row['ours_max'])}, {row['n']})"


def _aggregate_lines(r: dict[str, Any]) -> list[str]:
    from bptsb_ros.experiments.result import verdict_mark

    n = len(r["seeds"])
    lines = ["", f"## {r['experiment']} ({r['scale']}, {n} seeds: {_seed_range(r['seeds'])})", "",
             f"Paper: {md_text(r['paper_ref'])}. Wall time {_wall_text(r, 'text')} for the {n} seeds."]
    lines += _provenance_lines(r.get("provenance") or {})
    lines += _judged_lines(r)
    lines += _settings_lines(r.get("settings") or {})
    if r["rows"]:
        lines += ["", "| system | metric | ours: mean ± sd (range, seeds) | paper | paper in our range | unit |",
                  "|---|---|---|---|---|---|"]
        for row in r["rows"]:
            inside = {True: "yes", False: "no", None: ""}[row.get("paper_in_range")]
            lines.append(f"| {md_text(row['system'])} | {md_text(row['metric'])} | {_mean_text(row)} | "
                         f"{_fmt(row['paper'])} | {inside} | {md_text(row['unit'])} |")
    if r["claims"]:
        lines += ["", "Claims of the paper (verdict over seeds, k/n, each seed in order):", ""]
        for c in r["claims"]:
            k, m = c["holds_in"]
            lines.append(f"- **{verdict_mark(c['verdict'])}** {k}/{m} `{_strip(c['per_seed'])}` "
                         f"{md_text(c['claim'])} — {md_text(c['evidence'])}")
    return lines


def _judged_lines(r: dict[str, Any]) -> list[str]:
    """Which code judged the claims: the aggregate's own record, and the seeds' claim-code digests."""
    judged = r.get("judged") or {}
    details = r.get("details") or {}
    digests = [d for d in details.get("claim_code", []) if d and d != "None"]
    commits = [c for c in details.get("seed_commits", []) if c and c != "None"]
    parts = []
    if len(commits) > 1:
        parts.append(f"the seeds ran at commits {', '.join(commits)}")
    if judged.get("rejudged"):
        parts.append(f"claims judged again from the stored numbers at commit {judged.get('git_commit')}")
    if digests:
        parts.append(f"claim code {', '.join(digests)}")
    return [f"- judged: {md_text('; '.join(parts))}"] if parts else []


def _single_lines(r: dict[str, Any]) -> list[str]:
    lines = ["", f"## {r['experiment']} ({r['scale']}, seed {r['seed']})", "",
             f"Paper: {md_text(r['paper_ref'])}. Wall time {_wall_text(r, 'text')}."]
    lines += _provenance_lines(r.get("provenance") or {})
    lines += _settings_lines(r.get("settings") or {})
    if r["rows"]:
        lines += ["", "| system | metric | ours | paper | unit |", "|---|---|---|---|---|"]
        lines += [f"| {md_text(row['system'])} | {md_text(row['metric'])} | {_fmt(row['ours'])} | "
                  f"{_fmt(row['paper'])} | {md_text(row['unit'])} |" for row in r["rows"]]
    if r["claims"]:
        lines += ["", "Claims of the paper:", ""]
        lines += [f"- {claim_mark(c['holds'])}{':' if c['holds'] is None else ''} {md_text(c['claim'])} — "
                  f"{md_text(c['evidence'])}" for c in r["claims"]]
    return lines


_ABSOLUTE_PATH = re.compile(r"(?<![\w.~-])/(?:[^\s/]+/)*([^\s/]+)")


def portable_command(command: str) -> str:
    """``command`` with every absolute path shortened to ``…/`` and its last component: where the data lay on
    the machine that ran it is no part of how to reproduce it (``--data /srv/x/mnist`` → ``--data …/mnist``)."""
    return _ABSOLUTE_PATH.sub(lambda m: f"…/{m.group(1)}", command)


def _provenance_lines(prov: dict[str, Any]) -> list[str]:
    lines = []
    if prov.get("command"):
        sha = str(prov.get("git_commit") or "")
        commit = f" at commit `{sha}`" if _GIT_SHA.fullmatch(sha) else (f" at commit {md_text(sha)}" if sha else "")
        command = portable_command(str(prov["command"]))
        lines += ["", md_pre(command), "", f"({md_text(prov.get('machine', ''))}{commit}.)"]
    for key, value in prov.items():
        if key == "jobs" and isinstance(value, list):
            lines += [f"- jobs: {md_text(_jobs_line(batch))}" for batch in value]
        elif key == "versions" and isinstance(value, dict):
            lines.append("- versions: " + md_text(", ".join(f"{lib} {ver}" for lib, ver in value.items()
                                                           if ver is not None)))
        elif key == "attempts" and isinstance(value, list):
            lines.append(f"- attempts: {md_text(_attempts_line(value))}")
        elif key not in ("command", "git_commit", "machine", "python"):
            lines.append(f"- {md_text(key)}: {md_text(value)}")
    return lines


def _attempts_line(attempts: list[Any]) -> str:
    """``provenance.attempts`` in words: how many, and each one's wall time (the wall time sums them)."""
    parts = []
    for i, att in enumerate(attempts):
        if not isinstance(att, dict) or not isinstance(att.get("wall_s"), (int, float)):
            parts.append(str(att))
            continue
        note = {"upper": f" (killed; at most: {UPPER_BOUND_WHY})", None: "",
                "lower": " (killed; at least, from the files it wrote)"}[_estimate_kind(attempts, i)]
        parts.append(f"{_duration(att['wall_s'])}{note}")
    return f"{len(attempts)} ({' + '.join(parts)})" if len(attempts) > 1 else (parts[0] if parts else "none")


#: why a killed attempt's estimated time is only an upper bound (:func:`_estimate_kind`); ``--list`` says the same
UPPER_BOUND_WHY = "counted until the run resumed"


def _is_seconds(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _estimate_kind(attempts: list[Any], i: int) -> str | None:
    """What the time of attempt ``i`` is: None when measured (or unreadable), ``"upper"`` when it was estimated for
    a killed attempt and runs (to 1 s) up to the start of the next attempt (the estimate then found no file of its
    own after some point but the next attempt's bookkeeping: earlier versions counted the seeds marker, which a
    resumed ``--seeds`` run rewrites first, so it is only an upper bound), else ``"lower"`` (to the newest file it
    wrote: a lower bound)."""
    att = attempts[i]
    if not isinstance(att, dict) or not att.get("wall_s_estimated") or not _is_seconds(att.get("wall_s")):
        return None
    nxt = attempts[i + 1] if i + 1 < len(attempts) else None
    if not isinstance(nxt, dict) or not all(_is_seconds(v) for v in (att.get("started_unix"), nxt.get("started_unix"))):
        return "lower"
    return "upper" if att["wall_s"] >= nxt["started_unix"] - att["started_unix"] - 1.0 else "lower"


#: how a run's total wall time is marked, by the kinds of estimate among its attempts (:func:`_estimate_kind`)
WALL_MARKS = {"table": {frozenset({"upper"}): "≤ ", frozenset({"lower"}): "≥ ", frozenset({"upper", "lower"}): "~ "},
              "text": {frozenset({"upper"}): "at most ", frozenset({"lower"}): "at least ",
                       frozenset({"upper", "lower"}): "about "}}


def _wall_kinds(r: dict[str, Any]) -> frozenset[str]:
    attempts = (r.get("provenance") or {}).get("attempts")
    if not isinstance(attempts, list):
        return frozenset()
    return frozenset(k for i in range(len(attempts)) if (k := _estimate_kind(attempts, i)) is not None)


def _wall_text(r: dict[str, Any], style: str) -> str:
    """The run's wall time, marked (``style``: ``table`` or ``text``, :data:`WALL_MARKS`) where an attempt's time is
    only a bound: at most where every estimate is an upper bound, at least where every one is a lower bound, about
    where both kinds add up."""
    return f"{WALL_MARKS[style].get(_wall_kinds(r), '')}{_duration(r['wall_s'])}"


def _wall_legend(results: list[dict[str, Any]]) -> list[str]:
    """A line under the summary table explaining the marks its wall times carry (none when none does)."""
    kinds = {_wall_kinds(r) for r in results} - {frozenset()}
    if not kinds:
        return []
    words = {frozenset({"upper"}): f"≤ at most (a killed attempt {UPPER_BOUND_WHY})",
             frozenset({"lower"}): "≥ at least (a killed attempt timed to the newest file it wrote)",
             frozenset({"upper", "lower"}): "~ about (killed attempts, some timed at most, some at least)"}
    return ["", "Wall time: " + "; ".join(words[k] for k in words if k in kinds) + "."]


def _jobs_line(batch: object) -> str:
    """One batch of ``provenance.jobs`` (:class:`bptsb_ros.jobs.runner.RunInfo`) in words; anything else as it is."""
    if not isinstance(batch, dict):
        return str(batch)
    text = (f"{batch.get('what', 'jobs')}: {batch.get('jobs')} on {batch.get('scheduler')} "
            f"({batch.get('workers')} workers, ran in {batch.get('ran_in')} processes")
    if batch.get("reused"):
        text += f", {batch['reused']} reused"
    return text + ")"


def _settings_lines(settings: dict[str, Any]) -> list[str]:
    """One line naming the settings the run used (``epochs = 3, n_train = null``), if it recorded them."""
    if not settings:
        return []
    shown = ", ".join(f"{key} = {_setting_text(value)}" for key, value in settings.items())
    return [f"- settings: {md_text(shown)}"]


def _setting_text(value: Any) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_setting_text(v) for v in value) + "]"
    return "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def _unique_dir(name: str, used: set[str]) -> str:
    """``name``, or ``name-2``, ``name-3``... if an earlier result (same experiment, scale, seed) took it."""
    candidate, n = name, 1
    while candidate in used:
        n += 1
        candidate = f"{name}-{n}"
    used.add(candidate)
    return candidate


def _check_page(out: Path) -> None:
    """Refuse to replace ``out`` unless it is absent or a page this program wrote (its marker line)."""
    if out.is_symlink():
        raise ReportError(f"{out} is a symbolic link; bptsb report does not write through it")
    if not out.exists():
        return
    if not out.is_file():
        raise ReportError(f"{out} exists and is not a file; choose another --out")
    try:
        with out.open(encoding="utf-8", errors="replace") as f:
            head = [f.readline(4096).rstrip("\r\n") for _ in range(3)]
    except OSError as err:
        raise ReportError(f"{out}: unreadable ({err})") from None
    if head[0] != PAGE_MARKER and not (head[0] == TITLE and head[2].startswith(_LEGACY_MADE_BY)):
        raise ReportError(f"{out} exists and was not written by bptsb report (its first line is not "
                          f"{PAGE_MARKER!r}); move it away or choose another --out")


def _write_page(out: Path, text: str) -> None:
    """Write ``out`` atomically (a unique temporary file beside it, then a rename)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, text)


def _anchor(r: dict[str, Any]) -> str:
    """The page anchor of a result's section (GitHub's slug of its heading)."""
    if "seeds" in r:
        text = f"{r['experiment']} ({r['scale']}, {len(r['seeds'])} seeds: {_seed_range(r['seeds'])})"
    else:
        text = f"{r['experiment']} ({r['scale']}, seed {r['seed']})"
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def safe_figure(run_dir: Path, rel: str) -> tuple[Path | None, str]:
    """The figure ``rel`` of ``run_dir`` if it may be shown: a regular file inside ``run_dir`` reached
    through no symbolic link. Returns (path, "") or (None, why not)."""
    path = run_dir
    for part in PurePosixPath(rel).parts:
        path = path / part
        if path.is_symlink():
            return None, f"{path} is a symbolic link"
    if not path.resolve().is_relative_to(run_dir.resolve()):
        return None, f"{path} lies outside its run directory"
    if not path.is_file():
        return None, f"{path} is missing"
    return path, ""


def _figure_lines(run_dir: Path, rels: list[str], dest: str, fig_root: Path, page_dir: Path,
                  copies: dict[str, Path], warn: Callable[[str], None]) -> list[str]:
    """The page's lines for one result's figures; fills ``copies`` (path in the figures folder → source).
    A figure's PDF sibling (what :func:`bptsb_ros.analysis.style.save` writes beside each PNG) travels with it,
    under the same checks, and is linked after the image; a figure without one is shown alone."""
    lines = []
    for rel in rels:
        src, why = safe_figure(run_dir, rel)
        if src is None:
            if "missing" not in why:
                warn(f"figure not copied: {why}")
            lines.append(f"- figure {md_text(rel)}: not shown ({md_text(why.removeprefix(str(run_dir) + os.sep))})")
            continue
        target = _place(src, rel, dest, fig_root, page_dir, copies)
        line = f"![{md_text(PurePosixPath(rel).stem)}]({md_link_target(target)})"
        pdf_rel = str(PurePosixPath(rel).with_suffix(".pdf"))
        if PurePosixPath(rel).suffix.lower() != ".pdf" and pdf_rel not in rels:
            pdf, _ = safe_figure(run_dir, pdf_rel)
            if pdf is not None:
                line += f" ([PDF]({md_link_target(_place(pdf, pdf_rel, dest, fig_root, page_dir, copies))}))"
        lines.append(line)
    return lines


def _place(src: Path, rel: str, dest: str, fig_root: Path, page_dir: Path, copies: dict[str, Path]) -> str:
    """The page's link (POSIX, relative to the page) to the figure ``src``: where it lies when already beside the
    page, else its copy in the figures folder (entered in ``copies``)."""
    if src.resolve().is_relative_to(page_dir.resolve()):  # already beside the page: link it where it is
        return Path(os.path.relpath(src, page_dir)).as_posix()
    flat = PurePosixPath(rel.replace("/", "_"))
    name, n = f"{dest}/{flat}", 1
    while name in copies:  # "a/b.png" and "a_b.png" of one run
        n += 1
        name = f"{dest}/{flat.stem}-{n}{flat.suffix}"
    copies[name] = src
    return Path(os.path.relpath(fig_root / name, page_dir)).as_posix()
