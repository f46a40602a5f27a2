"""The agent a live node runs, from its source parameters (:data:`bptsb_ros.interface.source.SOURCE_PARAMS`):
a trained run directory, an MNIST system file, a config, or a fresh agent of a task's default body.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bptsb_ros.interface.params import ParameterError
from bptsb_ros.interface.source import fresh_config

if TYPE_CHECKING:
    from bptsb_ros.agent import Agent


def load_source(values: dict[str, Any]) -> tuple[Agent, bool]:
    """Build the agent named by the source parameters, in the parameter ``dtype``, parameters frozen.

    An MNIST system file (``tasks.drawing.save_system``) gives the agent of ``tasks.mnist_live.system_agent``:
    the system's body, the whole system as brain.

    Returns:
        (agent, trained): ``trained`` is True for an agent loaded from a run directory or a system file.

    Raises:
        ParameterError: naming ``agent``, ``config`` or the shape parameter that is wrong.
    """
    from bptsb_ros.agent import build_agent, dtype_of
    from bptsb_ros.config import ConfigError, load_config, validate

    dtype = dtype_of(values["dtype"])
    if values["agent"]:
        from bptsb_ros.tasks.mnist_live import SystemFileError, is_system_file, system_agent
        from bptsb_ros.training.checkpoint import CheckpointError, load_agent

        try:
            if is_system_file(values["agent"]):
                return system_agent(values["agent"], dtype), True
        except SystemFileError as err:
            raise ParameterError(f"parameter 'agent': {err}") from None

        try:
            return load_agent(values["agent"], dtype=dtype), True
        except (CheckpointError, ConfigError) as err:
            raise ParameterError(f"parameter 'agent': {err}") from None
    if values["config"]:
        try:
            cfg = load_config(values["config"], seed=values["seed"])
        except ConfigError as err:
            raise ParameterError(f"parameter 'config': {err}") from None
        cfg.dtype = values["dtype"]
    else:
        try:
            cfg = validate(fresh_config(values), "from the node's shape parameters")
        except ConfigError as err:
            raise ParameterError(f"shape parameters (task/shape/nodes/brain_type): {err}") from None
    try:
        agent = build_agent(cfg)
    except ValueError as err:
        raise ParameterError(f"shape parameters (shape/nodes/size): {err}") from None
    for module in agent.modules().values():
        module.requires_grad_(False)
    return agent, False
