"""Declared, described and validated ROS parameters for the live nodes.

Each node lists its parameters as :class:`Param` specs. :func:`~bptsb_ros.ros.declare_params.declare_parameters`
declares them on the node (with a ``ParameterDescriptor`` carrying the description and constraints), reads the
values given by ``--ros-args -p`` or ``--params-file`` and validates them, raising :class:`ParameterError` naming
the parameter. :func:`render_params_yaml` writes the defaults in the standard ``/**: ros__parameters:`` layout
(the files under ``config/``).

**Live parameters.** A parameter with ``dynamic=True`` can be changed while the node runs
(``ros2 param set /body_sim rate_scale 2.0``): a parameter callback validates the new value with the same
rules (a bad one is refused with the reason, the old value stays), lets the node apply it, and updates the
values dict the node reads. Every other parameter is read-only; the reason is part of its description
(``ros2 param describe``), from :data:`READ_ONLY_REASONS`. :data:`LOG_LEVEL` (every node) sets the node's
logger level live.

The module is ROS-free: the declaration on an rclpy node is :func:`bptsb_ros.ros.declare_params.declare_parameters`.
"""

from __future__ import annotations

import array
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

Kind = Literal["bool", "int", "float", "optional_float", "str", "str_list", "float_list", "cpus"]
ParamValue = bool | int | float | str | list[str] | list[float]


class ParameterError(ValueError):
    """A node parameter is missing, of the wrong type or out of range; the message names it."""


