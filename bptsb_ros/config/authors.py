"""Translate the authors' experiment YAML (flat camelCase: ``simTime``, ``lr_spring``, ``nodes``, …) into ours.

The authors published one flat file per experiment (``task: Lissajous``, ``simTime: 2000``, ``lr_spring:
10000``, …). :func:`import_config` turns such a mapping into an experiment config of ours: the task's packaged
config (``config/<name>.yaml``) supplies every value their file does not give, :data:`MAPPING` translates the
keys it knows, and the result is validated by :func:`bptsb_ros.config.validate`. Nothing is dropped silently:
the :class:`ImportResult` lists every key mapped (their key → our key, value, unit conversion), every key
understood that needs no key of ours (``generatorDist: [all]``: an SWG on every spring, as ours), every default
filled (our key = value, from which packaged config) and every key left unmapped (named, with its value and
why). :meth:`ImportResult.yaml_text` writes all of it as a comment header above the config.

Units: their ``simTime`` is seconds of simulated time (our ``sim_time``; for the episodic time-series tasks the
episode length, our ``narma.n_inputs`` = simTime / (timeStep · tau)); ``tau`` and ``updateTimeScale`` are steps,
as ours; ``nodes`` counts every mass, fixed ones included, as our ``body.nodes``.

Their file is untrusted data: bounded plain YAML (no tags), a mapping; a value of the wrong type, an unknown
task or an unknown enumerated value (shape, brain, optimiser) is an :class:`ImportFailure`, one line.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from bptsb_ros.config import MAX_CONFIG_BYTES, ConfigError, ExperimentConfig, config_dir, echo, safe_yaml, validate
from bptsb_ros.files.safe_write import UnsafeFileError, open_regular, read_regular, write_text_atomic

MARKER = "# written by bptsb config import from the authors' config; `bptsb config import --force` may replace it"
"""First line of every file :func:`write_output` writes; a file without it is never overwritten."""


class ImportFailure(ValueError):
    """Their file cannot be imported; the one-line message names the problem (and the key)."""


class Unmappable(Exception):  # noqa: N818 - a signal from a converter, not an error of the import
    """Raised by a converter: this key's value has no counterpart in our config (the message says why)."""


class TaskSpec(NamedTuple):
    family: str
    """the authors' task (their ``task:`` value, normalised): lissajous, locomotion, narma, memory, mnist"""
    packaged: str | None
    """our packaged config (``config/<packaged>.yaml``) that supplies the defaults; None: no config of ours"""
    summary: str


TASKS: dict[str, TaskSpec] = {
    "lissajous-single": TaskSpec("lissajous", "lissajous_single", "Lissajous curve drawing, one curve"),
    "lissajous-switching": TaskSpec("lissajous", "lissajous_single",
                                    "Lissajous switching by wind: our config holds the training settings; the "
                                    "second curve and the wind are set by bptsb reproduce lissajous-switching"),
    "locomotion-forward": TaskSpec("locomotion", "locomotion_forward", "locomotion, forward motion"),
    "locomotion-headwind": TaskSpec("locomotion", "locomotion_headwind", "locomotion switching under a headwind"),
    "narma": TaskSpec("narma", "narma", "expanded NARMA emulation"),
    "memory": TaskSpec("memory", "narma", "memory task y(t) = u(t - delay) (our narma config, narma.target memory)"),
    "mnist": TaskSpec("mnist", None, "MNIST drawing / classification"),
}
"""Our names for the authors' tasks (``--task``), in the order a family's variants are tried (plain first)."""

_THEIR_TASKS = {"lissajous": "lissajous", "locomotion": "locomotion", "expandednarma": "narma", "narma": "narma",
                "memory": "memory", "mnist": "mnist"}
_OUR_TASK = {"lissajous": "lissajous", "locomotion": "locomotion", "narma": "narma", "memory": "narma"}
_EXPERIMENTS = {"swg": "training", "train": "training", "training": "training", "closedloop": "closedloop",
                "perturbation": "perturbation", "switchingdynamics": "switching-dynamics"}
"""Their ``experiment:`` values (normalised) → the kind of run: a training, the FL fit, or an evaluation."""
_REPRODUCE = {("lissajous", "closedloop"): "lissajous-closed-loop",
              ("locomotion", "closedloop"): "locomotion-closed-loop-20",
              ("lissajous", "perturbation"): "lissajous-perturbation",
              ("locomotion", "perturbation"): "locomotion-perturbation",
              ("lissajous", "switching-dynamics"): "lissajous-switching",
              ("locomotion", "switching-dynamics"): "locomotion-headwind"}
