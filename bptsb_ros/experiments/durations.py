"""How long each experiment takes at each scale, and the table ``bptsb reproduce --list`` prints.

The times are measurements, kept as data in ``durations.yaml`` beside this module (experiment name → scale →
``seconds``, the run's wall time on 2 CPU cores, and ``measured``, when and how), not in the experiments' code;
a new measurement replaces an entry there. Each entry also says how many seeds its paper-scale verdicts are drawn
from (``seeds: {n: N}``) and, once that multi-seed run is made, its wall time (``seconds``, ``measured``); until then
the table estimates it from the one-seed time (:func:`seeds_seconds`).
"""

from __future__ import annotations

import importlib.resources
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bptsb_ros.experiments.result import SCALES

DURATIONS_FILE = "durations.yaml"


class DurationsError(ValueError):
    """``durations.yaml`` is malformed; one line naming the entry."""


@dataclass(frozen=True)
class Duration:
    """One measured wall time of ``bptsb reproduce NAME --scale SCALE``."""

    seconds: float
    """the run's wall time [s]"""
    measured: str
    """when and how it was measured"""


@dataclass(frozen=True)
class SeedsDuration:
    """The paper-scale run over seeds: how many, and its wall time once measured."""

    n: int
    """the number of seeds the paper-scale verdicts are drawn from"""
    measured: Duration | None = None
    """the wall time of ``bptsb reproduce NAME --scale paper --seeds 0-(n-1) --workers 2 ARGS``; None: not yet run"""
    args: str = ""
    """further ``bptsb reproduce`` arguments of that run (e.g. ``--set n_seeds=1``: one training per seed where the
    one-seed paper run trains several)"""
    share: float = 1.0
    """the part of the one-seed paper run's work one seed of this run does (0.2: one of its five trainings)"""
    upper_bound: bool = False
    """the measured time is only an upper bound (an attempt killed before it recorded its time was counted until
    the next attempt began; ``bptsb report`` says the same of the run)"""


#: the most seeds an entry may plan (a bound a user would never need to exceed)
MAX_SEEDS = 1000


def _duration(entry: Any, where: str) -> Duration:
    seconds = entry.get("seconds") if isinstance(entry, dict) else None
    measured = entry.get("measured") if isinstance(entry, dict) else None
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds) \
            or seconds <= 0:
        raise DurationsError(f"{DURATIONS_FILE}: {where}.seconds must be a positive number of seconds")
    if not isinstance(measured, str) or not measured.strip():
        raise DurationsError(f"{DURATIONS_FILE}: {where}.measured must say when and how")
    return Duration(float(seconds), measured.strip())


def _seeds(entry: Any, where: str) -> SeedsDuration:
    n = entry.get("n") if isinstance(entry, dict) else None
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_SEEDS:
        raise DurationsError(f"{DURATIONS_FILE}: {where}.n must be a whole number of seeds in 1..{MAX_SEEDS}")
    if set(entry) - {"n", "seconds", "measured", "args", "share", "upper_bound"}:
        raise DurationsError(f"{DURATIONS_FILE}: {where} may give only n, seconds, measured, args, share and "
                             "upper_bound")
    args, share, bound = entry.get("args", ""), entry.get("share", 1.0), entry.get("upper_bound", False)
    if not isinstance(args, str):
        raise DurationsError(f"{DURATIONS_FILE}: {where}.args must be the further reproduce arguments as text")
    if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 < share <= 1:
        raise DurationsError(f"{DURATIONS_FILE}: {where}.share must be a number in (0, 1]")
    measured = _duration(entry, where) if {"seconds", "measured"} & set(entry) else None
    if not isinstance(bound, bool) or (bound and measured is None):
        raise DurationsError(f"{DURATIONS_FILE}: {where}.upper_bound must be true or false, and true only beside a "
                             "measured time")
    return SeedsDuration(n, measured, args.strip(), float(share), bound)


