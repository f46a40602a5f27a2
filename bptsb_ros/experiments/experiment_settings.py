"""What each scale of a ``bptsb reproduce`` experiment means: ``settings/<experiment>.yaml`` read into its model.

The settings of an experiment are declared once, as a pydantic model in
:mod:`~bptsb_ros.experiments.settings_models` (each setting's type, bounds and help text, and the rules across
settings). Its settings file gives only the values: one mapping per scale, each an instance of the model, and
optionally its named variants (profiles: the paper's text, the authors' published code), each an instance of the
model's ``variant_model``, the same at every scale (a variant is a protocol, not a size)::

    # settings/lissajous-switching.yaml
    smoke: {pretrain_time: 5, switching_time: 5, hold: [2, 3], ...}
    short: {pretrain_time: 1000, switching_time: 2000, hold: [3, 8], ...}
    paper: {pretrain_time: 2000, switching_time: 30000, hold: [3, 8], ...}
    variants:
      paper_wind: {label: "paper wind (F, 0)", published_wind: false, ...}
      authors: {label: "authors' protocol", published_wind: true, ...}

The file is read with the project's bounded safe YAML loader; every problem (a misspelt, missing or unknown
setting, a wrong type, a value out of bounds, a rule that fails) is one :class:`SettingsError` line naming the
file and the setting, with a "did you mean" for a misspelt name. ``--set KEY=VALUE`` overrides
(:func:`resolve_settings`) are checked by the same model. An experiment reads its values as
``ctx.settings["epochs"]`` (or ``ctx.settings.epochs``) and its variants as ``ctx.settings.variants`` (file order,
name → values); the resolved values are recorded in result.json (``settings``).
"""

from __future__ import annotations

import difflib
import json
import re
import shlex
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from bptsb_ros.experiments.settings_models import SETTINGS_MODELS, ExperimentSettings, VariantSettings, shown
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

#: the packaged settings files, one per experiment (``<experiment name>.yaml``)
SETTINGS_DIR = Path(__file__).resolve().with_name("settings")
SCALES = ("smoke", "short", "paper")
SECTIONS = (*SCALES, "variants")
VARIANT_NAME = re.compile(r"[a-z][a-z0-9_]*")
MAX_FILE_BYTES = 100_000
MAX_NODES = 5_000

Overrides = Sequence[str] | Mapping[str, Any]
"""``--set`` texts ``["epochs=3", ...]`` (values parsed as YAML) or a mapping ``{"epochs": 3}``."""


class SettingsError(ValueError):
    """A settings file or a ``--set`` override is not valid; one line naming the file or the override."""


def _close(name: Any, names: Sequence[str]) -> str:
    """``"; did you mean epochs?"`` when a name of ``names`` is close to ``name``, else ``""``."""
    match = difflib.get_close_matches(str(name), list(names), n=1, cutoff=0.6)
    return f"; did you mean {match[0]}?" if match else ""


def _reason(error: Mapping[str, Any]) -> str:
    """What pydantic's ``error`` says is wrong, in the words of the settings (a list, not a tuple)."""
    if error["type"] in ("value_error", "assertion_error"):
        return str(error.get("ctx", {}).get("error", error["msg"]))
    return error["msg"].replace("Tuple should", "List should").replace("a valid tuple", "a list")


def _one_line(err: ValidationError, model: type[BaseModel], setting: Callable[[str], str], rules: str, *,
              what: str = "setting", first: Sequence[str] = ()) -> str:
    """The first problem of ``err`` as one line: ``setting(key)`` names a setting (``key`` as ``hold[0]`` for an
    item), ``rules`` the whole (where a rule failed); ``first`` orders the errors (the ``--set`` keys as given)."""
    rank = {key: i for i, key in enumerate(first)}
    error = min(err.errors(include_url=False), key=lambda e: rank.get(e["loc"][0], len(rank)) if e["loc"] else 0)
    loc = error["loc"]
    if not loc:  # a model validator: a rule across settings
        return f"{rules}: {_reason(error)}"
    key = f"{loc[0]}" + "".join(f"[{part}]" for part in loc[1:] if isinstance(part, int))
    if error["type"] == "missing":
        return f"{rules} lacks the {what} {key}"
    if error["type"] == "extra_forbidden":
        return f"{setting(shown(loc[0]))}: unknown {what}{_close(loc[0], list(model.model_fields))}"
    return f"{setting(key)}: {_reason(error)}, got {bounded_repr(error['input'])}"


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


def _values(model: BaseModel) -> dict[str, Any]:
    """The fields of ``model`` as the code reads them (tuples stay tuples, ints ints, floats floats)."""
    return {name: getattr(model, name) for name in type(model).model_fields}


