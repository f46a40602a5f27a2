"""What each scale of a ``bptsb reproduce`` experiment means, as data: ``settings/<experiment>.yaml``.

A settings file declares every setting once (its type, bounds and a help text) and gives its value at each
scale::

    settings:
      epochs: {type: int, min: 1, help: training epochs per system}
      n_train: {type: int, nullable: true, min: 1, help: "training images (null: every image of the split)"}
    smoke: {epochs: 1, n_train: 50}
    short: {epochs: 3, n_train: null}
    paper: {epochs: 50, n_train: null}

Named variants (profiles): an experiment that runs one protocol in several named ways (the paper's text, the
authors' published code) declares the variants' own settings in ``variant_settings`` (same declaration format)
and gives each variant every one of them under ``variants`` (the same at every scale: a variant is a protocol,
not a size)::

    variant_settings:
      published_wind: {type: bool, help: "the published code's wind (15·F, 1)"}
    variants:
      paper: {published_wind: false}
      authors: {published_wind: true}

The experiment reads them in file order as ``ctx.settings.variants`` (name → values); result.json records them.

Rules between settings (``rules``): each a comparison (< <= == != >= >) of two expressions of ``+ - * %`` over
numbers, settings, items of list settings (``hold[0]``) and ``max``, ``min`` or ``len`` of one; checked on the
resolved values before the experiment starts (a rule that reads a null setting holds)::

    rules:
      - {check: "washout < eval_inputs", help: "the NMSE is taken over the held-out inputs after the washout"}
      - {check: "grid % 2 == 1", help: "the label map has a cell at Δ = 0"}

Types: ``int``, ``float`` (an int is taken as a float), ``number`` (an int or a float, kept as written: a
duration the code passes on as it is), ``str``, ``bool`` and ``list[T]`` of those (a tuple in the code).
Declaration keys besides ``type`` and ``help``: ``min`` and ``max`` (inclusive; of every item of a list),
``length`` (of a list) and ``nullable`` (null allowed). A number (or list of numbers) must declare both ``min`` and
``max``: every setting has bounds a user would never need to exceed (``--set sim_time=1e300`` is refused, not run
until killed). Every scale gives exactly the declared settings.

The file is read with the project's bounded safe YAML loader; every problem is one :class:`SettingsError`
line naming the file and the setting, with a "did you mean" for a misspelt name. ``--set KEY=VALUE``
overrides (:func:`resolve_settings`) are checked against the same declarations. An experiment reads its
values as ``ctx.settings["epochs"]``; the resolved values are recorded in result.json (``settings``).
"""

from __future__ import annotations

import difflib
import json
import math
import operator
import re
import shlex
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

#: the packaged settings files, one per experiment (``<experiment name>.yaml``)
SETTINGS_DIR = Path(__file__).resolve().with_name("settings")
SCALES = ("smoke", "short", "paper")
SECTIONS = ("settings", *SCALES, "variant_settings", "variants", "rules")
SCALAR_TYPES = ("int", "float", "number", "str", "bool")
NUMBER_TYPES = ("int", "float", "number")
TYPES = (*SCALAR_TYPES, *(f"list[{t}]" for t in SCALAR_TYPES))
SPEC_KEYS = ("type", "help", "min", "max", "length", "nullable")
SETTING_NAME = re.compile(r"[a-z][a-z0-9_]*")
MAX_FILE_BYTES = 100_000
MAX_NODES = 5_000

Overrides = Sequence[str] | Mapping[str, Any]
"""``--set`` texts ``["epochs=3", ...]`` (values parsed as YAML) or a mapping ``{"epochs": 3}``."""


class SettingsError(ValueError):
    """A settings file or a ``--set`` override is not valid; one line naming the file or the override."""


def _shown(value: Any) -> str:
    text = str(value)
    return text if isinstance(value, str) and text.isprintable() and len(text) <= 80 else bounded_repr(value)


def _close(name: Any, names: Sequence[str]) -> str:
    """``"; did you mean epochs?"`` when a name of ``names`` is close to ``name``, else ``""``."""
    match = difflib.get_close_matches(str(name), list(names), n=1, cutoff=0.6)
    return f"; did you mean {match[0]}?" if match else ""