@dataclass(frozen=True)
class Param:
    """One node parameter.

    Attributes:
        name: parameter name (``topics.positions`` style dots nest in YAML).
        default: default value; its Python type must match ``kind``.
        description: one line with the unit, shown by ``ros2 param describe``.
        kind: value type.
        choices: allowed values (str or str_list items).
        minimum, maximum: inclusive numeric bounds (int/float).
        positive: numeric value must be > 0.
        dynamic: may be changed while the node runs (``ros2 param set``); otherwise read-only.
        size: float_list: required number of values.
    """

    name: str
    default: ParamValue
    description: str
    kind: Kind
    choices: tuple[str, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    positive: bool = False
    dynamic: bool = False
    size: int | None = None

    def constraints(self) -> str:
        """Human-readable constraints (``ParameterDescriptor.additional_constraints``)."""
        parts = []
        if self.choices:
            parts.append("one of " + ", ".join(c or "''" for c in self.choices))
        if self.positive:
            parts.append("> 0")
        if self.minimum is not None:
            parts.append(f">= {self.minimum:g}")
        if self.maximum is not None:
            parts.append(f"<= {self.maximum:g}")
        if self.size is not None:
            parts.append(f"{self.size} values")
        return "; ".join(parts)

    def validate(self, value: Any) -> ParamValue:
        """Coerce ``value`` to this parameter's kind and check it; raise ParameterError naming the parameter."""
        v = _coerce(self, value)
        if self.kind == "float_list":
            if self.size is not None and len(v) != self.size:
                raise ParameterError(f"parameter '{self.name}' must have {self.size} values, got {len(v)}")
            if not all(math.isfinite(x) for x in v):
                raise ParameterError(f"parameter '{self.name}' must be finite, got {v}")
        if self.kind == "optional_float" and v == "":
            return v
        if self.kind in ("int", "float", "optional_float"):
            if not math.isfinite(v):
                raise ParameterError(f"parameter '{self.name}' must be finite, got {v}")
            if self.positive and not v > 0:
                raise ParameterError(f"parameter '{self.name}' must be > 0, got {v}")
            if self.minimum is not None and v < self.minimum:
                raise ParameterError(f"parameter '{self.name}' must be >= {self.minimum:g}, got {v}")
            if self.maximum is not None and v > self.maximum:
                raise ParameterError(f"parameter '{self.name}' must be <= {self.maximum:g}, got {v}")
        if self.choices is not None:
            items = v if isinstance(v, list) else [v]
            bad = [item for item in items if item not in self.choices]
            if bad:
                raise ParameterError(
                    f"parameter '{self.name}': {', '.join(map(repr, bad))} not allowed; choose from "
                    f"{', '.join(self.choices)}"
                )
        return v


def _coerce(spec: Param, value: Any) -> ParamValue:
    kind, name = spec.kind, spec.name
    if kind == "bool":
        if isinstance(value, bool):
            return value
    elif kind == "int":
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif kind == "float":
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind == "optional_float":  # a number, or '' for "not given" (the node then uses its own default)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):
            if not value.strip():
                return ""
            try:
                return float(value)
            except ValueError:
                pass
    elif kind == "str":
        if isinstance(value, str):
            return value
    elif kind == "str_list":
        if value is None or (isinstance(value, Sequence) and not isinstance(value, str) and len(value) == 0):
            return []  # ROS reports an empty list as NOT_SET or an empty byte array
        if isinstance(value, Sequence) and not isinstance(value, str) and all(isinstance(x, str) for x in value):
            return list(value)
    elif kind == "float_list":
        if isinstance(value, (array.array, Sequence)) and not isinstance(value, (str, bytes)) and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
            return [float(x) for x in value]
    elif kind == "cpus":  # taskset -c text; ROS reads a bare number (-p cpus:=1) as an int, [0, 2] as an int array
        if isinstance(value, str):
            return value
        if isinstance(value, int) and not isinstance(value, bool):
            return str(value)
        if isinstance(value, (array.array, Sequence)) and not isinstance(value, bytes) and all(
                isinstance(x, int) and not isinstance(x, bool) for x in value):
            return ",".join(map(str, value))
    expected = {"bool": "a bool", "int": "an integer", "float": "a number", "optional_float": "a number or ''",
                "str": "a string",
                "str_list": "a list of strings", "float_list": "a list of numbers",
                "cpus": "CPU numbers ('1', '0,2', '0-3', 1 or [0, 2])"}[kind]
    raise ParameterError(f"parameter '{name}' must be {expected}, got {value!r} ({type(value).__name__})")


#: Why a read-only parameter cannot change while the node runs, by name, or by prefix for ``prefix.*``.
READ_ONLY_REASONS: dict[str, str] = {
    "executor": "the node's subscriptions, timers and services are added to its executor once, at startup",
    "raw_outputs": "the per-step messages are laid out once, at startup",
    "batch_wait": "the recorder's loop is set up once, at startup",
    "cpus": "the node's threads are placed once, when it starts stepping or answering (threads made later inherit it)",
    **dict.fromkeys(("agent", "config", "task", "shape", "nodes", "size", "dt", "integrator", "brain_type", "seed",
                     "dtype"), "the agent (body and brain) is built from it once, at startup, and every node of "
                    "the loop must hold the same one"),
    "topics.*": "publishers and subscriptions are created at startup (remap with -r from:=to instead)",
    "qos_depth": "QoS is fixed when the publishers and subscriptions are created",
    "mode": "the timing loop (lockstep or realtime) is chosen at startup",
    **dict.fromkeys(("duration", "wall_duration", "max_steps"), "the run length is fixed at startup: the "
                    "launcher, the run summary and the bag describe the run it gives"),
    **dict.fromkeys(("wait_for", "wait_for_subscribers", "startup_timeout", "min_subscribers"),
                    "only used while the loop starts up"),
    **dict.fromkeys(("command_timeout", "max_command_age", "min_rest_length", "max_rest_length", "max_force",
                     "max_wind", "command_publishers", "perturb_publishers", "on_divergence", "control_callers",
                     "pause_timeout"),
                    "a safety rule: it must hold for the whole run and not be loosened by anyone who can reach the "
                    "parameter services"),
    **dict.fromkeys(("final_ack_timeout", "summary_path"), "only used when the node stops; set it at startup"),
    "timing_path": "the records cover every step of the run from the first; they are written when the node stops",
    **dict.fromkeys(("rt_priority", "busy_wait"), "the scheduling policy is set once, when stepping begins"),
    "frame_id": "viewers and the bag expect one frame for the whole run",
    "every_step": "a node of the loop reads these topics every step from the start (the launchers set it for the "
                  "loop's brains); a topic must not thin out under it",
    "start_paused": "only the start; the ~/pause and ~/resume services pause and resume the running body",
    **dict.fromkeys(("open_loop_steps", "input_seed", "tau", "input_scale", "perturb_at", "perturb_sigma",
                     "perturb_seed", "schedule", "force", "force_y", "period", "schedule_seed", "hold_periods",
                     "timing", "start_on", "file"), "part of the run's definition "
                    "that the offline comparison of the bag (bptsb replay) reproduces"),
    "noise_seed": "the noise generator is seeded once, so that a run with noise can be repeated",
    **dict.fromkeys(("images", "labels", "first", "count", "episode_steps", "reset_every"), "the image stream and "
                    "its episodes are the run's definition, which the bag records and bptsb replay splits and "
                    "compares offline"),
    **dict.fromkeys(("bag_path", "chunk_size", "compression", "custom_data"), "the bag is opened with it at "
                    "startup"),
    **dict.fromkeys(("topics", "exclude_topics", "include_hidden_topics", "discovery_period", "queue_depth"),
                    "the topic selection and subscriptions are set up at startup, so the bag holds one consistent "
                    "set"),
    **dict.fromkeys(("flush_period", "drain_quiet", "stop_timeout"), "part of the recorder's guarantee of what "
                    "survives a kill or a stop; fixed for the whole recording"),
    **dict.fromkeys(("wait_for_recorder", "recorder_window", "recorder_timeout", "recorder_publishers", "ack_topic",
                     "ack_topics", "allow_loss"), "part of the guarantee that the recording is complete (or its "
                    "losses counted and reported); fixed for the whole run"),
}
#: Reason of a read-only parameter missing from :data:`READ_ONLY_REASONS`.
DEFAULT_READ_ONLY_REASON = "read once, when the node starts"

#: The ``executor`` choices of a live node (body_sim and the brains; ``bptsb bench --realtime --executor``).
EXECUTORS = ("events", "single")
#: The rclpy executor of a live node (body_sim and the brains).
EXECUTOR = Param("executor", "events", "rclpy executor of the node: events (rclpy.experimental.EventsExecutor, "
                 "dispatch in C++; where this rclpy lacks it: single) or single (SingleThreadedExecutor)", "str",
                 choices=EXECUTORS)
#: Pre-serialized per-step outputs (:mod:`bptsb_ros.ros.raw_out`).
RAW_OUTPUTS = Param("raw_outputs", True, "publish the per-step outputs as pre-serialized bytes (the same messages, "
                    "without building message objects every step); false: message objects", "bool")
#: Logger level of a node, live (every node declares it).
LOG_LEVEL = Param("log_level", "", "logger level of this node: debug, info, warn or error (debug shows per-message "
                  "and per-topic lines); empty: as set by --ros-args --log-level (default info)", "str",
                  choices=("", "debug", "info", "warn", "error"), dynamic=True)
#: The CPUs a live node runs on (``bptsb_ros.live.scheduling.pin_threads``).
CPUS = Param("cpus", "", "CPUs to run every thread of this node on, as taskset -c lists them ('1', '0,2', '0-3'), set "
             "when it starts stepping or answering (in a composed process, the body's apply to every node); "
             "docs/ros/timing.md has what one core for the body and its brains measured at 100 Hz and 1 kHz; empty: "
             "wherever it was started", "cpus")


def read_only_reason(p: Param) -> str:
    """Why ``p`` is read-only ('' for a dynamic parameter)."""
    if p.dynamic:
        return ""
    if p.name in READ_ONLY_REASONS:
        return READ_ONLY_REASONS[p.name]
    head = p.name.split(".", 1)[0]
    return READ_ONLY_REASONS.get(f"{head}.*", DEFAULT_READ_ONLY_REASON)


def describe(p: Param) -> str:
    """The description ``ros2 param describe`` shows: the text, then whether and why it can change live."""
    if p.dynamic:
        return f"{p.description} [dynamic: ros2 param set applies it while the node runs]"
    return f"{p.description} [read-only: {read_only_reason(p)}]"


def check_specs(specs: Sequence[Param]) -> None:
    """Raise ValueError if names repeat or a default fails its own validation (programming errors)."""
    names = [p.name for p in specs]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"duplicate parameter names: {sorted(dup)}")
    for p in specs:
        p.validate(p.default)


