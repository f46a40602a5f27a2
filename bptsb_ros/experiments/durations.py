"""How long each experiment takes at each scale, and the table ``bptsb reproduce --list`` prints.

The times are measurements, kept as data in ``durations.yaml`` beside this module (experiment name → scale →
``seconds``, the run's wall time on 2 CPU cores, and ``measured``, when and how), not in the experiments' code;
a new measurement replaces an entry there.
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


def parse_durations(data: Any) -> dict[str, dict[str, Duration]]:
    """Validate the mapping read from ``durations.yaml``: every entry names the three scales, each with a positive
    finite ``seconds`` and a non-empty ``measured`` text; DurationsError names the first bad entry."""
    if not isinstance(data, dict):
        raise DurationsError(f"{DURATIONS_FILE} must map experiment names to scales")
    table: dict[str, dict[str, Duration]] = {}
    for name, scales in data.items():
        if not isinstance(scales, dict) or set(scales) != set(SCALES):
            raise DurationsError(f"{DURATIONS_FILE}: {name} must give exactly the scales {', '.join(SCALES)}")
        row = {}
        for scale in SCALES:
            entry = scales[scale]
            seconds = entry.get("seconds") if isinstance(entry, dict) else None
            measured = entry.get("measured") if isinstance(entry, dict) else None
            if isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not math.isfinite(seconds) \
                    or seconds <= 0:
                raise DurationsError(f"{DURATIONS_FILE}: {name}.{scale}.seconds must be a positive number of seconds")
            if not isinstance(measured, str) or not measured.strip():
                raise DurationsError(f"{DURATIONS_FILE}: {name}.{scale}.measured must say when and how")
            row[scale] = Duration(float(seconds), measured.strip())
        table[str(name)] = row
    return table


def durations() -> dict[str, dict[str, Duration]]:
    """The packaged measurements: experiment name → scale → :class:`Duration`."""
    import yaml

    text = (importlib.resources.files("bptsb_ros.experiments") / DURATIONS_FILE).read_text(encoding="utf-8")
    return parse_durations(yaml.safe_load(text))


def format_seconds(seconds: float) -> str:
    """A wall time for the table: ``"8 s"`` below a minute, ``"4.2 min"`` below an hour, ``"2.3 h"`` above."""
    if seconds < 59.5:
        return f"{seconds:.0f} s"
    if seconds < 3570:
        return f"{seconds / 60:.1f} min" if seconds < 600 else f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def reproduce_table(rows: Iterable[tuple[str, str]], times: dict[str, dict[str, Duration]]) -> list[str]:
    """The lines of ``bptsb reproduce --list``: one row per (experiment, paper figure) with the measured time of each
    scale (``—`` where none is recorded); columns padded to their widest cell, the paper figure last and whole."""
    head = ("experiment", *SCALES, "paper figure")
    body = [(name, *(format_seconds(times[name][s].seconds) if name in times else "—" for s in SCALES), ref)
            for name, ref in rows]
    widths = [max(len(r[i]) for r in [head, *body]) for i in range(len(head))]

    def line(cells: tuple[str, ...]) -> str:
        text = [c.ljust(w) if i in (0, len(cells) - 1) else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))]
        return "  ".join(text).rstrip()

    return [line(head), line(tuple("-" * w for w in widths)), *map(line, body)]