def _num(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class SettingSpec:
    """One declared setting: its type (one of :data:`TYPES`), help text and bounds."""

    name: str
    type: str
    help: str
    min: float | None = None
    max: float | None = None
    length: int | None = None
    nullable: bool = False

    def check(self, value: Any, where: str) -> Any:
        """``value`` as the code uses it (a float for ``float``, a tuple for a list); SettingsError naming
        ``where`` (``file: short.epochs`` or ``--set epochs``) otherwise."""
        if value is None and self.nullable:
            return None
        if self.type.startswith("list["):
            if not isinstance(value, (list, tuple)):
                raise SettingsError(f"{where} must be a list of {self.type[5:-1]}, got {bounded_repr(value)}")
            if self.length is not None and len(value) != self.length:
                raise SettingsError(f"{where} must be a list of {self.length} items, got {len(value)}")
            return tuple(self._scalar(v, self.type[5:-1], f"{where}[{i}]") for i, v in enumerate(value))
        return self._scalar(value, self.type, where)

    def _scalar(self, value: Any, kind: str, where: str) -> Any:
        got = bounded_repr(value)
        if kind == "str":
            if not isinstance(value, str):
                raise SettingsError(f"{where} must be a text, got {got}")
            return value
        if kind == "bool":
            if not isinstance(value, bool):
                raise SettingsError(f"{where} must be true or false, got {got}")
            return value
        if kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise SettingsError(f"{where} must be an integer, got {got}")
        if isinstance(value, str) and _FLOAT_TEXT.fullmatch(value.strip()):  # YAML 1.1 reads 1e-05 as a text
            value = float(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SettingsError(f"{where} must be a number, got {got}")
        if self.min is not None and value < self.min:
            raise SettingsError(f"{where} must be ≥ {_num(self.min)}, got {got}")
        if self.max is not None and value > self.max:
            raise SettingsError(f"{where} must be ≤ {_num(self.max)}, got {got}")
        return float(value) if kind == "float" else value


#: a number in exponent form without a decimal point (``1e-05``, ``2E+3``), which YAML 1.1 leaves a text
_FLOAT_TEXT = re.compile(r"[-+]?[0-9]+(?:\.[0-9]*)?[eE][-+]?[0-9]+")


def _value_text(value: Any) -> str:
    """``value`` (JSON data) as ``--set`` text that reads back as the same value (floats keep a decimal point,
    so YAML 1.1 reads ``1.0e-05`` as a number, not the text ``1e-05``)."""
    if isinstance(value, list):
        return "[" + ",".join(_value_text(v) for v in value) + "]"
    if isinstance(value, float):
        text = repr(value)
        mantissa, e, exponent = text.partition("e")
        return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text
    return json.dumps(value)


@dataclass(frozen=True)
class ParsedSettings:
    """A checked settings file: the declarations and every scale's values (checked, as the code uses them)."""

    source: str
    specs: dict[str, SettingSpec]
    values: dict[str, dict[str, Any]]
    variant_specs: dict[str, SettingSpec] = field(default_factory=dict)
    variants: dict[str, dict[str, Any]] = field(default_factory=dict)
    rules: tuple[Rule, ...] = ()


_RULE_TOKEN = re.compile(r"\s*(?:(?P<num>[0-9]+(?:\.[0-9]+)?)|(?P<name>[a-z][a-z0-9_]*)|"
                         r"(?P<op><=|>=|==|!=|<|>|\+|-|\*|%|\(|\)|\[|\]))")
_COMPARE = {"<": operator.lt, "<=": operator.le, "==": operator.eq, "!=": operator.ne, ">=": operator.ge,
            ">": operator.gt}
_ARITHMETIC = {"+": operator.add, "-": operator.sub, "*": operator.mul, "%": operator.mod}
_FUNCTIONS = {"max": max, "min": min, "len": len}
MAX_RULE_CHARS = 200

#: an expression of a rule: ``("num", value)``, ``("setting", name, index, function)`` (index: an item of a list
#: setting or None; function: ``max``, ``min``, ``len`` of one or None) or ``(op, left, right)`` (+ - * %)
Expr = tuple


def _evaluate(expr: Expr, values: Mapping[str, Any]) -> float | None:
    """The value of ``expr`` for the settings ``values`` (None where it reads a null setting or an empty list)."""
    if expr[0] == "num":
        return expr[1]
    if expr[0] == "setting":
        _, name, index, function = expr
        v = values.get(name)
        if v is None:
            return None
        if function is not None:
            return _FUNCTIONS[function](v) if len(v) or function == "len" else None
        if index is not None:
            return v[index] if index < len(v) else None
        return v
    left, right = _evaluate(expr[1], values), _evaluate(expr[2], values)
    return None if left is None or right is None else _ARITHMETIC[expr[0]](left, right)


def _names(expr: Expr) -> set[str]:
    if expr[0] == "num":
        return set()
    if expr[0] == "setting":
        return {expr[1]}
    return _names(expr[1]) | _names(expr[2])


@dataclass(frozen=True)
class Rule:
    """``left op right`` over the settings (``check``: its text), with the reason it must hold (``help``)."""

    check: str
    help: str
    left: Expr
    op: str
    right: Expr

    def problem(self, values: Mapping[str, Any]) -> str | None:
        """Why the rule fails for ``values`` (None when it holds, or when a setting it reads is null)."""
        left, right = _evaluate(self.left, values), _evaluate(self.right, values)
        if left is None or right is None or _COMPARE[self.op](left, right):
            return None
        given = ", ".join(f"{n} = {_shown(values[n])}" for n in sorted(_names(self.left) | _names(self.right)))
        return f"{self.check} does not hold ({given}): {self.help}"


def _parse_rule(raw: Any, specs: Mapping[str, SettingSpec], where: str) -> Rule:
    """A rule ``{check: "a + b < c", help: ...}``: sums and differences of products of terms (a number, a setting,
    ``name[i]``, ``max(name)``, ``min(name)``, ``len(name)``, each possibly ``% N``) compared with one of
    < <= == != >= >."""
    if not isinstance(raw, Mapping) or set(raw) != {"check", "help"} or not isinstance(raw["check"], str) \
            or not isinstance(raw["help"], str) or not raw["help"].strip():
        raise SettingsError(f"{where} must be a mapping {{check: \"a < b\", help: why it must hold}}, got "
                            f"{bounded_repr(raw)}")
    text = raw["check"]
    if len(text) > MAX_RULE_CHARS:
        raise SettingsError(f"{where}: the check is longer than {MAX_RULE_CHARS} characters")
    tokens, pos = [], 0
    while pos < len(text.rstrip()):
        m = _RULE_TOKEN.match(text, pos)
        if not m or m.end() == pos:
            raise SettingsError(f"{where}: cannot read {bounded_repr(text[pos:pos + 20])} in {bounded_repr(text)}")
        tokens.append((m.lastgroup, m.group(m.lastgroup)))
        pos = m.end()
    tokens.append(("end", ""))
    at = [0]

    def peek() -> tuple[str, str]:
        return tokens[at[0]]

    def take(kind: str, value: str | None = None) -> str:
        k, v = tokens[at[0]]
        if k != kind or (value is not None and v != value):
            raise SettingsError(f"{where}: {bounded_repr(text)} is not a rule like \"a + b < c\" (at "
                                f"{bounded_repr(v or 'the end')})")
        at[0] += 1
        return v

    def atom() -> Expr:
        kind, value = peek()
        if kind == "num":
            take("num")
            return ("num", float(value) if "." in value else int(value))
        name = take("name")
        function = index = None
        if name in _FUNCTIONS and peek() == ("op", "("):
            take("op", "(")
            function, name = name, take("name")
            take("op", ")")
        if peek() == ("op", "["):
            take("op", "[")
            index = int(take("num"))
            take("op", "]")
        spec = specs.get(name)
        if spec is None:
            raise SettingsError(f"{where}: {bounded_repr(text)} names {name}, which is not a setting"
                                f"{_close(name, list(specs))}")
        as_list = function is not None or index is not None
        if as_list != spec.type.startswith("list[") or spec.type.removeprefix("list[").removesuffix("]") not in \
                NUMBER_TYPES and function != "len":
            raise SettingsError(f"{where}: {bounded_repr(text)} reads {name} ({spec.type}) as "
                                f"{'a list of numbers' if as_list else 'a number'}")
        return ("setting", name, index, function)

    def factor() -> Expr:
        expr = atom()
        while peek() in (("op", "*"), ("op", "%")):
            expr = (take("op"), expr, atom())
        return expr

    def side() -> Expr:
        expr = factor()
        while peek() in (("op", "+"), ("op", "-")):
            expr = (take("op"), expr, factor())
        return expr

    left = side()
    op = take("op")
    if op not in _COMPARE:
        raise SettingsError(f"{where}: {bounded_repr(text)} compares with {op!r}, not one of {', '.join(_COMPARE)}")
    right = side()
    take("end")
    return Rule(text, " ".join(raw["help"].split()), left, op, right)


def _spec(name: Any, raw: Any, where: str) -> SettingSpec:
    if not isinstance(name, str) or not SETTING_NAME.fullmatch(name):
        raise SettingsError(f"{where}: setting names are lower-case words ([a-z][a-z0-9_]*), got {bounded_repr(name)}")
    where = f"{where}.{name}"
    if not isinstance(raw, Mapping):
        raise SettingsError(f"{where} must be a mapping such as {{type: int, help: ...}}, got {bounded_repr(raw)}")
    for key in raw:
        if key not in SPEC_KEYS:
            raise SettingsError(f"{where}.{_shown(key)}: unknown key{_close(key, SPEC_KEYS)} "
                                f"(known: {', '.join(SPEC_KEYS)})")
    if raw.get("type") not in TYPES:
        raise SettingsError(f"{where}.type must be one of {', '.join(TYPES)}, got {bounded_repr(raw.get('type'))}")
    if not isinstance(raw.get("help"), str) or not raw["help"].strip():
        raise SettingsError(f"{where} needs a help text (help: what it is, with its unit)")
    for key in ("min", "max"):
        v = raw.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise SettingsError(f"{where}.{key} must be a number, got {bounded_repr(v)}")
        if v is None and raw["type"].removeprefix("list[").removesuffix("]") in NUMBER_TYPES:
            raise SettingsError(f"{where} needs a {key}: every number has bounds a user would never need to exceed")
    if raw.get("min") is not None and raw.get("max") is not None and raw["min"] > raw["max"]:
        raise SettingsError(f"{where}: min {raw['min']} is above max {raw['max']}")
    length = raw.get("length")
    if length is not None and (not raw["type"].startswith("list[") or isinstance(length, bool)
                               or not isinstance(length, int) or length < 0):
        raise SettingsError(f"{where}.length is a list's number of items (an integer ≥ 0), got {bounded_repr(length)}")
    if not isinstance(raw.get("nullable", False), bool):
        raise SettingsError(f"{where}.nullable must be true or false, got {bounded_repr(raw['nullable'])}")
    return SettingSpec(name, raw["type"], " ".join(raw["help"].split()), raw.get("min"), raw.get("max"), length,
                       raw.get("nullable", False))


def parse_settings(doc: Any, source: str) -> ParsedSettings:
    """Check a settings document (YAML text, or the mapping it parses to); ``source`` names it in messages."""
    if isinstance(doc, (str, bytes)):
        try:
            doc = load_untrusted_yaml(doc, source, max_bytes=MAX_FILE_BYTES, max_nodes=MAX_NODES)
        except UntrustedYamlError as err:
            raise SettingsError(str(err)) from None
    if not isinstance(doc, Mapping):
        raise SettingsError(f"{source}: must be a mapping with the sections {', '.join(SECTIONS)}")
    for key in doc:
        if key not in SECTIONS:
            raise SettingsError(f"{source}: {_shown(key)}: unknown section{_close(key, SECTIONS)} "
                                f"(sections: {', '.join(SECTIONS)})")
    declared = doc.get("settings")
    if not isinstance(declared, Mapping):
        raise SettingsError(f"{source}: settings must map each setting's name to its type and help text")
    specs = {name: _spec(name, raw, f"{source}: settings") for name, raw in declared.items()}
    values: dict[str, dict[str, Any]] = {}
    for scale in SCALES:
        given = doc.get(scale)
        if not isinstance(given, Mapping):
            raise SettingsError(f"{source}: no {scale} settings (a mapping of every declared setting to its value)")
        for key in given:
            if key not in specs:
                raise SettingsError(f"{source}: {scale}.{_shown(key)}: unknown setting{_close(key, list(specs))}")
        for key in specs:
            if key not in given:
                raise SettingsError(f"{source}: {scale} lacks the setting {key}")
        values[scale] = {key: spec.check(given[key], f"{source}: {scale}.{key}") for key, spec in specs.items()}
    variant_specs, variants = _parse_variants(doc, source)
    raw_rules = doc.get("rules", [])
    if not isinstance(raw_rules, list):
        raise SettingsError(f"{source}: rules must be a list of {{check: ..., help: ...}}")
    rules = tuple(_parse_rule(raw, specs, f"{source}: rules[{i}]") for i, raw in enumerate(raw_rules))
    for scale in SCALES:  # the packaged values keep the rules too
        problem = next((p for r in rules if (p := r.problem(values[scale]))), None)
        if problem:
            raise SettingsError(f"{source}: {scale}: {problem}")
    return ParsedSettings(source, specs, values, variant_specs, variants, rules)


def _parse_variants(doc: Mapping, source: str) -> tuple[dict[str, SettingSpec], dict[str, dict[str, Any]]]:
    """The ``variant_settings`` declarations and the checked ``variants`` (both absent: none)."""
    declared, given = doc.get("variant_settings"), doc.get("variants")
    if declared is None and given is None:
        return {}, {}
    if not isinstance(declared, Mapping) or not declared:
        raise SettingsError(f"{source}: variants need variant_settings, mapping each variant setting's name to its "
                            "type and help text")
    if not isinstance(given, Mapping) or not given:
        raise SettingsError(f"{source}: variant_settings need variants, mapping each variant's name to its values")
    specs = {name: _spec(name, raw, f"{source}: variant_settings") for name, raw in declared.items()}
    out: dict[str, dict[str, Any]] = {}
    for name, values in given.items():
        if not isinstance(name, str) or not SETTING_NAME.fullmatch(name):
            raise SettingsError(f"{source}: variants: variant names are lower-case words ([a-z][a-z0-9_]*), got "
                                f"{bounded_repr(name)}")
        if not isinstance(values, Mapping):
            raise SettingsError(f"{source}: variants.{name} must map every variant setting to its value, got "
                                f"{bounded_repr(values)}")
        for key in values:
            if key not in specs:
                raise SettingsError(f"{source}: variants.{name}.{_shown(key)}: unknown variant setting"
                                    f"{_close(key, list(specs))}")
        for key in specs:
            if key not in values:
                raise SettingsError(f"{source}: variants.{name} lacks the variant setting {key}")
        out[name] = {key: spec.check(values[key], f"{source}: variants.{name}.{key}") for key, spec in specs.items()}
    return specs, out


def settings_path(experiment: str) -> Path:
    """The packaged settings file of ``experiment`` (it may not exist: an experiment without settings)."""
    return SETTINGS_DIR / f"{experiment}.yaml"


def load_settings_file(experiment: str) -> ParsedSettings | None:
    """The checked settings file of ``experiment``; None when it has none."""
    path = settings_path(experiment)
    if not path.is_file():
        return None
    try:
        text = path.read_bytes()
    except OSError as err:
        raise SettingsError(f"{path}: unreadable ({err.strerror or err})") from None
    return parse_settings(text, f"settings file {path.name}")


def _yaml_reads_back(text: str) -> bool:
    """True when ``--set key=TEXT`` gives back the text itself (not ``3``, ``null`` or a list)."""
    try:
        return load_untrusted_yaml(text, "a text", max_bytes=10_000, max_nodes=1_000) == text
    except UntrustedYamlError:
        return False


class Settings(Mapping[str, Any]):
    """The resolved settings of one run (read-only): ``ctx.settings["epochs"]``."""

    def __init__(self, experiment: str, scale: str, values: Mapping[str, Any],
                 specs: Mapping[str, SettingSpec] | None = None, overridden: Sequence[str] = (),
                 variants: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        self.experiment, self.scale = experiment, scale
        self._values = dict(values)
        self.specs = dict(specs or {})
        self.overridden = tuple(overridden)
        #: the named variants (file order), name → {variant setting: value}; empty when the file has none
        self.variants: dict[str, dict[str, Any]] = {k: dict(v) for k, v in (variants or {}).items()}

    def __getitem__(self, key: str) -> Any:
        try:
            return self._values[key]
        except KeyError:
            raise KeyError(f"{self.experiment} has no setting {key!r}{_close(key, list(self._values))} (its file: "
                           f"{settings_path(self.experiment).name})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"Settings({self.experiment!r}, {self.scale!r}, {self._values!r})"

    def to_json(self) -> dict[str, Any]:
        """The values as JSON data (tuples as lists), for result.json."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in self._values.items()}

    def variants_json(self) -> dict[str, dict[str, Any]]:
        """The variants as JSON data (tuples as lists), for result.json."""
        return {name: {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}
                for name, values in self.variants.items()}

    def override_args(self) -> list[str]:
        """``--set key=value`` arguments that reproduce the overridden values (shell-quoted where needed)."""
        args = []
        for key in self.overridden:
            value = self._values[key]
            plain = isinstance(value, str) and _yaml_reads_back(value)
            text = value if plain else _value_text(self.to_json()[key])
            args.append(f"--set {shlex.quote(f'{key}={text}')}")
        return args

    def show(self) -> str:
        """The settings as YAML, each with its help text as a comment (``--show-config``)."""
        import yaml

        lines = [f"# {self.experiment} at scale {self.scale} (packaged: {settings_path(self.experiment).name}; "
                 "--set KEY=VALUE changes one)"]
        data = self.to_json()
        body = [yaml.safe_dump({k: v}, default_flow_style=True, width=10_000, allow_unicode=True,
                               sort_keys=False).strip().removeprefix("{").removesuffix("}") for k, v in data.items()]
        width = max((len(b) for b in body), default=0)
        for text, key in zip(body, data, strict=True):
            spec = self.specs.get(key)
            note = (spec.help if spec else "") + (" (--set)" if key in self.overridden else "")
            lines.append(f"{text.ljust(width)}  # {note}" if note else text)
        return "\n".join(lines) + "\n"


def _override_items(experiment: str, overrides: Overrides | None) -> list[tuple[str, Any, str]]:
    """(key, value, how it is named in messages) of each override, in order."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [(key, value, f"--set {_shown(key)}") for key, value in overrides.items()]
    if isinstance(overrides, str):
        raise SettingsError(f"settings overrides must be a list of key=value texts or a mapping, got the text "
                            f"{bounded_repr(overrides)}")
    items = []
    for text in overrides:
        if not isinstance(text, str) or "=" not in text:
            raise SettingsError(f"--set {_shown(text)} must look like key=value (e.g. epochs=3)")
        key, raw = text.split("=", 1)
        key = key.strip()
        try:
            value = load_untrusted_yaml(raw, f"--set {_shown(key)}", max_bytes=10_000, max_nodes=1_000)
        except UntrustedYamlError as err:
            raise SettingsError(str(err)) from None
        items.append((key, value, f"--set {_shown(key)}"))
    return items


def resolve_settings(experiment: str, scale: str, overrides: Overrides | None = None) -> Settings:
    """The settings of ``experiment`` at ``scale`` with ``overrides`` applied, each checked against its
    declaration (an unknown key is refused, with a "did you mean" where one is close)."""
    if scale not in SCALES:
        raise SettingsError(f"scale must be one of {', '.join(SCALES)}, got {bounded_repr(scale)}")
    parsed = load_settings_file(experiment)
    specs = parsed.specs if parsed else {}
    values = dict(parsed.values[scale]) if parsed else {}
    overridden: list[str] = []
    for key, value, where in _override_items(experiment, overrides):
        if key not in specs:
            known = f"{_close(key, list(specs))}" if specs else " (it has no settings)"
            raise SettingsError(f"{where}: unknown setting of {experiment}{known}")
        values[key] = specs[key].check(value, where)
        if key not in overridden:
            overridden.append(key)
    for rule in parsed.rules if parsed else ():  # across settings, before any work
        problem = rule.problem(values)
        if problem:
            given = " (with --set)" if overridden else ""
            raise SettingsError(f"settings of {experiment} at scale {scale}{given}: {problem}")
    return Settings(experiment, scale, values, specs, overridden, parsed.variants if parsed else None)
