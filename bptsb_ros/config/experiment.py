"""Experiment configuration: YAML files validated into typed models.

Every experiment is one YAML file under ``config/``. Unknown keys and wrong types are errors that
name the key (``training.lr.k: Input should be a valid number``). Durations are ``sim_time``
(seconds of simulated time, continuous tasks) and ``epochs`` (episodic tasks), so
``--set sim_time=20`` or ``--set epochs=2`` shortens any run.

Profiles: a file may name variants of itself in a top-level ``profiles:`` mapping (profile name → a partial
config, merged key by key over the file). ``profile: NAME`` in the file or ``--set profile=NAME`` selects one;
the other ``--set`` overrides apply after it, and the resolved config records the profile's name
(``config/narma.yaml``: ``--set profile=paper_table`` trains with the paper's learning-rate table).

Untrusted input is bounded: a config file is at most ``MAX_CONFIG_BYTES``, its YAML may expand (aliases
included) to at most ``MAX_YAML_NODES`` nodes, every float must be finite, and error messages echo at most
``ECHO_CHARS`` characters of an offending value.
"""

from __future__ import annotations

import copy
import difflib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from bptsb_ros.body.shapes import MAX_MASSES, SHAPES, build_shape
from bptsb_ros.files.untrusted_yaml import UntrustedYamlError, bounded_repr, load_untrusted_yaml

TASKS = ("lissajous", "locomotion", "narma")
MAX_CONFIG_BYTES = 1 << 20
"""Largest config file read [bytes]."""
MAX_YAML_NODES = 10_000
"""Most YAML nodes a config (or a ``--set`` value) may hold once its aliases are expanded."""
ECHO_CHARS = 80
"""Most characters of an offending value an error message repeats."""