def validate_values(specs: Sequence[Param], values: dict[str, Any]) -> dict[str, ParamValue]:
    """Validate raw values (missing ones take the default); raise ParameterError on the first bad one."""
    known = {p.name for p in specs}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}")
    return {p.name: p.validate(values.get(p.name, p.default)) for p in specs}


#: Applies a live change: called with (name, validated value) before the value is committed; raising
#: ParameterError refuses the change with that message.
OnChange = Callable[[str, ParamValue], None]


def apply_changes(specs: Sequence[Param], values: dict[str, ParamValue], changes: Sequence[tuple[str, Any]],
                  on_change: OnChange | None = None) -> str:
    """Validate and apply live changes (name, raw value) to ``values``: '' when all were applied, else the reason
    the whole set was refused (nothing is applied then, except by an ``on_change`` that already ran).

    Parameters not in ``specs`` (``use_sim_time``, ...) are left to ROS. A read-only one is refused (ROS refuses
    it before this runs; the check keeps this function safe on its own).
    """
    by_name = {p.name: p for p in specs}
    checked: list[tuple[str, ParamValue]] = []
    for name, raw in changes:
        spec = by_name.get(name)
        if spec is None:
            continue
        if not spec.dynamic:
            return f"parameter '{name}' is read-only: {read_only_reason(spec)}"
        try:
            checked.append((name, spec.validate(raw)))
        except ParameterError as err:
            return str(err)
    try:
        for name, value in checked:
            if on_change is not None:
                on_change(name, value)
    except ParameterError as err:
        return str(err)
    for name, value in checked:
        values[name] = value
    return ""


