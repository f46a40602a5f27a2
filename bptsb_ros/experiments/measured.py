"""What a run measured, kept so that its claims can be judged again without training again.

Measuring is expensive (hours of training), judging is cheap (a pure function over a few numbers). An experiment
therefore calls each of its claim functions through :meth:`Context.judge
<bptsb_ros.experiments.registry.Context.judge>`, which records the call — the judge's registered name and its
arguments, encoded by :func:`encode` — in ``result.json`` under ``measured``. :func:`rejudge` decodes those
arguments and calls the judges of the installed code again: a claim rule fixed later costs no rerun.

A judge is registered under a stable name with :func:`judge` (``@judge("lissajous-closed-loop")``), so a
result.json names it as data: a name read from a file is looked up in the registry, never imported.

The encoding is JSON with a few tagged forms, so that what a claim function receives decodes to the same values
(bit for bit): ``{"@float": "nan"}`` for non-finite floats (result.json holds only finite numbers), ``{"@array":
[...], "dtype": ..., "shape": [...]}`` for numpy arrays, ``{"@tuple": [...]}``, ``{"@dict": [[key, value],
...]}`` for mappings whose keys are not all plain texts, and ``{"@dataclass": NAME, "fields": {...}}`` for the
frozen dataclasses claim functions take; a dataclass name is resolved only among the classes the judge's own type
hints reach (its parameters and their fields, recursively), never by import.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from bptsb_ros.experiments.result import Claim, ResultError

#: judge name → claim function (a pure function returning a list of :class:`Claim`)
_JUDGES: dict[str, Callable[..., list[Claim]]] = {}
#: dtypes an encoded array may have
_DTYPES = frozenset({"float64", "float32", "int64", "int32", "int16", "int8", "uint8", "bool"})
#: an encoded array or structure larger than this is refused when decoding (result.json is at most 50 MB)
MAX_ELEMENTS = 5_000_000
MAX_DEPTH = 32


def judge(name: str) -> Callable[[Callable[..., list[Claim]]], Callable[..., list[Claim]]]:
    """Register a claim function under ``name`` (stable across refactors: it is what result.json stores)."""
    if not name or not all(c.isalnum() or c in "-_/." for c in name):
        raise ValueError(f"judge name {name!r} must be letters, digits and -_/.")

    def register(fn: Callable[..., list[Claim]]) -> Callable[..., list[Claim]]:
        if name in _JUDGES and _JUDGES[name] is not fn:
            raise ValueError(f"judge {name!r} registered twice")
        _JUDGES[name] = fn
        fn.judge_name = name  # type: ignore[attr-defined]
        return fn

    return register


def judge_name(fn: Callable[..., Any]) -> str:
    """The name ``fn`` was registered under (ValueError for an unregistered function)."""
    name = getattr(fn, "judge_name", None)
    if name is None or _JUDGES.get(name) is not fn:
        raise ValueError(f"{getattr(fn, '__qualname__', fn)!r} is not a registered judge (decorate it with @judge)")
    return name


def registered_judge(name: str) -> Callable[..., list[Claim]]:
    """The judge registered as ``name``; ResultError (one line) if there is none."""
    if not isinstance(name, str) or name not in _JUDGES:
        raise ResultError(f"measured: no claim function is registered as {str(name)[:80]!r}")
    return _JUDGES[name]


# ---------------------------------------------------------------------------------------------------- encoding


def encode(value: Any) -> Any:
    """``value`` as JSON-compatible data that :func:`decode` turns back into an equal value (see the module)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else {"@float": repr(value)}
    if isinstance(value, np.ndarray):
        if value.dtype.name not in _DTYPES:
            raise TypeError(f"cannot record an array of dtype {value.dtype}")
        return {"@array": [encode(v) for v in value.ravel().tolist()], "dtype": value.dtype.name,
                "shape": list(value.shape)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {"@dataclass": type(value).__name__,
                "fields": {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    if isinstance(value, tuple):
        return {"@tuple": [encode(v) for v in value]}
    if isinstance(value, Mapping):
        if all(isinstance(k, str) and not k.startswith("@") for k in value):
            return {k: encode(v) for k, v in value.items()}
        return {"@dict": [[encode(k), encode(v)] for k, v in value.items()]}
    if isinstance(value, (list, Sequence)):
        return [encode(v) for v in value]
    raise TypeError(f"cannot record a {type(value).__name__} as a measured number")


def dataclasses_of(fn: Callable[..., Any]) -> dict[str, type]:
    """Every dataclass reachable from ``fn``'s parameter type hints (and their fields' hints), by name."""
    found: dict[str, type] = {}

    def visit(hint: Any) -> None:
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            if found.get(hint.__name__) is hint:
                return
            found[hint.__name__] = hint
            for hint2 in typing.get_type_hints(hint).values():
                visit(hint2)
            return
        for arg in typing.get_args(hint):
            visit(arg)
        if isinstance(hint, types.UnionType):
            for arg in hint.__args__:
                visit(arg)

    for name, hint in typing.get_type_hints(fn).items():
        if name != "return":
            visit(hint)
    return found


class _Decoder:
    def __init__(self, classes: Mapping[str, type]) -> None:
        self.classes = classes
        self.elements = 0

    def count(self, n: int) -> None:
        self.elements += n
        if self.elements > MAX_ELEMENTS:
            raise ResultError(f"measured: more than {MAX_ELEMENTS} values")

    def __call__(self, data: Any, depth: int = 0) -> Any:
        if depth > MAX_DEPTH:
            raise ResultError(f"measured: nested deeper than {MAX_DEPTH}")
        self.count(1)
        if data is None or isinstance(data, (bool, int, float, str)):
            return data
        if isinstance(data, list):
            return [self(v, depth + 1) for v in data]
        if not isinstance(data, dict):
            raise ResultError(f"measured: unexpected {type(data).__name__}")
        tags = [k for k in data if k.startswith("@")]
        if not tags:
            return {k: self(v, depth + 1) for k, v in data.items()}
        tag = tags[0]
        if tag == "@float" and set(data) == {"@float"}:
            if data["@float"] not in ("nan", "inf", "-inf"):
                raise ResultError(f"measured: {str(data['@float'])[:20]!r} is not a non-finite float")
            return float(data["@float"])
        if tag == "@tuple" and set(data) == {"@tuple"} and isinstance(data["@tuple"], list):
            return tuple(self(v, depth + 1) for v in data["@tuple"])
        if tag == "@dict" and set(data) == {"@dict"} and isinstance(data["@dict"], list):
            out = {}
            for pair in data["@dict"]:
                if not (isinstance(pair, list) and len(pair) == 2):
                    raise ResultError("measured: a @dict entry is not a [key, value] pair")
                key = self(pair[0], depth + 1)
                try:
                    out[key] = self(pair[1], depth + 1)
                except TypeError:
                    raise ResultError("measured: a @dict key is not hashable") from None
            return out
        if tag == "@array" and set(data) == {"@array", "dtype", "shape"}:
            return self.array(data)
        if tag == "@dataclass" and set(data) == {"@dataclass", "fields"} and isinstance(data["fields"], dict):
            cls = self.classes.get(data["@dataclass"]) if isinstance(data["@dataclass"], str) else None
            if cls is None:
                raise ResultError(f"measured: {str(data['@dataclass'])[:80]!r} is not a type this claim "
                                  "function takes")
            names = {f.name for f in dataclasses.fields(cls)}
            if not set(data["fields"]) <= names:
                raise ResultError(f"measured: {cls.__name__} has no field "
                                  f"{sorted(set(data['fields']) - names)[0][:80]!r}")
            try:
                return cls(**{k: self(v, depth + 1) for k, v in data["fields"].items()})
            except TypeError as err:
                raise ResultError(f"measured: {cls.__name__}: {err}") from None
        raise ResultError(f"measured: unknown form {tag[:40]!r}")

    def array(self, data: dict[str, Any]) -> np.ndarray:
        dtype, shape, flat = data["dtype"], data["shape"], data["@array"]
        if dtype not in _DTYPES or not isinstance(shape, list) or not isinstance(flat, list) or not all(
                isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in shape):
            raise ResultError("measured: an @array needs a known dtype, a shape of sizes and a flat list")
        if math.prod(shape) != len(flat):
            raise ResultError(f"measured: an @array of shape {shape[:8]} holds {len(flat)} values")
        self.count(len(flat))
        values = [float(v["@float"]) if isinstance(v, dict) and set(v) == {"@float"}
                  and v["@float"] in ("nan", "inf", "-inf") else v for v in flat]
        if not all(isinstance(v, (int, float)) for v in values):
            raise ResultError("measured: an @array holds something that is not a number")
        try:
            return np.array(values, dtype=dtype).reshape(shape)
        except (ValueError, OverflowError) as err:
            raise ResultError(f"measured: an @array does not fit its dtype {dtype} ({err})") from None


def decode(data: Any, classes: Mapping[str, type]) -> Any:
    """The value :func:`encode` made ``data`` from; dataclasses only among ``classes`` (name → class).
    ResultError (one line) for anything else."""
    return _Decoder(classes)(data)


# --------------------------------------------------------------------------------------------------- records


def record(fn: Callable[..., list[Claim]], args: Sequence[Any], kwargs: Mapping[str, Any],
           label: str = "") -> dict[str, Any]:
    """The ``measured`` entry of one judge call: ``{"judge", "args", "kwargs", "label"}``."""
    return {"judge": judge_name(fn), "args": [encode(a) for a in args],
            "kwargs": {k: encode(v) for k, v in kwargs.items()}, "label": label}


def call(entry: Mapping[str, Any]) -> list[Claim]:
    """The claims of one ``measured`` entry judged by the installed code (labels prefixed as recorded)."""
    if not isinstance(entry, Mapping) or not {"judge", "args", "kwargs"} <= set(entry):
        raise ResultError("measured: an entry needs judge, args and kwargs")
    fn = registered_judge(entry["judge"])
    label = entry.get("label", "")
    if not isinstance(label, str) or not isinstance(entry["args"], list) or not isinstance(entry["kwargs"], dict):
        raise ResultError("measured: label must be a text, args a list, kwargs an object")
    classes = dataclasses_of(fn)
    args = [decode(a, classes) for a in entry["args"]]
    kwargs = {k: decode(v, classes) for k, v in entry["kwargs"].items()}
    try:
        claims = fn(*args, **kwargs)
    except (TypeError, ValueError, KeyError, IndexError, AttributeError, ZeroDivisionError) as err:
        raise ResultError(f"measured: {entry['judge']} cannot judge the stored numbers "
                          f"({type(err).__name__}: {str(err)[:200]})") from None
    return [Claim(label + c.claim, c.holds, c.evidence) for c in claims]


def stored_calls(result: Mapping[str, Any],
                 fn: Callable[..., list[Claim]]) -> list[tuple[str, list[Any], dict[str, Any]]]:
    """The calls of the claim function ``fn`` stored in a result.json's ``measured``, decoded: (label, args,
    kwargs) each, in order (for figures over seeds that draw what the claims read)."""
    name, classes = judge_name(fn), dataclasses_of(fn)
    return [(e.get("label", ""), [decode(a, classes) for a in e["args"]],
             {k: decode(v, classes) for k, v in e["kwargs"].items()})
            for e in result.get("measured") or [] if isinstance(e, Mapping) and e.get("judge") == name]


def rejudge(measured: Sequence[Mapping[str, Any]]) -> list[Claim]:
    """Every claim of a run, judged again from its ``measured`` record, in the recorded order."""
    if not isinstance(measured, Sequence) or isinstance(measured, (str, bytes)):
        raise ResultError("measured must be a list of judge calls")
    return [claim for entry in measured for claim in call(entry)]


def claim_code_digest() -> str:
    """The first 12 hex digits of SHA-256 over the source of this package's ``experiments`` modules (where every
    claim function and rule lives): two results judged by the same digest were judged by the same code."""
    import hashlib
    from pathlib import Path

    digest = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:12]
