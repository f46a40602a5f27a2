"""What each scale of a ``bptsb reproduce`` experiment means, as data: ``settings/<experiment>.yaml``.

A settings file declares every setting once (its type, bounds and a help text) and gives its value at each
scale::

    settings:
      epochs: {type: int, min: 1, help: training epochs per system}
      n_train: {type: int, nullable: true, min: 1, help: "training images (null: every image of the split)"}
    smoke: {epochs: 1, n_train: 50}
    short: {epochs: 3, n_train: null}
    paper: {epochs: 50, n_train: null}

Types: ``int``, ``float`` (an int is taken as a float), ``number`` (an int or a float, kept as written: a
duration the code passes on as it is), ``str``, ``bool`` and ``list[T]`` of those (a tuple in the code).
Declaration keys besides ``type`` and ``help``: ``min`` and ``max`` (inclusive; of every item of a list),
``length`` (of a list), ``nullable`` (null allowed) and ``choices`` (the allowed texts of a ``str`` or
``list[str]``). Every scale gives exactly the declared settings.

An optional ``variants`` section names protocols an experiment runs side by side in one result (each with its
own rows and claims), each a help text and the declared settings it changes::

    variants:
      paper: {help: "the paper's text", set: {}}
      authors: {help: "the authors' published code", set: {draw: authors, eval_periods: 3}}

``ctx.settings.variants`` maps each name to its help; ``ctx.settings.variant(name)`` gives the run's values
with that variant's changes (checked against the same declarations).

The file is read with the project's bounded safe YAML loader; every problem is one :class:`SettingsError`
line naming the file and the setting, with a "did you mean" for a misspelt name. ``--set KEY=VALUE``
overrides (:func:`resolve_settings`) are checked against the same declarations. An experiment reads its
values as ``ctx.settings["epochs"]``; the resolved values are recorded in result.json (``settings``).
"""

from __future__ import annotations

import difflib
import json
import math
import re
import shlex
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bptsb_ros.safe_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