def _as_json(values: Mapping[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}


@dataclass(frozen=True)
class ParsedSettings:
    """A checked settings file: its model, each scale's values and the named variants (file order)."""

    source: str
    model: type[ExperimentSettings]
    values: dict[str, ExperimentSettings]
    variants: dict[str, VariantSettings] = field(default_factory=dict)


def parse_settings(doc: Any, source: str, model: type[ExperimentSettings]) -> ParsedSettings:
    """Check a settings document (YAML text, or the mapping it parses to) against ``model``; ``source`` names it
    in messages."""
    if isinstance(doc, (str, bytes)):
        try:
            doc = load_untrusted_yaml(doc, source, max_bytes=MAX_FILE_BYTES, max_nodes=MAX_NODES)
        except UntrustedYamlError as err:
            raise SettingsError(str(err)) from None
    if not isinstance(doc, Mapping):
        raise SettingsError(f"{source}: must be a mapping with the sections {', '.join(SECTIONS)}")
    for key in doc:
        if key not in SECTIONS:
            raise SettingsError(f"{source}: {shown(key)}: unknown section{_close(key, SECTIONS)} "
                                f"(sections: {', '.join(SECTIONS)}; the settings themselves are declared in "
                                f"{model.__name__}, settings_models.py)")
    values: dict[str, ExperimentSettings] = {}
    for scale in SCALES:
        given = doc.get(scale)
        if not isinstance(given, Mapping):
            raise SettingsError(f"{source}: no {scale} settings (a mapping of every setting of {model.__name__} "
                                "to its value)")
        try:
            values[scale] = model.model_validate(given)
        except ValidationError as err:
            raise SettingsError(_one_line(err, model, lambda key, s=scale: f"{source}: {s}.{key}",
                                          f"{source}: {scale}")) from None
    return ParsedSettings(source, model, values, _parse_variants(doc, source, model))


def _parse_variants(doc: Mapping, source: str, model: type[ExperimentSettings]) -> dict[str, VariantSettings]:
    """The checked ``variants`` of a settings document (none where the model has no variant model)."""
    given, variant_model = doc.get("variants"), model.variant_model
    if variant_model is None:
        if given is not None:
            raise SettingsError(f"{source}: variants: {model.__name__} has no variant model")
        return {}
    if not isinstance(given, Mapping) or not given:
        raise SettingsError(f"{source}: no variants (a mapping of each variant's name to its values: "
                            f"{variant_model.__name__})")
    out: dict[str, VariantSettings] = {}
    for name, values in given.items():
        if not isinstance(name, str) or not VARIANT_NAME.fullmatch(name):
            raise SettingsError(f"{source}: variants: variant names are lower-case words ([a-z][a-z0-9_]*), got "
                                f"{bounded_repr(name)}")
        if not isinstance(values, Mapping):
            raise SettingsError(f"{source}: variants.{name} must map every variant setting to its value, got "
                                f"{bounded_repr(values)}")
        try:
            out[name] = variant_model.model_validate(values)
        except ValidationError as err:
            raise SettingsError(_one_line(err, variant_model, lambda key, n=name: f"{source}: variants.{n}.{key}",
                                          f"{source}: variants.{name}", what="variant setting")) from None
    return out


def settings_path(experiment: str) -> Path:
    """The packaged settings file of ``experiment`` (it may not exist: an experiment without settings)."""
    return SETTINGS_DIR / f"{experiment}.yaml"


def settings_model(experiment: str) -> type[ExperimentSettings] | None:
    """The settings model of ``experiment`` (:data:`~bptsb_ros.experiments.settings_models.SETTINGS_MODELS`);
    None when it has no settings."""
    return SETTINGS_MODELS.get(experiment)


def load_settings_file(experiment: str) -> ParsedSettings | None:
    """The checked settings file of ``experiment``; None when it has neither a settings model nor a file."""
    path, model = settings_path(experiment), settings_model(experiment)
    if not path.is_file():
        if model is None:
            return None
        raise SettingsError(f"{experiment} has a settings model ({model.__name__}) but no settings file "
                            f"{path.name}")
    if model is None:
        raise SettingsError(f"settings file {path.name}: {experiment} has no settings model (SETTINGS_MODELS in "
                            "settings_models.py)")
    try:
        text = path.read_bytes()
    except OSError as err:
        raise SettingsError(f"{path}: unreadable ({err.strerror or err})") from None
    return parse_settings(text, f"settings file {path.name}", model)


def _yaml_reads_back(text: str) -> bool:
    """True when ``--set key=TEXT`` gives back the text itself (not ``3``, ``null`` or a list)."""
    try:
        return load_untrusted_yaml(text, "a text", max_bytes=10_000, max_nodes=1_000) == text
    except UntrustedYamlError:
        return False


class Settings(Mapping[str, Any]):
    """The resolved settings of one run (read-only): ``ctx.settings["epochs"]`` or ``ctx.settings.epochs``.

    ``model`` is the validated model instance (None for an experiment without settings), ``overridden`` the keys
    ``--set`` changed (in order), ``variants`` the named variants (file order), name → {variant setting: value}.
    """

    def __init__(self, experiment: str, scale: str, model: ExperimentSettings | None = None,
                 overridden: Sequence[str] = (), variants: Mapping[str, VariantSettings] | None = None) -> None:
        self.experiment, self.scale = experiment, scale
        self.model = model
        self._values: dict[str, Any] = _values(model) if model is not None else {}
        self.overridden = tuple(overridden)
        #: the named variants (file order), name → {variant setting: value}; empty when the file has none
        self.variants: dict[str, dict[str, Any]] = {name: _values(v) for name, v in (variants or {}).items()}

    def __getitem__(self, key: str) -> Any:
        try:
            return self._values[key]
        except KeyError:
            raise KeyError(f"{self.experiment} has no setting {key!r}{_close(key, list(self._values))} (its file: "
                           f"{settings_path(self.experiment).name})") from None

    def __getattr__(self, name: str) -> Any:
        """``ctx.settings.epochs``: a setting as an attribute (where no attribute of this class has its name)."""
        values = self.__dict__.get("_values")
        if name.startswith("_") or values is None or name not in values:
            raise AttributeError(f"{type(self).__name__} of {self.__dict__.get('experiment')} has no attribute or "
                                 f"setting {name!r}")
        return values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"Settings({self.experiment!r}, {self.scale!r}, {self._values!r})"

    def help_text(self, key: str) -> str:
        """The help text of the setting ``key`` (its field's description)."""
        info = type(self.model).model_fields.get(key) if self.model is not None else None
        return (info.description or "") if info is not None else ""

    def to_json(self) -> dict[str, Any]:
        """The values as JSON data (tuples as lists), for result.json."""
        return _as_json(self._values)

    def variants_json(self) -> dict[str, dict[str, Any]]:
        """The variants as JSON data (tuples as lists), for result.json."""
        return {name: _as_json(values) for name, values in self.variants.items()}

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
            note = self.help_text(key) + (" (--set)" if key in self.overridden else "")
            lines.append(f"{text.ljust(width)}  # {note}" if note else text)
        return "\n".join(lines) + "\n"


def _override_items(overrides: Overrides | None) -> list[tuple[str, Any]]:
    """(key, value) of each override, in order (``--set`` texts parsed as YAML)."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return list(overrides.items())
    if isinstance(overrides, str):
        raise SettingsError(f"settings overrides must be a list of key=value texts or a mapping, got the text "
                            f"{bounded_repr(overrides)}")
    items = []
    for text in overrides:
        if not isinstance(text, str) or "=" not in text:
            raise SettingsError(f"--set {shown(text)} must look like key=value (e.g. epochs=3)")
        key, raw = text.split("=", 1)
        key = key.strip()
        try:
            value = load_untrusted_yaml(raw, f"--set {shown(key)}", max_bytes=10_000, max_nodes=1_000)
        except UntrustedYamlError as err:
            raise SettingsError(str(err)) from None
        items.append((key, value))
    return items


def resolve_settings(experiment: str, scale: str, overrides: Overrides | None = None) -> Settings:
    """The settings of ``experiment`` at ``scale`` with ``overrides`` applied, checked by its model (an unknown
    key is refused, with a "did you mean" where one is close; the rules hold on the resolved values)."""
    if scale not in SCALES:
        raise SettingsError(f"scale must be one of {', '.join(SCALES)}, got {bounded_repr(scale)}")
    parsed = load_settings_file(experiment)
    names = list(parsed.model.model_fields) if parsed else []
    values = _values(parsed.values[scale]) if parsed else {}
    overridden: list[str] = []
    for key, value in _override_items(overrides):
        if key not in names:
            known = f"{_close(key, names)}" if names else " (it has no settings)"
            raise SettingsError(f"--set {shown(key)}: unknown setting of {experiment}{known}")
        values[key] = value
        if key not in overridden:
            overridden.append(key)
    if parsed is None:
        return Settings(experiment, scale)
    try:
        model = parsed.model.model_validate(values) if overridden else parsed.values[scale]
    except ValidationError as err:
        raise SettingsError(_one_line(err, parsed.model, lambda key: f"--set {key}",
                                      f"settings of {experiment} at scale {scale} (with --set)",
                                      first=overridden)) from None
    return Settings(experiment, scale, model, overridden, parsed.variants)
