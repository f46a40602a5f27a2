"""The record of one reproduced paper experiment: ``result.json``.

Schema (every experiment writes exactly this, plus the optional ``details`` and ``provenance``)::

    {"experiment": str, "paper_ref": str, "scale": "smoke"|"short"|"paper", "seed": int, "wall_s": float,
     "rows":   [{"system": str, "metric": str, "unit": str, "ours": float|null, "paper": float|str|null}],
     "claims": [{"claim": str, "holds": bool|null, "evidence": str}],
     "figures": [str],            # paths relative to the run directory
     "details": {...},            # optional: per-seed values, anything a reader may want
     "provenance": {...},         # optional: command, package version, git commit, split of the data
     "settings": {name: value}}   # optional: the experiment's settings the run used (scale + --set);
                                  # each value null, a bool, a finite number, a text or a list of those

``experiment`` is a slug (``[a-z0-9][a-z0-9_-]*``: it names folders of the report); ``wall_s``, ``seed`` and
the numbers of ``rows`` are finite (NaN and ±Infinity are refused, in the file and in the schema).

``claims[].holds`` is computed by the experiment from its own numbers and has three states: ``true`` (the
claim holds), ``false`` (it does not) and ``null``, *not testable*: a premise the claim rests on failed (the
training diverged, the baseline has no periodic orbit to compare with...), so our numbers say nothing about
the claim either way; its ``evidence`` then names the failed premise and must not be empty.
:class:`Claim` refuses anything but a real boolean or None so that a string or a hand-written ``"yes"``
cannot slip in; :meth:`Claim.not_testable` makes the third state.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bptsb_ros.experiments.claim_rules import verdict_over_seeds

SCALES = ("smoke", "short", "paper")
RESULT_FILE = "result.json"
#: what an experiment's name may look like (it becomes part of folder names and page anchors)
EXPERIMENT_SLUG = re.compile(r"[a-z0-9][a-z0-9_-]*")
MAX_SLUG_LEN = 100


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


def claim_mark(holds: bool | None) -> str:
    """How a verdict is shown: ``✓`` holds, ``✗`` does not, ``∅ not testable`` (a premise failed)."""
    return "∅ not testable" if holds is None else ("✓" if holds else "✗")


@dataclass
class Claim:
    """A qualitative statement of the paper and whether our numbers support it.

    ``holds`` is True (supported), False (contradicted) or None: *not testable*, a premise of the claim
    failed and ``evidence`` names it (use :meth:`not_testable`). Anything else is refused.
    """

    claim: str
    holds: bool | None
    evidence: str

    def __post_init__(self) -> None:
        if isinstance(self.holds, np.bool_):
            self.holds = bool(self.holds)
        if self.holds is not None and not isinstance(self.holds, bool):
            raise ResultError(f"claim {self.claim!r}: holds must be a computed bool (or None: not testable), got "
                              f"{type(self.holds).__name__}")
        if self.holds is None and not (isinstance(self.evidence, str) and self.evidence.strip()):
            raise ResultError(f"claim {self.claim!r}: a not-testable claim needs evidence naming the failed premise")

    @classmethod
    def not_testable(cls, claim: str, premise: str) -> Claim:
        """The claim ``claim`` cannot be tested because ``premise`` (what failed, in words) failed."""
        return cls(claim, None, premise)


def all_not_testable(claims: list[Claim], reason: str) -> list[Claim]:
    """The same claims (same texts), every one not testable because ``reason``: the claims of a system whose training
    diverged, so a seed where it did keeps its place among the seeds (∅ for it) instead of losing the run."""
    return [Claim.not_testable(c.claim, reason) for c in claims]


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
    #: the experiment's resolved settings (``ctx.settings``), as JSON values
    settings: dict[str, Any] = field(default_factory=dict)
    #: every claim function call with its encoded arguments (:mod:`~bptsb_ros.experiments.measured`), so the
    #: claims can be judged again from the stored numbers
    measured: list[dict[str, Any]] = field(default_factory=list)
    #: which code judged the claims (:func:`judged_by`)
    judged: dict[str, Any] = field(default_factory=dict)

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
_CLAIM = {"claim": str, "evidence": str}


def validate_result(data: Any, source: str = "result") -> None:
    """Raise :class:`ResultError` unless ``data`` follows the result.json schema: one seed's run, or (with
    ``seeds``) the aggregate of several (:func:`validate_aggregate`)."""
    if not isinstance(data, dict):
        raise ResultError(f"{source}: must be a JSON object, got {type(data).__name__}")
    if "seeds" in data:
        validate_aggregate(data, source)
        return
    for key, kind in _TOP.items():
        if key not in data:
            raise ResultError(f"{source}: missing key {key!r}")
        if not isinstance(data[key], kind) or (kind is int and isinstance(data[key], bool)):
            raise ResultError(f"{source}: {key} has the wrong type ({type(data[key]).__name__})")
    name = data["experiment"]
    if len(name) > MAX_SLUG_LEN or not EXPERIMENT_SLUG.fullmatch(name):
        raise ResultError(f"{source}: experiment must be a name like 'lissajous-closed-loop' (lower-case letters, "
                          f"digits, '-' and '_'), got {name!r:.80}")
    if not _finite(data["wall_s"]) or data["wall_s"] < 0:
        raise ResultError(f"{source}: wall_s must be a finite number of seconds ≥ 0, got {data['wall_s']!r}")
    for key in ("details", "provenance", "judged"):
        if key in data and not isinstance(data[key], dict):
            raise ResultError(f"{source}: {key} must be an object, got {type(data[key]).__name__}")
    if "measured" in data and not (isinstance(data["measured"], list)
                                   and all(isinstance(m, dict) for m in data["measured"])):
        raise ResultError(f"{source}: measured must be a list of objects (judge calls)")
    if "settings" in data:
        _check_settings(data["settings"], source)
    if data["scale"] not in SCALES:
        raise ResultError(f"{source}: scale must be one of {', '.join(SCALES)}, got {data['scale']!r}")
    for i, row in enumerate(data["rows"]):
        _check_fields(row, _ROW, f"{source}: rows[{i}]")
        for key in ("ours", "paper"):
            if key not in row:
                raise ResultError(f"{source}: rows[{i}] lacks {key!r}")
        if row["ours"] is not None and not _finite(row["ours"]):
            raise ResultError(f"{source}: rows[{i}].ours must be a finite number or null, got {row['ours']!r:.80}")
        if row["paper"] is not None and not (isinstance(row["paper"], str) or _finite(row["paper"])):
            raise ResultError(f"{source}: rows[{i}].paper must be a finite number, a text or null, got "
                              f"{row['paper']!r:.80}")
    for i, claim in enumerate(data["claims"]):
        _check_fields(claim, _CLAIM, f"{source}: claims[{i}]")
        if "holds" not in claim or (claim["holds"] is not None and not isinstance(claim["holds"], bool)):
            raise ResultError(f"{source}: claims[{i}].holds must be true, false or null (not testable), got "
                              f"{claim.get('holds')!r:.80}")
        if claim["holds"] is None and not claim["evidence"].strip():
            raise ResultError(f"{source}: claims[{i}] is not testable (holds null) but its evidence does not name "
                              "the failed premise")
    for i, fig in enumerate(data["figures"]):
        if not isinstance(fig, str) or Path(fig).is_absolute() or ".." in Path(fig).parts:
            raise ResultError(f"{source}: figures[{i}] must be a path inside the run directory, got {fig!r}")


#: an aggregate claim's verdict over seeds (the rule: :func:`bptsb_ros.experiments.claim_rules.verdict_over_seeds`)
AGGREGATE_VERDICTS = ("holds", "fails", "split", "not_testable")
_AGG_TOP = {"experiment": str, "paper_ref": str, "scale": str, "seeds": list, "wall_s": (int, float), "rows": list,
            "claims": list, "figures": list}
MAX_SEEDS = 1000


def verdict_mark(verdict: str) -> str:
    """How a verdict over seeds is shown: ``✓`` holds, ``✗`` fails, ``split``, ``∅`` not testable."""
    return {"holds": "✓", "fails": "✗", "split": "split", "not_testable": "∅"}[verdict]


def validate_aggregate(data: dict[str, Any], source: str = "result") -> None:
    """Raise :class:`ResultError` unless ``data`` is a valid aggregate over seeds (``bptsb reproduce --seeds``)::

        {"experiment", "paper_ref", "scale", "seeds": [int], "wall_s", "figures", "details"?, "provenance"?,
         "settings"?, "seed_runs": {seed: folder},
         "rows": [{"system", "metric", "unit", "ours" (mean | null), "ours_sd", "ours_min", "ours_max", "n",
                   "per_seed": [number | null, one per seed], "paper", "paper_in_range": bool | null}],
         "claims": [{"claim", "evidence", "verdict": "holds" | "fails" | "split" | "not_testable",
                     "holds_in": [k, n], "not_testable_in": int, "per_seed": [true | false | null, one per seed],
                     "interval": [lo, hi] | null}]}
    """
    for key, kind in _AGG_TOP.items():
        if key not in data:
            raise ResultError(f"{source}: missing key {key!r}")
        if not isinstance(data[key], kind):
            raise ResultError(f"{source}: {key} has the wrong type ({type(data[key]).__name__})")
    name = data["experiment"]
    if len(name) > MAX_SLUG_LEN or not EXPERIMENT_SLUG.fullmatch(name):
        raise ResultError(f"{source}: experiment must be a name like 'lissajous-closed-loop', got {name!r:.80}")
    if data["scale"] not in SCALES:
        raise ResultError(f"{source}: scale must be one of {', '.join(SCALES)}, got {data['scale']!r:.40}")
    seeds = data["seeds"]
    if not seeds or len(seeds) > MAX_SEEDS or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0
                                                       for s in seeds) or len(set(seeds)) != len(seeds):
        raise ResultError(f"{source}: seeds must be 1 to {MAX_SEEDS} distinct whole numbers >= 0")
    if not _finite(data["wall_s"]) or data["wall_s"] < 0:
        raise ResultError(f"{source}: wall_s must be a finite number of seconds ≥ 0, got {data['wall_s']!r:.40}")
    for key in ("details", "provenance", "seed_runs", "judged"):
        if key in data and not isinstance(data[key], dict):
            raise ResultError(f"{source}: {key} must be an object, got {type(data[key]).__name__}")
    if "settings" in data:
        _check_settings(data["settings"], source)
    n_seeds = len(seeds)
    for i, row in enumerate(data["rows"]):
        where = f"{source}: rows[{i}]"
        _check_fields(row, _ROW, where)
        per = row.get("per_seed")
        if not isinstance(per, list) or len(per) != n_seeds or not all(v is None or _finite(v) for v in per):
            raise ResultError(f"{where}.per_seed must hold a finite number or null for each of the {n_seeds} seeds")
        values = [v for v in per if v is not None]
        if row.get("n") != len(values) or isinstance(row.get("n"), bool):
            raise ResultError(f"{where}.n must count the seeds with a value ({len(values)})")
        for key in ("ours", "ours_sd", "ours_min", "ours_max"):
            if key not in row or not (row[key] is None if not values else _finite(row[key])):
                raise ResultError(f"{where}.{key} must be a finite number (null when no seed has a value)")
        if values and not (row["ours_min"] <= row["ours"] <= row["ours_max"] or math.isclose(
                row["ours_min"], row["ours_max"])):
            raise ResultError(f"{where}: ours must lie between ours_min and ours_max")
        if "paper" not in row or not (row["paper"] is None or isinstance(row["paper"], str) or _finite(row["paper"])):
            raise ResultError(f"{where}.paper must be a finite number, a text or null")
        if row.get("paper_in_range", None) is not None and not isinstance(row["paper_in_range"], bool):
            raise ResultError(f"{where}.paper_in_range must be true, false or null")
    for i, claim in enumerate(data["claims"]):
        where = f"{source}: claims[{i}]"
        _check_fields(claim, _CLAIM, where)
        if claim.get("verdict") not in AGGREGATE_VERDICTS:
            raise ResultError(f"{where}.verdict must be one of {', '.join(AGGREGATE_VERDICTS)}, got "
                              f"{claim.get('verdict')!r:.40}")
        per = claim.get("per_seed")
        if not isinstance(per, list) or len(per) != n_seeds or not all(v is None or isinstance(v, bool) for v in per):
            raise ResultError(f"{where}.per_seed must hold true, false or null for each of the {n_seeds} seeds")
        k, n = sum(v is True for v in per), sum(v is not None for v in per)
        if claim.get("holds_in") != [k, n] or claim.get("not_testable_in") != n_seeds - n:
            raise ResultError(f"{where}: holds_in must be [{k}, {n}] and not_testable_in {n_seeds - n} (from "
                              "per_seed)")
        evidence = claim.get("per_seed_evidence", [""] * n_seeds)
        if not isinstance(evidence, list) or len(evidence) != n_seeds or not all(isinstance(e, str) for e in evidence):
            raise ResultError(f"{where}.per_seed_evidence must hold a text for each of the {n_seeds} seeds")
        if claim["verdict"] != verdict_over_seeds(k, n, n_seeds):
            raise ResultError(f"{where}: verdict {claim['verdict']!r} is not what the rule gives for {k} of {n} "
                              f"testable in {n_seeds} seeds")
    for i, fig in enumerate(data["figures"]):
        if not isinstance(fig, str) or Path(fig).is_absolute() or ".." in Path(fig).parts:
            raise ResultError(f"{source}: figures[{i}] must be a path inside the run directory, got {fig!r:.80}")


def _setting_scalar(value: Any) -> bool:
    return value is None or isinstance(value, (bool, str)) or _finite(value)


def _check_settings(settings: Any, source: str) -> None:
    """``settings``: an object of name → null, bool, finite number, text, or a list of those."""
    if not isinstance(settings, dict):
        raise ResultError(f"{source}: settings must be an object, got {type(settings).__name__}")
    for key, value in settings.items():
        ok = _setting_scalar(value) or (isinstance(value, list) and all(_setting_scalar(v) for v in value))
        if not ok:
            raise ResultError(f"{source}: settings.{key:.80} must be null, a bool, a finite number, a text or a "
                              f"list of those, got {value!r:.80}")


def _finite(value: Any) -> bool:
    """True for a finite int or float (not a bool; an int too large for a float is not finite)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False


