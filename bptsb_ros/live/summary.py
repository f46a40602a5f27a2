"""The live body's run summary as text and as a file (ROS-free): :func:`summary_text` for the log at the end of a
run, :func:`write_summary` for ``summary_path`` (JSON), from :meth:`~bptsb_ros.live.body_core.BodyCore.summary`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bptsb_ros.files.safe_write import write_atomic


def write_summary(path: str | Path, summary: Mapping[str, Any]) -> None:
    """Write the run summary as JSON (parent folders created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps(summary, indent=2) + "\n")


def summary_text(summary: Mapping[str, Any]) -> str:
    """The run summary as a few readable lines: one per group of :data:`SUMMARY_GROUPS` (timing series, commands
    by source, wind), the rest on a first "run" line; floats with 4 significant digits. Rejection counters that are
    0 are left out (``rejected=0`` when all of a group are; the JSON summary keeps every counter); every other
    key appears exactly once."""
    def fmt(value: Any) -> str:
        if isinstance(value, dict):
            return "{" + ", ".join(f"{k} {v}" for k, v in value.items()) + "}"
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    lines: dict[str, list[str]] = {"run": []}
    quiet: set[str] = set()
    for key, value in summary.items():
        prefix = next((pre for pre in SUMMARY_GROUPS if key.startswith(pre)), "")
        label = SUMMARY_GROUPS[prefix] if prefix else "run"
        item = key[len(prefix):]
        lines.setdefault(label, [])
        if prefix and item.startswith("rejected_") and value == 0:
            quiet.add(label)
            continue
        lines[label].append(f"{item}={fmt(value)}")
    for label in quiet:
        if not any(item.startswith("rejected_") for item in lines[label]):
            lines[label].append("rejected=0")
    width = max(map(len, lines))
    return "\n".join(f"  {label:<{width}}  {', '.join(items)}" for label, items in lines.items() if items)


#: summary key prefix -> line label of :func:`summary_text`
SUMMARY_GROUPS = {"jitter_ms_": "jitter [ms]", "compute_ms_": "compute [ms]",
                  "command_latency_ms_": "command latency [ms]", "phase_ms_": "per step [ms]",
                  "command_age_steps_": "command age [steps]",
                  "rest_length_": "rest-length commands", "force_": "force commands", "wind_": "wind",
                  "perturbation_": "perturbations", "reset_": "resets"}


def brain_problem(summary: Mapping[str, Any]) -> str:
    """Why a finished run does not count ('' when it does): steps ran on the safe command because an awaited brain
    was silent (``silent_brain_steps`` of the summary: steps per source) — the loop ran without its brain, so the
    launchers fail it. One line naming the sources, the silent steps and the run's steps."""
    silent = summary.get("silent_brain_steps")
    if not isinstance(silent, Mapping):
        return ""
    bad = {s: n for s, n in silent.items() if isinstance(n, int) and n > 0}
    if not bad:
        return ""
    counts = ", ".join(f"{s} silent on {n}" for s, n in bad.items())
    return (f"body_sim ran on the safe command for lack of its brain ({counts} of steps 0..{summary.get('steps', '?')})"
            ": the loop did not run as launched")
