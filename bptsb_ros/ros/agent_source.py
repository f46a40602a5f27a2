"""Where a live node gets its body and brain: a trained agent's run directory, an experiment YAML
(fresh, untrained agent) or a few shape parameters (fresh agent of a task's default body).

Every node of a loop reads the same source parameters, so body and brains agree on the agent. A
fresh agent is built by ``bptsb_ros.agent.build_agent`` from a seeded config, exactly as training
starts, so two processes with the same parameters hold the same random parameters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bptsb_ros.ros.params import Param, ParameterError

if TYPE_CHECKING:
    from bptsb_ros.agent import Agent

TASKS = ("lissajous", "locomotion", "narma")
#: default body of a fresh agent per task: (shape, masses)
TASK_BODIES: dict[str, tuple[str, int]] = {
    "lissajous": ("double_circle", 25),
    "locomotion": ("caterpillar", 10),
    "narma": ("double_circle", 33),
}

SOURCE_PARAMS: tuple[Param, ...] = (
    Param("agent", "", "run directory (or checkpoint.pt) of a trained agent, or an MNIST system file (systems/"
          "<name>.pt, or a run directory holding just one); empty: a fresh, untrained agent from 'config' or from "
          "'task' and the shape parameters", "str"),
    Param("config", "", "experiment YAML of a fresh agent (used when 'agent' is empty)", "str"),
    Param("task", "lissajous", "task of a fresh agent (when 'agent' and 'config' are empty)", "str", choices=TASKS),
    Param("shape", "", "body shape of a fresh agent; empty: the task's default", "str",
          choices=("", "double_circle", "multiple_circle", "caterpillar")),
    Param("nodes", 0, "number of masses of a fresh agent's body, fixed ones included; 0: the task's default",
          "int", minimum=0),
    Param("size", 4.0, "diameter of a fresh agent's circular body [m]", "float", positive=True),
    Param("dt", 0.01, "time step of a fresh agent's body [s] (a trained agent brings its own)", "float",
          positive=True),
    Param("integrator", "verlet", "integrator of a fresh agent's body", "str", choices=("verlet", "published")),
    Param("brain_type", "", "brain of a fresh agent; empty: swg, or mlp for narma", "str",
          choices=("", "swg", "mlp", "lil")),
    Param("seed", 0, "seed of a fresh agent's random parameters (k, d, SWG phases, brain weights)", "int"),
    Param("dtype", "float64", "floating-point type of the live computation", "str", choices=("float32", "float64")),
)


def fresh_config(values: dict[str, Any]) -> dict[str, Any]:
    """The experiment config (raw mapping) of a fresh agent from shape parameters."""
    task = values["task"]
    shape, nodes = TASK_BODIES[task]
    brain = values["brain_type"] or ("mlp" if task == "narma" else "swg")
    return {
        "task": task,
        "seed": values["seed"],
        "dtype": values["dtype"],
        "body": {
            "shape": values["shape"] or shape,
            "nodes": values["nodes"] or nodes,
            "size": values["size"],
            "dt": values["dt"],
            "integrator": values["integrator"],
            "environment": "locomotion" if task == "locomotion" else "none",
        },
        "brain": {"type": brain},
    }


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
