"""What ``bptsb report`` may replace: a results page is never replaced by one made from other runs.

A page the report writes records the results it was made from, one key per run of one seed
(``experiment/scale/seed``; an aggregate over seeds gives one per seed), in an HTML comment on its second line
(:func:`sources_line`). Writing a page over an existing one is allowed only if every result the old page shows
is among the new page's results (:func:`check_replace`), so a page of paper-scale runs is never replaced by one
of a single smoke run; ``--force`` replaces it all the same. Pages written before the comment existed are read
by their section headings (``## name (scale, seed N)``, ``## name (scale, 5 seeds: 0-4)``). A page shows one
scale unless it is asked to mix them (:func:`check_scales`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

SOURCES_PREFIX = "<!-- bptsb report results: "
SOURCES_SUFFIX = " -->"
_KEY = re.compile(r"[a-z0-9][a-z0-9_-]*/[a-z]+/-?\d+")
_LEGACY_HEADING = re.compile(r"^## ([a-z0-9][a-z0-9_-]*) \(([a-z]+), (?:seed (-?\d+)|\d+ seeds: ([\d,-]+))\)\s*$",
                             re.MULTILINE)
#: most seeds one heading's range may name (a range is data read from a page)
MAX_HEADING_SEEDS = 10_000
#: how much of an existing page is read for its record [characters]
MAX_PAGE_CHARS = 4 << 20


class ReplaceRefused(RuntimeError):
    """The report would replace a page made from other runs, or mix scales; one line saying what to do."""


def result_keys(result: dict[str, Any]) -> set[str]:
    """``experiment/scale/seed`` of one result.json: one key, or one per seed of an aggregate over seeds."""
    seeds = result["seeds"] if "seeds" in result else [result["seed"]]
    return {f"{result['experiment']}/{result['scale']}/{seed}" for seed in seeds}


def _keys(results: Iterable[dict[str, Any]]) -> set[str]:
    return {key for r in results for key in result_keys(r)}


def sources_line(results: Iterable[dict[str, Any]]) -> str:
    """The comment line that records a page's results (sorted keys, space-separated)."""
    return SOURCES_PREFIX + " ".join(sorted(_keys(results))) + SOURCES_SUFFIX


def page_sources(text: str) -> set[str]:
    """The results an existing page was made from: its sources comment, else its legacy section headings."""
    for line in text.splitlines()[:5]:
        if line.startswith(SOURCES_PREFIX) and line.endswith(SOURCES_SUFFIX):
            keys = line[len(SOURCES_PREFIX):-len(SOURCES_SUFFIX)].split()
            return {k for k in keys if _KEY.fullmatch(k)}
    keys = set()
    for name, scale, seed, seeds in _LEGACY_HEADING.findall(text):
        keys |= {f"{name}/{scale}/{s}" for s in ([seed] if seed else _seed_list(seeds))}
    return keys


def _seed_list(text: str) -> list[str]:
    """The seeds of a heading's range (``0-4,7``, as ``format_seeds`` writes it); none if it is not one."""
    out: list[str] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        if not lo.isdigit() or (hi and not hi.isdigit()):
            return []
        first, last = int(lo), int(hi or lo)
        if last < first or len(out) + last - first >= MAX_HEADING_SEEDS:
            return []
        out += [str(s) for s in range(first, last + 1)]
    return out


def check_replace(out: Path, results: Iterable[dict[str, Any]], *, force: bool) -> None:
    """Refuse (ReplaceRefused) to write the page ``out`` over an existing one that shows results the new page would
    not have, unless ``force``. An absent page, or one that is not a file, is left to the report's own checks."""
    if force or out.is_symlink() or not out.is_file():
        return
    try:
        with out.open(encoding="utf-8", errors="replace") as f:
            old = page_sources(f.read(MAX_PAGE_CHARS))
    except OSError:
        return  # unreadable: the report's own check of the page says so
    lost = sorted(old - _keys(results))
    if lost:
        shown = ", ".join(lost[:3]) + (f" and {len(lost) - 3} more" if len(lost) > 3 else "")
        raise ReplaceRefused(f"{out} shows results that are not under this runs directory ({shown}): it was made "
                             "from other runs; choose another --out, or pass --force to replace it")


def check_scales(results: Iterable[dict[str, Any]], *, mix: bool) -> None:
    """Refuse (ReplaceRefused) results of more than one scale on one page, unless ``mix``."""
    scales = sorted({r["scale"] for r in results})
    if len(scales) > 1 and not mix:
        raise ReplaceRefused(f"the runs directory holds results of the scales {', '.join(scales)}: a page shows one "
                             "scale; point at a folder of one scale, or pass --mix-scales")