"""The ``bptsb reproduce`` experiment that runs each of their evaluation protocols."""
_HINTS = {"lissajous": ("lissajous1", "lissajous2", "generatorDist"), "locomotion": ("generatorNum",),
          "memory": ("cumulative", "lr_readoutlayer"),
          "mnist": ("pixel", "batchSize", "fixedImages", "dataSize", "testDataSize", "char", "deltaScale")}
"""Keys that only one of their tasks uses: the task of a file without ``task:``."""


def _norm(text: str) -> str:
    return re.sub(r"[^a-z0-9]", "", text.lower())


# -- value checks: a wrong type is an ImportFailure naming their key ----------------------------------------------
def _number(key: str, value: Any, *, integer: bool = False, minimum: float | None = None,
            positive: bool = False) -> float | int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ImportFailure(f"{key}: expected a finite number, got {echo(value)}")
    if integer:
        if value != int(value):
            raise ImportFailure(f"{key}: expected a whole number, got {echo(value)}")
        value = int(value)
    if positive and value <= 0 or minimum is not None and value < minimum:
        bound = "> 0" if positive else f">= {minimum:g}"
        raise ImportFailure(f"{key}: expected a number {bound}, got {echo(value)}")
    return value


def _text(key: str, value: Any) -> str:
    if not isinstance(value, str):
        raise ImportFailure(f"{key}: expected text, got {echo(value)}")
    return value