class ConfigError(ValueError):
    """A configuration file or override is invalid; the message names the offending key."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


class BodyConfig(_Strict):
    shape: Literal[SHAPES] = "double_circle"  # type: ignore[valid-type]  # the registry of body/shapes.py
    nodes: int = Field(25, ge=2, le=MAX_MASSES, description="number of masses, fixed ones included")
    size: float = Field(4.0, gt=0, le=1000.0, description="diameter of circular bodies [m]")
    neighbours: int = Field(3, ge=1, description="caterpillar: mass k links to k+1..k+neighbours")
    dt: float = Field(0.01, gt=0, le=1.0, description="integration time step [s]")
    integrator: Literal["verlet", "published"] = "verlet"
    k_init: tuple[float, float] = (1.0, 100.0)
    d_init: tuple[float, float] = (0.0, 10.0)
    environment: Literal["none", "locomotion"] = "none"
    ground_clamp: bool = False

    @model_validator(mode="after")
    def _ranges(self) -> BodyConfig:
        for key in ("k_init", "d_init"):
            lo, hi = getattr(self, key)
            if not 0 <= lo <= hi:
                raise ValueError(f"{key} must be a range [low, high] with 0 <= low <= high, got [{lo}, {hi}]")
        return self


class BrainConfig(_Strict):
    type: Literal["swg", "mlp", "lil"] = "swg"
    amplitude: float = Field(0.5, description="SWG initial amplitude A")
    omega: float = Field(6.283185307179586, gt=0, description="SWG angular frequency [rad/s], not trained")
    hidden: int = Field(128, ge=1, description="MLP hidden width")
    gain: float = Field(1.0, gt=0, description="MLP Xavier gain")


class LearningRates(_Strict):
    """Per-parameter learning rates (paper, Table 'Learning rates')."""

    k: float = Field(1e4, ge=0)
    d: float = Field(1e3, ge=0)
    l: float = Field(1e1, ge=0)  # noqa: E741 - the paper's symbol
    amplitude: float = Field(1e1, ge=0)
    phase: float = Field(1e2, ge=0)
    brain: float = Field(1e-1, ge=0, description="LIL/MLP weights and biases")


class TrainingConfig(_Strict):
    optimizer: Literal["sgd", "adam"] = "sgd"
    update_steps: int = Field(100, ge=1, description="truncated window length (updateTimeScale) [steps]")
    lr: LearningRates = LearningRates()
    adjoint: bool = Field(True, description="hand-derived backward (fast); False uses plain autograd")
    backend: Literal["numba", "torch", "fused"] = Field(
        "numba", description="body integration: numba (compiled window kernel, fastest on CPU), torch (the "
                             "reference; GPU) or fused (numba; an SWG training window, loss, gradients and "
                             "the SGD update as compiled calls without autograd: Lissajous, switching and "
                             "locomotion with SGD; NARMA and memory: each episode one compiled node, any "
                             "optimiser; anything else trains on numba)")
    projection: Literal["clamp", "reset"] = Field(
        "clamp", description="after each update, k, d, l below zero are clamped to 0 (clamp, the paper) or reset to "
                             "0.1 (reset, the authors' published code); the fused backend has clamp only and trains "
                             "on numba with reset")
    lr_decay: bool = Field(
        False, description="divide every learning rate by 10 at 80 % and again at 90 % of the updates when there are "
                           "more than 1,000 (the authors' switching trainings)")
    reject_factor: float = Field(
        0.0, ge=0, description="the update guard's spike rule: reject (undo) an update whose loss exceeds factor × the "
                               "previous loss (the mean of the last 5 once there are 5); 0: off. Non-finite losses, "
                               "gradients and diverged simulations are always rejected (bptsb_ros.training.guard)")
    reject_patience: int = Field(5, ge=1, description="divide all learning rates by 10 after this many rejections "
                                                      "(two good updates in a row reset the count)")
    checkpoint_every: int = Field(0, ge=0, description="updates between checkpoints (0: only at the end)")
    log_every: int = Field(10, ge=1)


class FeedbackConfig(_Strict):
    """Feedback layer fit (closed loop), for SWG agents."""

    enabled: bool = True
    state: Literal["spring_length", "position", "velocity", "acceleration"] = "spring_length"
    noise: float = Field(0.08, ge=0, description="σ of Gaussian noise added to the inputs while fitting")
    fit_time: float = Field(100.0, gt=0, description="open-loop run used for the fit [s]")
    criterion: Literal["aic", "gcv"] = "aic"


class LissajousConfig(_Strict):
    alpha: float = 1.0
    beta: float = 2.0
    delta: float = 0.0
    amplitude_fraction: float = Field(0.05, gt=0, description="X = Y = fraction × diameter (paper: 1/20)")
    eval_periods: int = Field(10, ge=1)


class LocomotionConfig(_Strict):
    target_slope: float = Field(0.004, ge=0, description="v_target(t) = slope × t [m/s per s of training]")
    warmup_windows: int = Field(100, ge=0, description="windows simulated without updates before training")
    speed_block: int = Field(100, ge=1, description="steps per block over which speed is averaged")
    loss_velocity: Literal["after", "before"] = Field(
        "after", description="speed in the loss from each step's velocity after its update (ours) or before it "
                             "(the published code)")
    eval_time: float = Field(20.0, gt=0, description="evaluation run [s]")
    target_speed: float | None = Field(
        None, description="constant target speed [m/s] instead of the ramp (headwind switching: v_max / 2)")
    wind_force: float = Field(0.0, description="F_wind [N]: force along x on every mass while the wind blows "
                                               "(headwind < 0)")
    wind_period: float = Field(0.0, ge=0, description="wind cycle [s]: calm for the first half of each period, "
                                                      "blowing for the second; 0: blows all the time")


class NarmaConfig(_Strict):
    order: int = Field(2, ge=1, description="m, the NARMA delay")
    tau: int = Field(20, ge=1, description="simulation steps per input")
    n_inputs: int = Field(150, ge=10, description="inputs per episode")
    washout: int = Field(30, ge=0, description="inputs discarded at the start")
    train_end: int = Field(120, description="samples washout..train_end-1 train; the rest test")
    input_scale: float = Field(20.0, gt=0, description="force scale: brain input = scale × u")
    brain_input: Literal["unit", "symmetric"] = Field(
        "unit", description="brain input = input_scale × u (unit: the paper's text, u in [0, 1] → (0, 20)) or "
        "input_scale × (2u − 1) (symmetric: the published code, (−20, 20)); the target always uses u in [0, 1]")
    target: Literal["expanded", "memory"] = Field(
        "expanded", description="expanded NARMA (main text) or the memory task y(t) = u(t − delay) (supplement)")
    delay: int = Field(8, ge=0, description="memory task: Δt, the delay in task steps")
    eval_seed: int = 12345


class ExperimentConfig(_Strict):
    task: Literal["lissajous", "locomotion", "narma"]
    name: str = ""
    profile: str = Field("", description="the profile of the file's 'profiles:' applied (recorded; '' none)")
    seed: int = 0
    dtype: Literal["float32", "float64"] = "float32"
    sim_time: float = Field(100.0, gt=0, description="simulated training time [s] (continuous tasks)")
    epochs: int = Field(1, ge=1, description="training episodes (episodic tasks)")
    body: BodyConfig = BodyConfig()
    brain: BrainConfig = BrainConfig()
    training: TrainingConfig = TrainingConfig()
    feedback: FeedbackConfig = FeedbackConfig()
    lissajous: LissajousConfig = LissajousConfig()
    locomotion: LocomotionConfig = LocomotionConfig()
    narma: NarmaConfig = NarmaConfig()

    @model_validator(mode="after")
    def _consistent(self) -> ExperimentConfig:
        if self.task in ("lissajous", "locomotion") and self.brain.type != "swg":
            raise ValueError(f"task {self.task!r} needs brain.type 'swg', got {self.brain.type!r}")
        if self.task == "narma" and self.brain.type == "swg":
            raise ValueError("task 'narma' needs brain.type 'mlp' or 'lil'")
        if self.task == "locomotion" and self.body.shape != "caterpillar":
            raise ValueError("task 'locomotion' needs body.shape 'caterpillar'")
        if self.task != "locomotion" and self.body.shape == "caterpillar":
            raise ValueError(f"body.shape 'caterpillar' is the locomotion robot, not for task {self.task!r}")
        n = self.narma
        if self.task == "narma" and not (n.washout < n.train_end < n.n_inputs):
            raise ValueError("narma needs washout < train_end < n_inputs")
        if self.task == "locomotion" and self.training.update_steps % self.locomotion.speed_block:
            raise ValueError(f"training.update_steps ({self.training.update_steps}) must be a multiple of "
                             f"locomotion.speed_block ({self.locomotion.speed_block})")
        b = self.body
        try:
            build_shape(b.shape, b.nodes, b.size, b.neighbours)
        except ValueError as err:
            raise ValueError(f"body: {err}") from None
        kinds = ("amplitude", "phase") if self.brain.type == "swg" else ("brain",)
        if all(getattr(self.training.lr, k) == 0 for k in ("k", "d", "l", *kinds)):
            raise ValueError("training.lr: every learning rate is zero, nothing would be trained")
        return self


def echo(value: Any) -> str:
    """``repr`` of a user-supplied value, bounded to about ``ECHO_CHARS`` characters."""
    return bounded_repr(value, ECHO_CHARS)


def safe_yaml(text: str, what: str) -> Any:
    """Parse untrusted YAML (bounded in size and alias expansion); raises ConfigError naming ``what``."""
    try:
        return load_untrusted_yaml(text, what, max_bytes=MAX_CONFIG_BYTES, max_nodes=MAX_YAML_NODES)
    except UntrustedYamlError as err:
        raise ConfigError(str(err)) from None


def _section_model(path: Sequence[Any]) -> type[BaseModel] | None:
    """The model of the config section at ``path`` (``()``: the whole config); None where ``path`` is no section."""
    model: type[BaseModel] = ExperimentConfig
    for part in path:
        field = model.model_fields.get(part) if isinstance(part, str) else None
        annotation = field.annotation if field is not None else None
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


def config_keys() -> list[str]:
    """Every valid dotted key of an experiment config, sections and values (``training``, ``training.lr.k``)."""
    keys: list[str] = []

    def walk(path: list[str]) -> None:
        for name in _section_model(path).model_fields:
            keys.append(".".join([*path, name]))
            if _section_model([*path, name]) is not None:
                walk([*path, name])

    walk([])
    return keys


def did_you_mean(path: Sequence[Any]) -> str:
    """``"; did you mean training.lr.phase?"`` for the unknown key at ``path``, ``""`` when no valid key is close.

    Its last part is matched (difflib.get_close_matches) against the keys of the same section (cutoff 0.6) and,
    for a key put in the wrong section (``body.amplitude``), against the last parts of every other valid dotted
    key (stricter, cutoff 0.8); the closer of the two wins."""
    if not path:
        return ""
    name, parent = str(path[-1]), [str(p) for p in path[:-1]]
    section = _section_model(parent)
    siblings = {n: ".".join([*parent, n]) for n in [*(section.model_fields if section else ()),
                                                  *([] if parent else ["profiles"])]}
    others: dict[str, str] = {}
    for key in config_keys():
        head, _, last = key.rpartition(".")
        if head != ".".join(parent):
            others.setdefault(last, key)
    best, score = "", 0.0
    for names, cutoff in ((siblings, 0.6), (others, 0.8)):
        for match in difflib.get_close_matches(name, list(names), n=1, cutoff=cutoff):
            ratio = difflib.SequenceMatcher(None, name, match).ratio()
            if ratio > score:
                best, score = names[match], ratio
    return f"; did you mean {best}?" if best else ""


def _format_errors(err: ValidationError, source: str) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(top level)"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key" + did_you_mean(e["loc"])
        lines.append(f"  {loc}: {msg} (got {echo(e.get('input'))})")
    return f"invalid configuration {source}:\n" + "\n".join(lines)


def parse_override(text: str) -> tuple[list[str], Any]:
    """``a.b=value`` → (["a", "b"], YAML-parsed value)."""
    if "=" not in text:
        raise ConfigError(f"override {echo(text)} must look like key=value (e.g. sim_time=20)")
    key, raw = text.split("=", 1)
    path = [p for p in key.strip().split(".") if p]
    if not path:
        raise ConfigError(f"override {echo(text)} has an empty key")
    return path, safe_yaml(raw, f"override {echo(key)}")


def _shown_key(path: Sequence[str]) -> str:
    key = ".".join(path)
    return key if key.isprintable() and len(key) <= ECHO_CHARS else echo(key)


def check_override_key(path: Sequence[str]) -> None:
    """Raise ConfigError (one line, with a "did you mean" where a valid key is close) unless ``path`` names a
    key or section of an experiment config (anything under ``profiles`` is the file's own business)."""
    if path[0] == "profiles":
        return
    for i, part in enumerate(path):
        if _section_model(path[:i]) is None:
            raise ConfigError(f"override {_shown_key(path)}: {_shown_key(path[:i])} is a value, not a section")
        if part not in _section_model(path[:i]).model_fields:
            raise ConfigError(f"override {_shown_key(path[:i + 1])}: unknown key{did_you_mean(path[:i + 1])}")


Overrides = Sequence[str] | Mapping[str, Any]
"""Config overrides: ``--set`` texts ``["a.b=value", ...]`` (values parsed as YAML) or a mapping
``{"a.b": value}`` (values taken as they are)."""


def override_items(overrides: Overrides | None) -> list[tuple[list[str], Any, str]]:
    """Overrides → (key path, value, the override as named in messages), in order."""
    if overrides is None:
        return []
    if isinstance(overrides, str):
        raise ConfigError(f"overrides must be a list of key=value texts or a mapping, got the text {echo(overrides)}")
    if isinstance(overrides, Mapping):
        items = []
        for key, value in overrides.items():
            if not isinstance(key, str):
                raise ConfigError(f"override key {echo(key)} must be a text (a dotted key such as 'training.lr.k')")
            path = [p for p in key.strip().split(".") if p]
            if not path:
                raise ConfigError(f"override key {echo(key)} is empty")
            items.append((path, copy.deepcopy(value), f"{key}={echo(value)}"))
        return items
    for text in overrides:
        if not isinstance(text, str):
            raise ConfigError(f"override {echo(text)} must be a text key=value (e.g. 'sim_time=20')")
    return [(*parse_override(text), text) for text in overrides]


def override_mapping(overrides: Overrides | None) -> dict[str, Any]:
    """Overrides (``--set`` texts, values parsed as YAML, or a mapping) as one mapping ``{"a.b": value}``, in their
    order; a key given twice keeps its last value. How code composes overrides: ``{**base, "epochs": 3}``."""
    return {".".join(path): value for path, value, _ in override_items(overrides)}


def apply_overrides(data: dict, overrides: Overrides) -> dict:
    """Apply ``--set`` overrides (or a mapping of them) to a raw config mapping (validation happens afterwards)."""
    return _apply_items(data, override_items(overrides))


def _apply_items(data: dict, items: list[tuple[list[str], Any, str]]) -> dict:
    for path, value, text in items:
        check_override_key(path)
        node = data
        for part in path[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"override {echo(text)}: {echo(part)} is not a section")
            node = child
        node[path[-1]] = value
    return data


def _merge(base: dict, patch: dict) -> None:
    """Merge ``patch`` into ``base`` in place: nested mappings key by key, anything else replaced."""
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value)
        else:
            base[key] = value