def _check_fields(item: Any, fields: dict[str, type], where: str) -> None:
    if not isinstance(item, dict):
        raise ResultError(f"{where} must be an object")
    for key, kind in fields.items():
        if not isinstance(item.get(key), kind):
            raise ResultError(f"{where}.{key} must be {kind.__name__}, got {item.get(key)!r:.80}")


def write_result(out_dir: Path, result: ExperimentResult) -> Path:
    """Write ``out_dir/result.json`` atomically, as a regular file only (a crash never leaves half a file)."""
    return write_json_result(out_dir, result.to_json())


def write_json_result(out_dir: Path, data: dict[str, Any]) -> Path:
    """Validate ``data`` (a single-seed or aggregate result) and write it as ``out_dir/result.json`` atomically, as a
    regular file only (:func:`~bptsb_ros.files.safe_write.write_atomic`)."""
    from bptsb_ros.files.safe_write import write_atomic

    validate_result(data, str(out_dir / RESULT_FILE))
    return write_atomic(out_dir / RESULT_FILE, json.dumps(data, indent=2, allow_nan=False) + "\n")


MAX_RESULT_BYTES = 50_000_000


def _refuse_constant(name: str) -> Any:
    """json.loads would turn ``NaN``/``Infinity``/``-Infinity`` into floats; a result.json never holds them."""
    raise ResultError(f"{name} is not valid JSON (a result.json holds only finite numbers)")


def read_result(path: Path) -> dict[str, Any]:
    """Read and validate one result.json; raises ResultError naming the file."""
    try:
        if path.stat().st_size > MAX_RESULT_BYTES:
            raise ResultError(f"{path}: larger than {MAX_RESULT_BYTES} bytes, not a result file")
        data = json.loads(path.read_text(encoding="utf-8"), parse_constant=_refuse_constant)
    except ResultError as err:
        raise ResultError(f"{path}: {err}") from None
    except RecursionError:
        raise ResultError(f"{path}: unreadable (nested too deeply)") from None
    except (OSError, ValueError) as err:  # ValueError: JSONDecodeError, UnicodeDecodeError, an int too long
        raise ResultError(f"{path}: unreadable ({err})") from None
    validate_result(data, str(path))
    return data