#: the packaged settings files, one per experiment (``<experiment name>.yaml``)
SETTINGS_DIR = Path(__file__).resolve().with_name("settings")
SCALES = ("smoke", "short", "paper")
SECTIONS = ("settings", *SCALES, "variants")
SCALAR_TYPES = ("int", "float", "number", "str", "bool")
TYPES = (*SCALAR_TYPES, *(f"list[{t}]" for t in SCALAR_TYPES))
SPEC_KEYS = ("type", "help", "min", "max", "length", "nullable", "choices")
VARIANT_KEYS = ("help", "set")
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
    choices: tuple[str, ...] | None = None

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
            if self.choices is not None and value not in self.choices:
                raise SettingsError(f"{where} must be one of {', '.join(self.choices)}, got {got}"
                                    f"{_close(value, self.choices)}")
            return value
        if kind == "bool":
            if not isinstance(value, bool):
                raise SettingsError(f"{where} must be true or false, got {got}")
            return value
        if kind == "int" and (isinstance(value, bool) or not isinstance(value, int)):
            raise SettingsError(f"{where} must be an integer, got {got}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SettingsError(f"{where} must be a number, got {got}")
        if self.min is not None and value < self.min:
            raise SettingsError(f"{where} must be ≥ {_num(self.min)}, got {got}")
        if self.max is not None and value > self.max:
            raise SettingsError(f"{where} must be ≤ {_num(self.max)}, got {got}")
        return float(value) if kind == "float" else value


@dataclass(frozen=True)
class ParsedSettings:
    """A checked settings file: the declarations and every scale's values (checked, as the code uses them)."""

    source: str
    specs: dict[str, SettingSpec]
    values: dict[str, dict[str, Any]]
    variants: dict[str, tuple[str, dict[str, Any]]] | None = None
    """name → (help, the settings it changes, checked); None: the file has no variants section"""


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
    length = raw.get("length")
    if length is not None and (not raw["type"].startswith("list[") or isinstance(length, bool)
                               or not isinstance(length, int) or length < 0):
        raise SettingsError(f"{where}.length is a list's number of items (an integer ≥ 0), got {bounded_repr(length)}")
    if not isinstance(raw.get("nullable", False), bool):
        raise SettingsError(f"{where}.nullable must be true or false, got {bounded_repr(raw['nullable'])}")
    choices = raw.get("choices")
    if choices is not None and (raw["type"] not in ("str", "list[str]") or not isinstance(choices, list) or not choices
                                or not all(isinstance(c, str) for c in choices)):
        raise SettingsError(f"{where}.choices is a non-empty list of texts, for a str or list[str] setting; got "
                            f"{bounded_repr(choices)}")
    return SettingSpec(name, raw["type"], " ".join(raw["help"].split()), raw.get("min"), raw.get("max"), length,
                       raw.get("nullable", False), tuple(choices) if choices is not None else None)


def _variants(raw: Any, specs: Mapping[str, SettingSpec], source: str) -> dict[str, tuple[str, dict[str, Any]]]:
    """The checked ``variants`` section: name → (help, {setting: value})."""
    where = f"{source}: variants"
    if not isinstance(raw, Mapping) or not raw:
        raise SettingsError(f"{where} must map each variant's name to {{help: ..., set: {{...}}}}, got "
                            f"{bounded_repr(raw)}")
    out = {}
    for name, spec in raw.items():
        if not isinstance(name, str) or not SETTING_NAME.fullmatch(name):
            raise SettingsError(f"{where}: variant names are lower-case words ([a-z][a-z0-9_]*), got "
                                f"{bounded_repr(name)}")
        at = f"{where}.{name}"
        if not isinstance(spec, Mapping):
            raise SettingsError(f"{at} must be a mapping {{help: ..., set: {{...}}}}, got {bounded_repr(spec)}")
        for key in spec:
            if key not in VARIANT_KEYS:
                raise SettingsError(f"{at}.{_shown(key)}: unknown key{_close(key, VARIANT_KEYS)} "
                                    f"(known: {', '.join(VARIANT_KEYS)})")
        if not isinstance(spec.get("help"), str) or not spec["help"].strip():
            raise SettingsError(f"{at} needs a help text (help: which protocol it is)")
        changes = spec.get("set", {})
        if not isinstance(changes, Mapping):
            raise SettingsError(f"{at}.set must map declared settings to values, got {bounded_repr(changes)}")
        for key in changes:
            if key not in specs:
                raise SettingsError(f"{at}.set.{_shown(key)}: unknown setting{_close(key, list(specs))}")
        out[name] = (" ".join(spec["help"].split()),
                     {key: specs[key].check(value, f"{at}.set.{key}") for key, value in changes.items()})
    return out


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
    variants = _variants(doc["variants"], specs, source) if "variants" in doc else None
    return ParsedSettings(source, specs, values, variants)


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
                 variants: Mapping[str, tuple[str, Mapping[str, Any]]] | None = None) -> None:
        self.experiment, self.scale = experiment, scale
        self._values = dict(values)
        self.specs = dict(specs or {})
        self.overridden = tuple(overridden)
        self._variants = {name: (text, dict(changes)) for name, (text, changes) in (variants or {}).items()}

    @property
    def variants(self) -> dict[str, str]:
        """The settings file's variants, name → help, in file order (empty without a variants section)."""
        return {name: text for name, (text, _) in self._variants.items()}

    def variant(self, name: str) -> dict[str, Any]:
        """This run's values with the changes of variant ``name``."""
        if name not in self._variants:
            raise KeyError(f"{self.experiment} has no variant {name!r}{_close(name, list(self._variants))} "
                           f"(variants: {', '.join(self._variants) or 'none'})")
        return {**self._values, **self._variants[name][1]}

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

    def override_args(self) -> list[str]:
        """``--set key=value`` arguments that reproduce the overridden values (shell-quoted where needed)."""
        args = []
        for key in self.overridden:
            value = self._values[key]
            plain = isinstance(value, str) and _yaml_reads_back(value)
            text = value if plain else json.dumps(self.to_json()[key], separators=(",", ":"))
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
    return Settings(experiment, scale, values, specs, overridden, parsed.variants if parsed else None)