def parse_durations(data: Any) -> tuple[dict[str, dict[str, Duration]], dict[str, SeedsDuration]]:
    """Validate the mapping read from ``durations.yaml``: every entry names the three scales, each with a positive
    finite ``seconds`` and a non-empty ``measured`` text, and ``seeds`` (``n``, and ``seconds`` with ``measured``
    once the multi-seed run is made); DurationsError names the first bad entry. Returns (experiment → scale →
    time, experiment → seeds)."""
    if not isinstance(data, dict):
        raise DurationsError(f"{DURATIONS_FILE} must map experiment names to scales")
    table: dict[str, dict[str, Duration]] = {}
    seeds: dict[str, SeedsDuration] = {}
    for name, scales in data.items():
        if not isinstance(scales, dict) or set(scales) != {*SCALES, "seeds"}:
            raise DurationsError(f"{DURATIONS_FILE}: {name} must give exactly the scales {', '.join(SCALES)} "
                                 f"and seeds")
        table[str(name)] = {scale: _duration(scales[scale], f"{name}.{scale}") for scale in SCALES}
        seeds[str(name)] = _seeds(scales["seeds"], f"{name}.seeds")
    return table, seeds


def _packaged() -> Any:
    import yaml

    text = (importlib.resources.files("bptsb_ros.experiments") / DURATIONS_FILE).read_text(encoding="utf-8")
    return yaml.safe_load(text)


def durations() -> dict[str, dict[str, Duration]]:
    """The packaged measurements: experiment name → scale → :class:`Duration`."""
    return parse_durations(_packaged())[0]


def seed_plan() -> dict[str, SeedsDuration]:
    """The packaged seed counts of the paper-scale runs, with their wall times where measured."""
    return parse_durations(_packaged())[1]


def seeds_seconds(one_seed: float, seeds: SeedsDuration, parallel: bool, workers: int = 2) -> tuple[float, bool]:
    """The wall time [s] of the paper-scale run over ``seeds.n`` seeds, and whether it was measured: the measurement
    where there is one, else an estimate from the one-seed time — ``n`` × it for an experiment that spreads its own
    trainings over the workers (``parallel``), ``n / workers`` × it for one whose seeds run side by side, each
    times the seeds' ``share`` of the one-seed run's work."""
    if seeds.measured is not None:
        return seeds.measured.seconds, True
    return one_seed * seeds.share * seeds.n / (1 if parallel else workers), False


def format_seconds(seconds: float) -> str:
    """A wall time for the table: ``"8 s"`` below a minute, ``"4.2 min"`` below an hour, ``"2.3 h"`` above."""
    if seconds < 59.5:
        return f"{seconds:.0f} s"
    if seconds < 3570:
        return f"{seconds / 60:.1f} min" if seconds < 600 else f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def reproduce_table(rows: Iterable[tuple[str, str, bool]], times: dict[str, dict[str, Duration]],
                    seeds: dict[str, SeedsDuration] | None = None) -> list[str]:
    """The lines of ``bptsb reproduce --list``: one row per (experiment, paper figure, parallel) with the measured
    time of each scale (``—`` where none is recorded), the paper run's seed count and its time over those seeds
    (``≈`` marks an estimate, :func:`seeds_seconds`; ``≤`` a measured upper bound), then the total over all
    experiments; columns padded to their widest cell, the paper figure last and whole."""
    seeds = seeds or {}
    head = ("experiment", *SCALES, "seeds", "paper × seeds", "paper figure")
    body = []
    total, estimated, bounded = 0.0, False, False
    for name, ref, parallel in rows:
        cells = [format_seconds(times[name][s].seconds) if name in times else "—" for s in SCALES]
        if name in seeds and name in times:
            seconds, measured = seeds_seconds(times[name]["paper"].seconds, seeds[name], parallel)
            total += seconds
            estimated |= not measured
            bounded |= seeds[name].upper_bound
            mark = "≤ " if seeds[name].upper_bound else "" if measured else "≈ "
            cells += [str(seeds[name].n), mark + format_seconds(seconds)]
        else:
            cells += ["—", "—"]
        body.append((name, *cells, ref))
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]

    def line(cells: tuple[str, ...]) -> str:
        text = [c.ljust(w) if i in (0, len(cells) - 1) else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))]
        return "  ".join(text).rstrip()

    lines = [line(head), line(tuple("-" * w for w in widths)), *map(line, body)]
    if seeds:
        notes = [*(["≈: estimated from the one-seed time"] if estimated else []),
                 *(["≤: at most, a killed attempt counted until the run resumed"] if bounded else [])]
        prefix = "≈ " if estimated else "≤ " if bounded else ""
        lines.append(f"all experiments at paper scale over their seeds: {prefix}"
                     f"{format_seconds(total)} on 2 cores" + (f" ({'; '.join(notes)})" if notes else ""))
    return lines