def _bool(key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ImportFailure(f"{key}: expected true or false, got {echo(value)}")
    return value


def _list(key: str, value: Any) -> list:
    if not isinstance(value, list):
        raise ImportFailure(f"{key}: expected a list, got {echo(value)}")
    return value


def _choice(key: str, value: Any, choices: Mapping[str, Any], spelled: str) -> Any:
    got = choices.get(_norm(_text(key, value)))
    if got is None:
        raise ImportFailure(f"{key}: unknown value {echo(value)} (the authors' values: {spelled})")
    return got


# -- the converters -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Conv:
    """A converted value with what the conversion did (shown in the report)."""

    value: Any
    detail: str = ""


@dataclass
class _Context:
    source: Mapping[str, Any]
    task: str
    kind: str
    ours: dict[str, Any]  # the packaged config, resolved (model defaults included)
    key: str = ""  # their key being converted
    target: str | None = None  # our key it goes to (None: no key of ours)

    @property
    def family(self) -> str:
        return TASKS[self.task].family

    def number(self, key: str, our_key: str, **check: Any) -> float | int:
        """Their ``key`` if their file has it, else our packaged value of ``our_key``."""
        if key in self.source:
            return _number(key, self.source[key], **check)
        node: Any = self.ours
        for part in our_key.split("."):
            node = node[part]
        return node


Converter = Callable[[Any, _Context], Any]


def _same(check: Callable[..., Any], detail: str = "", **kw: Any) -> Converter:
    """A converter for a value in the same unit as ours: type-checked (``check(key, value, **kw)``), passed on."""
    def convert(value: Any, ctx: _Context) -> Conv:
        return Conv(check(ctx.key, value, **kw), detail)
    return convert


def _task_settings(family: str) -> dict[str, Any]:
    """What our task name fixes in our config (also without a ``task:`` in their file, from ``--task``)."""
    out: dict[str, Any] = {"task": _OUR_TASK[family]}
    if family in ("narma", "memory"):
        out["narma"] = {"target": "memory" if family == "memory" else "expanded"}
    return out


def _task(value: Any, ctx: _Context) -> Conv:
    return Conv(_task_settings(ctx.family), f"read as --task {ctx.task}")


def _experiment(value: Any, ctx: _Context) -> str:
    kind = _EXPERIMENTS.get(_norm(_text("experiment", value)))
    if kind is None:
        raise Unmappable(f"unknown experiment (known: {', '.join(sorted(set(_EXPERIMENTS)))}); read as a training")
    if kind in ("perturbation", "switching-dynamics"):
        raise Unmappable(f"an evaluation of a trained agent, run by bptsb reproduce "
                         f"{_REPRODUCE.get((ctx.family, kind), '(none for this task)')}; this config is the training's")
    if kind == "closedloop":
        return (f"the closed-loop FL fit: our feedback section (bptsb reproduce "
                f"{_REPRODUCE.get((ctx.family, kind), '(none for this task)')} runs the protocol)")
    return "a training run: what our config describes"


def _sim_time(value: Any, ctx: _Context) -> Conv:
    seconds = _number("simTime", value, positive=True)
    if ctx.target is None:
        raise Unmappable(f"the length [s] of the {ctx.kind} run; our config has no key for it (bptsb reproduce "
                         f"{_REPRODUCE.get((ctx.family, ctx.kind), '…')} sets it)")
    dt = ctx.number("timeStep", "body.dt", positive=True)
    steps = seconds / dt
    if ctx.target == "narma.n_inputs":
        tau = ctx.number("tau", "narma.tau", integer=True, minimum=1)
        n = steps / tau
        if abs(n - round(n)) > 1e-6 * max(1.0, abs(n)):
            raise ImportFailure(f"simTime: {seconds:g} s is not a whole number of inputs ({seconds:g} s / "
                                f"({dt:g} s x tau {tau}) = {n:g})")
        return Conv(int(round(n)), f"episode of {seconds:g} s / ({dt:g} s x tau {tau} steps) = {round(n)} inputs")
    what = "the FL fit's open-loop run" if ctx.target == "feedback.fit_time" else "simulated training time"
    return Conv(float(seconds), f"{what} [s], as ours ({steps:.10g} steps at dt {dt:g} s)")


def _tau(value: Any, ctx: _Context) -> Any:
    tau = _number("tau", value, integer=True, minimum=1)
    if ctx.target is None:
        raise Unmappable("steps per input/control interval: our Lissajous and locomotion configs hold no input "
                         "(the SWG runs continuously), so nothing of ours depends on it")
    return Conv(tau, "steps per input, as ours")


def _brain(value: Any, ctx: _Context) -> Conv:
    kind = _choice("brain", value, {"swg": "swg", "fl": "fl", "mlp": "mlp", "lil": "lil"}, "SWG, FL, MLP, LIL")
    if kind == "fl":
        return Conv({"brain": {"type": "swg"}, "feedback": {"enabled": True}},
                    "FL: the feedback layer over an SWG-trained agent")
    return Conv({"brain": {"type": kind}})


def _shape(value: Any, ctx: _Context) -> Conv:
    shapes = {"doublecircles": "double_circle", "doublecircle": "double_circle",
              "multiplecircles": "multiple_circle", "multiplecircle": "multiple_circle",
              "caterpillarrobot": "caterpillar", "caterpillar": "caterpillar"}
    return Conv(_choice("shape", value, shapes, "DoubleCircles, MultipleCircles, CaterpillarRobot"))


def _optim(value: Any, ctx: _Context) -> Conv:
    return Conv(_choice("optim", value, {"sgd": "sgd", "adam": "adam"}, "SGD, Adam"))


def _state(value: Any, ctx: _Context) -> Conv:
    states = {"springlength": "spring_length", "position": "position", "velocity": "velocity",
              "acceleration": "acceleration"}
    return Conv(_choice("reservoirStateType", value, states, "springLength, position, velocity, acceleration"))


def _lr(key: str) -> Converter:
    def convert(value: Any, ctx: _Context) -> Conv:
        return Conv(float(_number(key, value, minimum=0)), "learning rate, as ours")
    return convert


def _readout_lr(value: Any, ctx: _Context) -> str:
    if _number("lr_readoutlayer", value, minimum=0) != 0:
        raise Unmappable("a trained readout layer: our output is the CMP's raw y, no readout is trained")
    return "0: no readout layer trained; our output is the CMP's raw y"


def _input_scale(value: Any, ctx: _Context) -> Any:
    scale = _number("inputScale", value)
    if ctx.target is not None:
        return Conv(float(scale), "force scale of the input, as ours")
    if ctx.task == "locomotion-headwind":
        return "the headwind's strength: used by wind -> locomotion.wind_force"
    if ctx.task == "lissajous-switching":
        raise Unmappable("the wind's strength: our lissajous config has no wind (bptsb reproduce "
                         "lissajous-switching trains with F_wind = 1)")
    if scale == 0:
        return "0: no external input, as our task"
    raise Unmappable("an input scale for a task that has no input in our config")


def _wind(value: Any, ctx: _Context) -> Any:
    on = _bool("wind", value)
    if ctx.target is not None:  # locomotion.wind_force [N]
        if not on:
            return Conv(0.0, "no wind")
        scale = _number("inputScale", ctx.source.get("inputScale", 1))
        return Conv(-1.0 * scale, f"headwind F_wind = -1 N x inputScale {scale:g} (the paper's F_wind = -1; the "
                                  "published code pushed -15 N x inputScale and +1 N upward)")
    if not on:
        return "no wind, as our task"
    raise Unmappable("our lissajous config has no wind: bptsb reproduce lissajous-switching trains with F_wind = 1 "
                     "(the published code: 15 N x inputScale)")


def _curve(key: str, value: Any) -> tuple[float, float, float]:
    """Their curve ``[α, β, p, q]`` → (α, β, δ = π·p/q) [rad]."""
    items = _list(key, value)
    if len(items) != 4:
        raise ImportFailure(f"{key}: expected [alpha, beta, p, q] (delta = pi*p/q), got {echo(value)}")
    a, b, p, q = (_number(key, v) for v in items)
    if q == 0:
        raise ImportFailure(f"{key}: q (the 4th entry, delta = pi*p/q) must not be 0, got {echo(value)}")
    return float(a), float(b), math.pi * p / q


def _lissajous1(value: Any, ctx: _Context) -> Any:
    a, b, delta = _curve("lissajous1", value)
    if ctx.target is None:
        raise Unmappable(f"a Lissajous curve in a {ctx.family} config")
    p, q = value[2], value[3]
    return Conv({"alpha": a, "beta": b, "delta": delta}, f"[alpha, beta, p, q]: delta = pi*{p:g}/{q:g} rad")


def _lissajous2(value: Any, ctx: _Context) -> str:
    if _list("lissajous2", value) == []:
        return "empty: no second curve (single-curve task)"
    a, b, delta = _curve("lissajous2", value)
    raise Unmappable(f"the switching task's second curve (alpha, beta, delta) = ({a:g}, {b:g}, {delta:.6g}): our "
                     "lissajous config holds one curve; bptsb reproduce lissajous-switching runs (2, 1, pi/2) as the "
                     "paper says and this config's protocol as its variant 'authors'")


def _noise(value: Any, ctx: _Context) -> Any:
    sigma = _number("noise", value, minimum=0)
    if ctx.target is not None:
        return Conv(float(sigma), "sigma of the FL fit's input noise, as ours")
    if sigma == 0:
        return "0: no noise in training, as ours"
    raise Unmappable("noise during SWG training: ours trains without noise (feedback.noise is the FL fit's)")


def _all_springs(key: str, everything: list, what: str) -> Converter:
    def convert(value: Any, ctx: _Context) -> str:
        if _list(key, value) == everything:
            return f"{what} on every spring, as ours"
        raise Unmappable(f"{what} on some springs only: ours are on every spring")
    return convert


def _episodic(key: str, note: str, **check: Any) -> Converter:
    def convert(value: Any, ctx: _Context) -> Any:
        got = _number(key, value, **check)
        if ctx.target is None:
            raise Unmappable(f"no key of ours for it in a {ctx.family} config")
        return Conv(got, note)
    return convert


def _delay(value: Any, ctx: _Context) -> Any:
    got = _number("delay", value, integer=True, minimum=0)
    if ctx.target is None:
        raise Unmappable(f"no key of ours for it in a {ctx.family} config")
    if ctx.target == "narma.order":
        return Conv(_number("delay", got, integer=True, minimum=1), "the NARMA order m (delay 2: m = 2)")
    return Conv(got, "the memory task's delay [task steps]")


def _cumulative(value: Any, ctx: _Context) -> str:
    raise Unmappable("not described by the paper or the published-code notes; our memory target is "
                     "y(t) = u(t - delay)")


class Rule(NamedTuple):
    targets: Mapping[str, str | None]
    """where their key goes, by context (the first of: the kind of run, our task name, the authors' task, "*"
    that this mapping names): our dotted key, "" for several keys at once (the converter returns a mapping), or
    None: no key of ours (the converter then returns why the value needs none, or raises Unmappable)"""
    convert: Converter
    note: str


_TS = ("narma", "memory")
MAPPING: dict[str, Rule] = {
    "task": Rule({"*": ""}, _task, "the task: task (and narma.target for expandedNARMA / memory)"),
    "experiment": Rule({"*": None}, _experiment, "the kind of run; a training or FL fit, else unmapped"),
    "simTime": Rule({"closedloop": "feedback.fit_time", "perturbation": None, "switching-dynamics": None,
                     "narma": "narma.n_inputs", "memory": "narma.n_inputs", "*": "sim_time"}, _sim_time,
                    "seconds of simulated time: sim_time; episodic tasks: n_inputs = simTime/(timeStep*tau); "
                    "closed loop: feedback.fit_time"),
    "timeStep": Rule({"*": "body.dt"}, _same(_number, "integration step [s], as ours", positive=True),
                     "integration time step [s]"),
    "tau": Rule({"narma": "narma.tau", "memory": "narma.tau", "*": None}, _tau, "steps per input interval"),
    "brain": Rule({"*": ""}, _brain, "SWG/MLP/LIL: brain.type; FL: brain.type swg + feedback.enabled"),
    "shape": Rule({"*": "body.shape"}, _shape, "DoubleCircles/MultipleCircles/CaterpillarRobot"),
    "size": Rule({"*": "body.size"}, _same(_number, "diameter [m], as ours", positive=True), "body diameter [m]"),
    "nodes": Rule({"*": "body.nodes"}, _same(_number, "every mass, fixed ones included, as ours", integer=True,
                                             minimum=2), "number of masses, fixed ones included"),
    "neighbours": Rule({"*": "body.neighbours"}, _same(_number, "caterpillar links per mass, as ours", integer=True,
                                                       minimum=1), "caterpillar: mass k links to k+1..k+n"),
    "optim": Rule({"*": "training.optimizer"}, _optim, "SGD/Adam"),
    "updateTimeScale": Rule({"*": "training.update_steps"},
                            _same(_number, "truncated window [steps], as ours", integer=True, minimum=1),
                            "truncated BPTT window [steps]"),
    "lr_spring": Rule({"*": "training.lr.k"}, _lr("lr_spring"), "learning rate of the spring constants k"),
    "lr_damping": Rule({"*": "training.lr.d"}, _lr("lr_damping"), "learning rate of the damping d"),
    "lr_restlength": Rule({"*": "training.lr.l"}, _lr("lr_restlength"), "learning rate of the rest lengths l"),
    "lr_amplitude": Rule({"*": "training.lr.amplitude"}, _lr("lr_amplitude"), "learning rate of the SWG A"),
    "lr_phase": Rule({"*": "training.lr.phase"}, _lr("lr_phase"), "learning rate of the SWG phase"),
    "lr_brain": Rule({"*": "training.lr.brain"}, _lr("lr_brain"), "learning rate of the LIL/MLP weights"),
    "lr_readoutlayer": Rule({"*": None}, _readout_lr, "0: no trained readout (ours has none)"),
    "inputScale": Rule({"narma": "narma.input_scale", "memory": "narma.input_scale", "*": None}, _input_scale,
                       "time series: narma.input_scale; headwind: the wind's strength (see wind)"),
    "wind": Rule({"locomotion": "locomotion.wind_force", "*": None}, _wind,
                 "locomotion: locomotion.wind_force = -inputScale N when true, 0 when false"),
    "lissajous1": Rule({"lissajous": "lissajous", "*": None}, _lissajous1,
                       "[alpha, beta, p, q]: lissajous.alpha, .beta, .delta = pi*p/q"),
    "lissajous2": Rule({"*": None}, _lissajous2, "the switching task's second curve ([] : none)"),
    "noise": Rule({"closedloop": "feedback.noise", "*": None}, _noise,
                  "closed loop: feedback.noise; training: 0 (no noise)"),
    "generatorDist": Rule({"*": None}, _all_springs("generatorDist", ["all"], "an SWG"), "[all]: SWGs everywhere"),
    "generatorNum": Rule({"*": None}, _all_springs("generatorNum", [-1], "an SWG"), "[-1]: SWGs everywhere"),
    "feedbackSprings": Rule({"*": None}, _all_springs("feedbackSprings", ["all"], "the FL"),
                            "[all]: the FL on every spring"),
    "reservoirStateType": Rule({"*": "feedback.state"}, _state, "the FL's input state"),
    "epoch": Rule({"narma": "epochs", "memory": "epochs", "*": None},
                  _episodic("epoch", "training episodes, as ours", integer=True, minimum=1), "training episodes"),
    "delay": Rule({"narma": "narma.order", "memory": "narma.delay", "*": None}, _delay,
                  "expanded NARMA: the order m; memory: the delay"),
    "cumulative": Rule({"*": None}, _cumulative, "undocumented; unmapped"),
}
"""The authors' keys → where they go in our config (:class:`Rule`: our dotted key by context, converter, note)."""


# -- the result ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Mapped:
    their_key: str
    their_value: Any
    ours: tuple[tuple[str, Any], ...]  # (our dotted key, value) pairs
    detail: str


@dataclass(frozen=True)
class Understood:
    their_key: str
    their_value: Any
    why: str


@dataclass(frozen=True)
class Default:
    our_key: str
    value: Any
    source: str


@dataclass(frozen=True)
class Unmapped:
    their_key: str
    their_value: Any
    why: str


@dataclass
class ImportResult:
    """Our config (raw mapping ``data`` and validated ``config``) and the account of every key."""

    task: str
    origin: str
    data: dict[str, Any]
    config: ExperimentConfig
    defaults_from: str
    mapped: list[Mapped] = field(default_factory=list)
    understood: list[Understood] = field(default_factory=list)
    defaults: list[Default] = field(default_factory=list)
    unmapped: list[Unmapped] = field(default_factory=list)

    def report_lines(self) -> list[str]:
        """The account, one entry a line (what ``bptsb config import`` prints and writes as the header)."""
        b = self.config.body
        from bptsb_ros.body.shapes import build_shape

        topo = build_shape(b.shape, b.nodes, b.size, b.neighbours)
        fixed = int(topo.fixed.sum())
        lines = [f"source: {_shown(self.origin)} (the authors' form)",
                 f"task: {self.task} ({TASKS[self.task].summary}) -> "
                 + ", ".join(f"{k} = {echo(v)}" for k, v in _leaves(_task_settings(TASKS[self.task].family)))
                 + f"; defaults from {self.defaults_from}",
                 f"body: {b.shape}, {topo.n_masses} masses ({fixed} fixed, {topo.n_masses - fixed} movable), "
                 f"{topo.n_springs} springs",
                 "mapped (their key: value -> our key = value):"]
        for m in self.mapped:
            ours = ", ".join(f"{k} = {echo(v)}" for k, v in m.ours)
            lines.append(f"  {_shown(m.their_key)}: {echo(m.their_value)} -> {ours}" + (f"  ({m.detail})" if m.detail
                                                                                        else ""))
        lines.append("understood, nothing to set (their value is what our code does):")
        lines += [f"  {_shown(u.their_key)}: {echo(u.their_value)}  ({u.why})" for u in self.understood] or ["  none"]
        lines.append(f"defaults (our key = value, from {self.defaults_from}; keys in neither file take config.py's "
                     "defaults, `bptsb config show FILE` prints them all):")
        lines += [f"  {d.our_key} = {echo(d.value)}" for d in self.defaults] or ["  none"]
        lines.append("not mapped (named here, not in the config):")
        lines += [f"  {_shown(u.their_key)}: {echo(u.their_value)}  ({u.why})" for u in self.unmapped] or ["  none"]
        return lines

    def yaml_text(self) -> str:
        """The file ``bptsb config import --out`` writes: :data:`MARKER`, the account as comments, our config."""
        header = [MARKER, *(f"# {line}" for line in self.report_lines())]
        body = yaml.safe_dump(self.data, sort_keys=False, allow_unicode=True)
        return "\n".join(header) + "\n\n" + body


def _shown(text: Any) -> str:
    """A key or name from their file, printable on one line (quoted repr when it is not plain)."""
    return text if isinstance(text, str) and text.isprintable() and len(text) <= 80 else echo(text)


# -- the import ---------------------------------------------------------------------------------------------------
def detect_task(source: Mapping[str, Any], requested: str | None = None) -> str:
    """Our task name (a key of :data:`TASKS`) for their file: ``requested`` (``--task``) if given and compatible
    with their ``task:``, else from ``task:`` (and ``wind`` / ``lissajous2`` / ``experiment`` for the switching
    variants), else from the keys only one task uses; :class:`ImportFailure` when it cannot tell."""
    family = None
    if "task" in source:
        their = _text("task", source["task"])
        family = _THEIR_TASKS.get(_norm(their))
        if family is None:
            raise ImportFailure(f"task: unknown task {echo(their)} (the authors' tasks: Lissajous, locomotion, "
                                "expandedNARMA, memory, MNIST)")
    if requested is not None:
        if requested not in TASKS:
            raise ImportFailure(f"--task: unknown task {echo(requested)} (known: {', '.join(TASKS)})")
        if family is not None and TASKS[requested].family != family:
            raise ImportFailure(f"--task {requested} does not fit the file's task: {source['task']}")
        return requested
    if family is None:
        hinted = sorted({f for f, keys in _HINTS.items() if any(k in source for k in keys)}
                        | ({"locomotion"} if _norm(str(source.get("shape", ""))).startswith("caterpillar") else set()))
        if len(hinted) != 1:
            raise ImportFailure("cannot tell the task from the file's keys (it has no task:); name it with --task "
                                f"({', '.join(TASKS)})")
        family = hinted[0]
    variants = [name for name, spec in TASKS.items() if spec.family == family]
    if len(variants) == 1:
        return variants[0]
    second = source.get("lissajous2")
    switching = (source.get("wind") is True or isinstance(second, list) and len(second) > 0
                 or _norm(str(source.get("experiment", ""))) == "switchingdynamics")
    return variants[1] if switching else variants[0]


def _packaged(name: str) -> tuple[dict[str, Any], str]:
    path = config_dir() / f"{name}.yaml"
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ImportFailure(f"cannot read the packaged config {path}: {err.strerror or err}") from None
    data = safe_yaml(text, f"packaged config {path}") or {}
    data.pop("profiles", None)  # variants of the packaged experiment, not of theirs
    data.pop("profile", None)
    return data, f"config/{name}.yaml"


def _put(data: dict[str, Any], dotted: str, value: Any) -> None:
    node = data
    *parents, last = dotted.split(".")
    for part in parents:
        node = node.setdefault(part, {})
    if isinstance(value, dict) and isinstance(node.get(last), dict):
        _merge(node[last], value)
    else:
        node[last] = copy.deepcopy(value)


def _merge(base: dict[str, Any], patch: Mapping[str, Any]) -> None:
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)


