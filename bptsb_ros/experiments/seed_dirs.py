"""The folders of a multi-seed run and the ``--seeds`` text: what the registry, the report and the runner need to
know about seeds without running any (:mod:`~bptsb_ros.experiments.seeds` runs and aggregates them).

A multi-seed run ``OUT`` holds :data:`SEEDS_MARKER` and one folder per seed, ``OUT/seed-N``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from bptsb_ros.experiments.result import MAX_SEEDS

#: written into a multi-seed run's directory: what the run is (experiment, scale, settings), for --resume
SEEDS_MARKER = ".bptsb-seeds.json"
#: the largest seed accepted (seeds derive further seeds, e.g. 1000 · seed + agent for the locomotion agents)
MAX_SEED = 1_000_000
_RANGE = re.compile(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?")


class SeedsError(ValueError):
    """A seeds list that cannot be read, or a multi-seed run that cannot go on; one line for the user."""


def seed_dir_name(seed: int) -> str:
    """The folder of seed ``seed`` inside a multi-seed run: ``seed-N``."""
    return f"seed-{seed}"


def in_multi_seed_run(out_dir: Path) -> bool:
    """``out_dir`` is a seed's folder (``seed-N``) inside a multi-seed run."""
    return bool(re.fullmatch(r"seed-\d+", out_dir.name)) and (out_dir.parent / SEEDS_MARKER).is_file()


def sibling_run_dirs(out_dir: Path) -> list[Path]:
    """The runs beside ``out_dir`` that may share trained systems with it: for a seed's folder of a multi-seed run,
    the same seed's folder of every other run beside that run (``OUT/../*/seed-N``); else every directory beside
    ``out_dir`` (``OUT/../*``). Whether one is a run, and whose, is for the reader to check."""
    here = Path(out_dir)
    try:
        if in_multi_seed_run(here):
            return [p / here.name for p in sorted(here.parent.parent.iterdir())
                    if p != here.parent and p.is_dir() and (p / here.name).is_dir()]
        return [p for p in sorted(here.parent.iterdir()) if p != here and p.is_dir()]
    except OSError:
        return []


def parse_seeds(text: str) -> list[int]:
    """``"0-9"``, ``"0,3,5"`` or ``"0-4,7"`` → the seeds, in the order given, each once (SeedsError otherwise)."""
    if not isinstance(text, str) or not text.strip():
        raise SeedsError("--seeds needs seeds like 0-9 or 0,3,5")
    seeds: list[int] = []
    for part in text.split(","):
        m = _RANGE.fullmatch(part)
        if not m:
            raise SeedsError(f"--seeds: {part.strip()[:40]!r} is not a seed or a range like 0-9")
        lo = int(m.group(1))
        hi = int(m.group(2)) if m.group(2) is not None else lo
        if hi < lo:
            raise SeedsError(f"--seeds: the range {lo}-{hi} runs backwards")
        if hi > MAX_SEED:
            raise SeedsError(f"--seeds: seeds go up to {MAX_SEED}, got {hi}")
        if len(seeds) + hi - lo + 1 > MAX_SEEDS:
            raise SeedsError(f"--seeds: at most {MAX_SEEDS} seeds")
        seeds.extend(range(lo, hi + 1))
    if len(set(seeds)) != len(seeds):
        dup = next(s for s in seeds if seeds.count(s) > 1)
        raise SeedsError(f"--seeds: seed {dup} is listed twice")
    return seeds


def format_seeds(seeds: Sequence[int]) -> str:
    """The shortest ``--seeds`` text for ``seeds`` (``[0, 1, 2, 5]`` → ``"0-2,5"``)."""
    parts, i = [], 0
    seeds = list(seeds)
    while i < len(seeds):
        j = i
        while j + 1 < len(seeds) and seeds[j + 1] == seeds[j] + 1:
            j += 1
        parts.append(str(seeds[i]) if i == j else f"{seeds[i]}-{seeds[j]}")
        i = j + 1
    return ",".join(parts)
