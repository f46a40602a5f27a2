"""The rclpy side of the live nodes' parameters: :func:`declare_parameters` declares a node's
:class:`~bptsb_ros.interface.params.Param` specs on it (with a ``ParameterDescriptor`` carrying the description and
constraints), validates the values given by ``--ros-args -p`` or ``--params-file``, and keeps the dynamic ones
live; :func:`set_log_level` applies ``log_level``. The specs, their validation and the params-file rendering are
ROS-free (:mod:`bptsb_ros.interface.params`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from bptsb_ros.interface.params import OnChange, Param, ParameterError, ParamValue, apply_changes, describe, yaml_value

if TYPE_CHECKING:
    from rclpy.node import Node


def set_log_level(node: Node, level: str) -> None:
    """Set ``node``'s logger level ('' leaves it as --log-level set it)."""
    if not level:
        return
    from rclpy.logging import LoggingSeverity

    node.get_logger().set_level({"debug": LoggingSeverity.DEBUG, "info": LoggingSeverity.INFO,
                                 "warn": LoggingSeverity.WARN, "error": LoggingSeverity.ERROR}[level])


#: list kinds and their ROS array type (``rcl_interfaces/msg/ParameterType``): declared statically typed, so that
#: an empty list is a STRING_ARRAY (or DOUBLE_ARRAY), not the BYTE_ARRAY rclpy infers from ``[]``
ARRAY_TYPES: dict[str, str] = {"str_list": "STRING_ARRAY", "float_list": "DOUBLE_ARRAY"}


def _declare_array(node: Node, p: Param, descriptor: Any) -> None:
    """Declare a list parameter with its array type (``descriptor.dynamic_typing`` False) and its default.

    rclpy infers the type of a default value, and ``[]`` (or an empty ``-p name:=[]``, which arrives unset)
    reads as a byte array; so the parameter is declared by type, left writable while its value is set
    typed, and only then gets its final (possibly read-only) descriptor.
    """
    from rclpy.exceptions import InvalidParameterTypeException, ParameterUninitializedException
    from rclpy.parameter import Parameter

    ptype = Parameter.Type[ARRAY_TYPES[p.kind]]
    descriptor.type = ptype.value
    writable = type(descriptor)(name=descriptor.name, type=descriptor.type, description=descriptor.description,
                                additional_constraints=descriptor.additional_constraints, read_only=False,
                                dynamic_typing=False)
    override = node._parameter_overrides.get(p.name)  # rclpy keeps -p / --params-file values here
    try:
        node.declare_parameter(p.name, ptype, writable)
    except InvalidParameterTypeException:
        given = override.value if override is not None else None
        example = "[1.0, 0.0]" if p.kind == "float_list" else "['a', 'b']"
        raise ParameterError(f"parameter '{p.name}' must be a list of "
                             f"{'numbers with a decimal point' if p.kind == 'float_list' else 'strings'}, e.g. "
                             f"{example}; got {given!r}") from None
    try:
        node.get_parameter(p.name)
    except ParameterUninitializedException:  # not given, or given as an empty list
        value = [] if override is not None else list(p.default)
        result = node.set_parameters([Parameter(p.name, ptype, value)])[0]
        if not result.successful:
            raise ParameterError(f"parameter '{p.name}': {result.reason}") from None
    node.set_descriptor(p.name, descriptor)


def declare_parameters(node: Node, specs: Sequence[Param], on_change: OnChange | None = None) -> dict[str, ParamValue]:
    """Declare ``specs`` on ``node`` (scalars dynamically typed so ``2`` works for a float; lists statically
    typed as STRING_ARRAY / DOUBLE_ARRAY, :func:`_declare_array`) and validate.

    Parameters with ``dynamic=True`` may be set while the node runs: a parameter callback validates them
    (:func:`apply_changes`), calls ``on_change`` and updates the returned dict, which the node keeps reading;
    the others are read-only. ``log_level`` (if among ``specs``) is applied here, at startup and when set.

    Returns the validated values by name. Raises ParameterError naming the first bad parameter.
    """
    from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult

    out: dict[str, ParamValue] = {}
    for p in specs:
        descriptor = ParameterDescriptor(
            name=p.name, description=describe(p), additional_constraints=p.constraints(),
            read_only=not p.dynamic, dynamic_typing=p.kind not in ARRAY_TYPES,
        )
        if p.kind in ARRAY_TYPES:
            _declare_array(node, p, descriptor)
        else:
            node.declare_parameter(p.name, p.default, descriptor)
        out[p.name] = p.validate(node.get_parameter(p.name).value)
    if "log_level" in out:
        set_log_level(node, str(out["log_level"]))

    def changed(name: str, value: ParamValue) -> None:
        if on_change is not None:
            on_change(name, value)
        if name == "log_level":
            set_log_level(node, str(value))

    def callback(params: list) -> SetParametersResult:
        reason = apply_changes(specs, out, [(q.name, q.value) for q in params], changed)
        if reason:
            node.get_logger().warning(f"refused parameter change: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        for q in params:
            if q.name in out:
                node.get_logger().info(f"parameter {q.name} set to {yaml_value(out[q.name])}")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(callback)
    return out