def _leaves(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for key, value in data.items():
        if isinstance(value, dict):
            out += _leaves(value, f"{prefix}{key}.")
        else:
            out.append((f"{prefix}{key}", value))
    return out


def _one_line(err: ConfigError) -> str:
    """A ConfigError's key lines on one line, without its "invalid configuration ...:" heading."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].startswith("invalid configuration"):
        lines = lines[1:]
    return "; ".join(re.sub(r"^\(top level\): Value error, (.*) \(got .*\)$", r"\1", line) for line in lines)


def import_config(source: Any, task: str | None = None, origin: str = "(mapping)") -> ImportResult:
    """Our experiment config from their mapping ``source`` (see the module docstring); ``task`` is ``--task``.

    Raises :class:`ImportFailure` (one line) for anything that cannot be imported."""
    if not isinstance(source, dict):
        raise ImportFailure(f"{_shown(origin)}: the authors' config must be a mapping of keys, got "
                            f"{type(source).__name__}")
    name = detect_task(source, task)
    spec = TASKS[name]
    if spec.packaged is None:
        raise ImportFailure(f"{name}: bptsb_ros has no experiment config for the MNIST tasks (config.py knows "
                            "lissajous, locomotion, narma); bptsb reproduce mnist-drawing, mnist-pca, mnist-labelmap, "
                            "... set their hyperparameters")
    packaged, defaults_from = _packaged(spec.packaged)
    experiment = source.get("experiment")
    kind = _EXPERIMENTS.get(_norm(experiment), "training") if isinstance(experiment, str) else "training"
    data = copy.deepcopy(packaged)
    fixed = _task_settings(spec.family)
    _merge(data, fixed)
    try:
        ours = validate(copy.deepcopy(packaged), defaults_from).model_dump(mode="json")
    except ConfigError as err:
        raise ImportFailure(f"the packaged config is invalid: {_one_line(err)}") from None
    ctx = _Context(source, name, kind, ours)
    mapped: list[Mapped] = []
    understood: list[Understood] = []
    unmapped: list[Unmapped] = []
    written = {k for k, _ in _leaves(fixed)}
    selectors = (kind, name, spec.family, "*")
    for key, value in source.items():
        rule = MAPPING.get(key) if isinstance(key, str) else None
        if rule is None:
            unmapped.append(Unmapped(key, value, "not a key of the authors' form that this importer knows"))
            continue
        ctx.key, ctx.target = key, next(rule.targets[s] for s in selectors if s in rule.targets)
        try:
            got = rule.convert(value, ctx)
        except Unmappable as why:
            unmapped.append(Unmapped(key, value, str(why)))
            continue
        if ctx.target is None:
            understood.append(Understood(key, value, str(got)))
            continue
        conv = got if isinstance(got, Conv) else Conv(got)
        if ctx.target == "":
            _merge(data, conv.value)
            pairs = _leaves(conv.value)
        else:
            _put(data, ctx.target, conv.value)
            pairs = (_leaves(conv.value, ctx.target + ".") if isinstance(conv.value, dict)
                     else [(ctx.target, conv.value)])
        written.update(k for k, _ in pairs)
        mapped.append(Mapped(key, value, tuple(pairs), conv.detail))
    defaults = [Default(k, v, defaults_from) for k, v in _leaves(packaged) if k not in written]
    try:
        config = validate(copy.deepcopy(data), f"imported from {_shown(origin)}")
    except ConfigError as err:
        raise ImportFailure(f"the imported config does not validate: {_one_line(err)}") from None
    return ImportResult(name, origin, data, config, defaults_from, mapped, understood, defaults, unmapped)


def read_their_file(path: str | Path) -> Any:
    """Their YAML file parsed as bounded plain data (a regular file of at most MAX_CONFIG_BYTES, no tags)."""
    try:
        raw = read_regular(path, MAX_CONFIG_BYTES)
    except UnsafeFileError as err:
        raise ImportFailure(str(err)) from None
    except FileNotFoundError:
        raise ImportFailure(f"{_shown(str(path))}: no such file") from None
    except OSError as err:
        raise ImportFailure(f"cannot read {_shown(str(path))}: {err.strerror or err}") from None
    try:
        return safe_yaml(raw.decode("utf-8"), f"config file {_shown(str(path))}")
    except UnicodeDecodeError:
        raise ImportFailure(f"{_shown(str(path))} is not UTF-8 text") from None
    except ConfigError as err:
        raise ImportFailure(str(err)) from None


def import_file(path: str | Path, task: str | None = None) -> ImportResult:
    """:func:`import_config` of the file ``path``."""
    return import_config(read_their_file(path), task, origin=str(path))


def write_output(text: str, out: str | Path, force: bool = False) -> Path:
    """Write ``text`` to ``out`` atomically. An existing ``out`` is replaced only with ``force`` and only when its
    first line is :data:`MARKER` (a file this command wrote); anything else is refused (ImportFailure)."""
    out = Path(out)
    if out.is_symlink():
        raise ImportFailure(f"{_shown(str(out))} is a symbolic link; bptsb config import does not write through it")
    if out.exists():
        try:
            with open_regular(out) as f:
                first = f.readline(4096).decode("utf-8", errors="replace").rstrip("\r\n")
        except (UnsafeFileError, OSError) as err:
            raise ImportFailure(f"{_shown(str(out))} exists and cannot be checked ({err}); choose another --out") \
                from None
        if first != MARKER:
            raise ImportFailure(f"{_shown(str(out))} exists and was not written by bptsb config import (its first "
                                "line is not the marker); it is never overwritten, choose another --out")
        if not force:
            raise ImportFailure(f"{_shown(str(out))} exists (written by bptsb config import); pass --force to "
                                "replace it")
    write_text_atomic(out, text)
    return out


def mapping_table() -> list[str]:
    """:data:`MAPPING` as lines ``their key -> our key (by context): note`` (for documentation)."""
    def where(target: str | None) -> str:
        return "(several)" if target == "" else target or "(no key of ours)"

    return [f"{key} -> " + ", ".join(where(t) if s == "*" else f"{s}: {where(t)}" for s, t in rule.targets.items())
            + f"  ({rule.note})" for key, rule in MAPPING.items()]
