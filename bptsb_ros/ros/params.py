"""Declared, described and validated ROS parameters for the live nodes.

Each node lists its parameters as :class:`Param` specs. :func:`declare_parameters` declares them on the
node (with a ``ParameterDescriptor`` carrying the description and constraints, read-only), reads the
values given by ``--ros-args -p`` or ``--params-file`` and validates them, raising
:class:`ParameterError` naming the parameter. :func:`render_params_yaml` writes the defaults in the
standard ``/**: ros__parameters:`` layout (the files under ``config/``).

The module itself is ROS-free; rclpy is imported only inside :func:`declare_parameters`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from rclpy.node import Node

Kind = Literal["bool", "int", "float", "str", "str_list"]
ParamValue = bool | int | float | str | list[str]


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
    """

    name: str
    default: ParamValue
    description: str
    kind: Kind
    choices: tuple[str, ...] | None = None
    minimum: float | None = None
    maximum: float | None = None
    positive: bool = False

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
        return "; ".join(parts)

    def validate(self, value: Any) -> ParamValue:
        """Coerce ``value`` to this parameter's kind and check it; raise ParameterError naming the parameter."""
        v = _coerce(self, value)
        if self.kind in ("int", "float"):
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
    elif kind == "str":
        if isinstance(value, str):
            return value
    elif kind == "str_list":
        if value is None or (isinstance(value, Sequence) and not isinstance(value, str) and len(value) == 0):
            return []  # ROS reports an empty list as NOT_SET or an empty byte array
        if isinstance(value, Sequence) and not isinstance(value, str) and all(isinstance(x, str) for x in value):
            return list(value)
    expected = {"bool": "a bool", "int": "an integer", "float": "a number", "str": "a string",
                "str_list": "a list of strings"}[kind]
    raise ParameterError(f"parameter '{name}' must be {expected}, got {value!r} ({type(value).__name__})")


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


def declare_parameters(node: Node, specs: Sequence[Param]) -> dict[str, ParamValue]:
    """Declare ``specs`` on ``node`` (read-only, dynamically typed so ``2`` works for a float) and validate.

    Returns the validated values by name. Raises ParameterError naming the first bad parameter.
    """
    from rcl_interfaces.msg import ParameterDescriptor

    out: dict[str, ParamValue] = {}
    for p in specs:
        descriptor = ParameterDescriptor(
            name=p.name, description=p.description, additional_constraints=p.constraints(),
            read_only=True, dynamic_typing=True,
        )
        node.declare_parameter(p.name, p.default, descriptor)
        out[p.name] = p.validate(node.get_parameter(p.name).value)
    return out


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
        lines.append(f"    # {p.description}" + (f" ({p.constraints()})" if p.constraints() else ""))
        lines.append(f"    {p.name}: {yaml_value(p.default)}")
    for head, params in groups.items():
        if not head:
            continue
        lines.append(f"    {head}:")
        for p in params:
            lines.append(f"      # {p.description}")
            lines.append(f"      {p.name.split('.', 1)[1]}: {yaml_value(p.default)}")
    return "\n".join(lines) + "\n"