def yaml_value(value: ParamValue) -> str:
    """A parameter value as YAML (params files, ``--ros-args -p name:=value``): strings single-quoted so YAML
    keeps them strings (``'123'``), lists in flow style."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    return "''" if value == "" else "'" + value.replace("'", "''") + "'"


def params_sections_text(sections: Mapping[str, Mapping[str, ParamValue]],
                         extra: Mapping[str, Sequence[str]] | None = None) -> str:
    """A ROS 2 params file of given values: one ``ros__parameters`` section per key of ``sections`` (a node pattern:
    ``/**`` for any node, ``/**/body_sim`` for that node in any namespace), its parameters in order, then
    ``extra[key]``'s ``NAME:=VALUE`` texts (the value already YAML, as ``-p`` reads it). Empty lists are left out:
    rcl cannot type an empty YAML list, and every list parameter's default is what an empty one would set."""
    lines = []
    for key, params in sections.items():
        lines += [f"{key}:", "  ros__parameters:"]
        lines += [f"    {name}: {yaml_value(value)}" for name, value in params.items() if value != []]
        for item in (extra or {}).get(key, ()):
            name, _, value = item.partition(":=")
            lines.append(f"    {name}: {value}")
    return "\n".join(lines) + "\n"


def render_params_yaml(node_name: str, specs: Sequence[Param],
                       extra: Sequence[tuple[str, ParamValue, str]] = ()) -> str:
    """The defaults of ``specs`` as a ROS 2 params file (``/**: ros__parameters:``), descriptions as comments.

    ``extra`` adds (name, value, comment) entries for parameters the node does not declare itself
    (e.g. ``use_sim_time``, declared by every rclpy node).
    """
    lines = [
        f"# Parameters of the {node_name} node (defaults). Use with",
        f"#   bptsb run {node_name} --ros-args --params-file config/{node_name}_params.yaml",
        "# or in a launch file; override single values with --ros-args -p name:=value.",
        "# [dynamic] ones can also be changed while the node runs (ros2 param set); the others are read-only",
        "# (ros2 param describe says why).",
        "/**:",
        "  ros__parameters:",
    ]
    for name, value, comment in extra:
        lines.append(f"    # {comment}")
        lines.append(f"    {name}: {yaml_value(value)}")
    groups: dict[str, list[Param]] = {}
    for p in specs:
        head = p.name.split(".", 1)[0] if "." in p.name else ""
        groups.setdefault(head, []).append(p)
    for p in groups.get("", []):
        lines.append(f"    # {p.description}" + (f" ({p.constraints()})" if p.constraints() else "")
                     + (" [dynamic]" if p.dynamic else ""))
        lines.append(f"    {p.name}: {yaml_value(p.default)}")
    for head, params in groups.items():
        if not head:
            continue
        lines.append(f"    {head}:")
        for p in params:
            lines.append(f"      # {p.description}" + (" [dynamic]" if p.dynamic else ""))
            lines.append(f"      {p.name.split('.', 1)[1]}: {yaml_value(p.default)}")
    return "\n".join(lines) + "\n"
