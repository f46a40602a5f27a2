"""The record of one reproduced paper experiment: ``result.json``.

Schema (every experiment writes exactly this, plus the optional ``details`` and ``provenance``)::

    {"experiment": str, "paper_ref": str, "scale": "smoke"|"short"|"paper", "seed": int, "wall_s": float,
     "rows":   [{"system": str, "metric": str, "unit": str, "ours": float|null, "paper": float|str|null}],
     "claims": [{"claim": str, "holds": bool, "evidence": str}],
     "figures": [str],            # paths relative to the run directory
     "details": {...},            # optional: per-seed values, settings, anything a reader may want
     "provenance": {...}}         # optional: command, package version, git commit, split of the data

``claims[].holds`` is computed by the experiment from its own numbers; :class:`Claim` refuses anything
but a real boolean so that a string or a hand-written ``"yes"`` cannot slip in.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

SCALES = ("smoke", "short", "paper")
RESULT_FILE = "result.json"


class ResultError(ValueError):
    """A result.json that does not follow the schema; the message names the offending field."""


@dataclass
class Row:
    """One number of ours beside the paper's. ``paper`` is the paper's value, a short text where the paper
    gives a range or a qualitative value, or None where the paper reports no number."""

    system: str
    metric: str
    unit: str
    ours: float | None
    paper: float | str | None = None


@dataclass
class Claim:
    """A qualitative statement of the paper and whether our numbers support it."""

    claim: str
    holds: bool
    evidence: str

    def __post_init__(self) -> None:
        if isinstance(self.holds, np.bool_):
            self.holds = bool(self.holds)
        if not isinstance(self.holds, bool):
            raise ResultError(f"claim {self.claim!r}: holds must be a computed bool, got {type(self.holds).__name__}")


@dataclass
class ExperimentResult:
    experiment: str
    paper_ref: str
    scale: str
    seed: int
    wall_s: float = 0.0
    rows: list[Row] = field(default_factory=list)
    claims: list[Claim] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["rows"] = [{**r, "ours": _number(r["ours"])} for r in data["rows"]]
        data["details"] = _plain(data["details"])
        validate_result(data)
        return data


def _number(value: Any) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _plain(value: Any) -> Any:
    """numpy scalars/arrays and tuples → JSON-serialisable Python values (NaN/inf → None)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.integer, int)):
        return int(value)
    if isinstance(value, (np.floating, float)):
        return _number(value)
    return value


_TOP = {"experiment": str, "paper_ref": str, "scale": str, "seed": int, "wall_s": (int, float), "rows": list,
        "claims": list, "figures": list}
_ROW = {"system": str, "metric": str, "unit": str}
_CLAIM = {"claim": str, "holds": bool, "evidence": str}


def validate_result(data: Any, source: str = "result") -> None:
    """Raise :class:`ResultError` unless ``data`` follows the result.json schema."""
    if not isinstance(data, dict):
        raise ResultError(f"{source}: must be a JSON object, got {type(data).__name__}")
    for key, kind in _TOP.items():
        if key not in data:
            raise ResultError(f"{source}: missing key {key!r}")
        if not isinstance(data[key], kind) or (kind is int and isinstance(data[key], bool)):
            raise ResultError(f"{source}: {key} has the wrong type ({type(data[key]).__name__})")
    if data["scale"] not in SCALES:
        raise ResultError(f"{source}: scale must be one of {', '.join(SCALES)}, got {data['scale']!r}")
    for i, row in enumerate(data["rows"]):
        _check_fields(row, _ROW, f"{source}: rows[{i}]")
        for key in ("ours", "paper"):
            if key not in row:
                raise ResultError(f"{source}: rows[{i}] lacks {key!r}")
        if row["ours"] is not None and (isinstance(row["ours"], bool) or not isinstance(row["ours"], (int, float))):
            raise ResultError(f"{source}: rows[{i}].ours must be a number or null")
        if row["paper"] is not None and (isinstance(row["paper"], bool)
                                         or not isinstance(row["paper"], (int, float, str))):
            raise ResultError(f"{source}: rows[{i}].paper must be a number, a text or null")
    for i, claim in enumerate(data["claims"]):
        _check_fields(claim, _CLAIM, f"{source}: claims[{i}]")
    for i, fig in enumerate(data["figures"]):
        if not isinstance(fig, str) or Path(fig).is_absolute() or ".." in Path(fig).parts:
            raise ResultError(f"{source}: figures[{i}] must be a path inside the run directory, got {fig!r}")


def _check_fields(item: Any, fields: dict[str, type], where: str) -> None:
    if not isinstance(item, dict):
        raise ResultError(f"{where} must be an object")
    for key, kind in fields.items():
        if not isinstance(item.get(key), kind):
            raise ResultError(f"{where}.{key} must be {kind.__name__}, got {item.get(key)!r:.80}")


def write_result(out_dir: Path, result: ExperimentResult) -> Path:
    """Write ``out_dir/result.json`` atomically (a crash never leaves half a file)."""
    path = out_dir / RESULT_FILE
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result.to_json(), indent=2, allow_nan=False))
    os.replace(tmp, path)
    return path


MAX_RESULT_BYTES = 50_000_000


def read_result(path: Path) -> dict[str, Any]:
    """Read and validate one result.json; raises ResultError naming the file."""
    try:
        if path.stat().st_size > MAX_RESULT_BYTES:
            raise ResultError(f"{path}: larger than {MAX_RESULT_BYTES} bytes, not a result file")
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ResultError(f"{path}: unreadable ({err})") from None
    validate_result(data, str(path))
    return data