def apply_profile(data: dict, source: str = "") -> dict:
    """Remove the ``profiles:`` mapping from a raw config and merge the one ``profile`` names into it."""
    profiles = data.pop("profiles", None)
    if profiles is None:
        profiles = {}
    if not isinstance(profiles, dict) or not all(isinstance(v, dict) for v in profiles.values()):
        raise ConfigError(f"profiles in {source or 'the config'} must map each profile name to a mapping of keys")
    name = data.get("profile", "")
    if name in (None, ""):  # ``--set profile=`` (YAML: null) selects none
        data.pop("profile", None)
        return data
    if not isinstance(name, str) or name not in profiles:
        known = ", ".join(sorted(map(str, profiles))) or "none"
        raise ConfigError(f"profile {echo(name)} is not defined in {source or 'the config'} (defined: {known})")
    _merge(data, profiles[name])
    return data


def validate(data: dict, source: str = "") -> ExperimentConfig:
    """Validate a raw mapping; raises ConfigError listing every bad key."""
    if not isinstance(data, dict):
        raise ConfigError(f"configuration {source} must be a mapping, got {type(data).__name__}")
    try:
        return ExperimentConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format_errors(err, source)) from None


def config_dir() -> Path:
    """The directory of the packaged experiment configs (:func:`bptsb_ros.files.package_data.config_dir`: the
    installed package's copy, a source checkout's ``config/``, or the ament share); ConfigError if none is there."""
    from bptsb_ros.files.package_data import PackageDataError
    from bptsb_ros.files.package_data import config_dir as packaged_dir

    try:
        return packaged_dir()
    except PackageDataError as err:
        raise ConfigError(str(err)) from None


def load_config(path: str | Path, overrides: Overrides | None = None, seed: int | None = None) -> ExperimentConfig:
    """Read, override and validate an experiment YAML (``overrides``: see :data:`Overrides`)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file not found: {path}")
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ConfigError(f"config file {path} is {path.stat().st_size} bytes; the limit is {MAX_CONFIG_BYTES}")
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"config file {path} is not UTF-8 text") from None
    except OSError as err:
        raise ConfigError(f"cannot read config file {path}: {err.strerror or err}") from None
    data = safe_yaml(text, f"config file {path}") or {}
    if not isinstance(data, dict):
        raise ConfigError(f"configuration {path} must be a mapping, got {type(data).__name__}")
    items = override_items(overrides)
    chosen = [item for item in items if item[0] == ["profile"]]  # the profile first, the rest over it
    data = apply_profile(_apply_items(data, chosen), str(path))
    data = _apply_items(data, [item for item in items if item[0] != ["profile"]])
    if seed is not None:
        data["seed"] = seed
    cfg = validate(data, str(path))
    if not cfg.name:
        cfg.name = path.stem
    return cfg
