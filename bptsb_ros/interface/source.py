"""Where a live node gets its body and brain: a trained agent's run directory, an experiment YAML
(fresh, untrained agent) or a few shape parameters (fresh agent of a task's default body).

Every node of a loop reads the same source parameters, so body and brains agree on the agent. A
fresh agent is built by ``bptsb_ros.agent.build_agent`` from a seeded config, exactly as training
starts, so two processes with the same parameters hold the same random parameters.
"""

from __future__ import annotations

from typing import Any, Literal, get_args, get_origin

from pydantic import BaseModel

from bptsb_ros.config.experiment import TASKS, BodyConfig, BrainConfig, ExperimentConfig
from bptsb_ros.interface.params import Param, ParamValue

#: default body of a fresh agent per task: (shape, masses)
TASK_BODIES: dict[str, tuple[str, int]] = {
    "lissajous": ("double_circle", 25),
    "locomotion": ("caterpillar", 10),
    "narma": ("double_circle", 33),
}


def _choices(model: type[BaseModel], field: str) -> tuple[str, ...]:
    """The values a ``Literal`` field of ``model`` allows."""
    annotation = model.model_fields[field].annotation
    assert get_origin(annotation) is Literal, f"{model.__name__}.{field} is not a Literal"
    return get_args(annotation)


def config_param(name: str, model: type[BaseModel], field: str, what: str, *, default: ParamValue | None = None,
                 choices: tuple[str, ...] | None = None, minimum: float | None = None) -> Param:
    """The node parameter ``name`` of a fresh agent's config field ``model.field``: its type, default, allowed values
    and bounds from the config schema (``default``, ``choices``, ``minimum``: where the node's differ); its
    description is the field's own, then ``what`` (the field's name, without one)."""
    info = model.model_fields[field]
    value = info.default if default is None else default
    kind = "str" if isinstance(value, str) else "int" if isinstance(value, int) else "float"
    if choices is None and get_origin(info.annotation) is Literal:
        choices = _choices(model, field)
    positive = any(getattr(m, "gt", None) == 0 for m in info.metadata)  # pydantic's Field(gt=0)
    maximum = next((float(m.le) for m in info.metadata if getattr(m, "le", None) is not None), None)
    text = f"{info.description}, {what}" if info.description else what
    return Param(name, value, text, kind, choices=choices, minimum=minimum, maximum=maximum, positive=positive)


SOURCE_PARAMS: tuple[Param, ...] = (
    Param("agent", "", "run directory (or checkpoint.pt) of a trained agent, or an MNIST system file (systems/"
          "<name>.pt, or a run directory holding just one); empty: a fresh, untrained agent from 'config' or from "
          "'task' and the shape parameters", "str"),
    Param("config", "", "experiment YAML of a fresh agent (used when 'agent' is empty)", "str"),
    config_param("task", ExperimentConfig, "task", "task of a fresh agent (when 'agent' and 'config' are empty)",
                 default="lissajous", choices=TASKS),
    config_param("shape", BodyConfig, "shape", "body shape of a fresh agent; empty: the task's default", default="",
                 choices=("", *_choices(BodyConfig, "shape"))),
    config_param("nodes", BodyConfig, "nodes", "of a fresh agent's body; 0: the task's default", default=0, minimum=0),
    config_param("size", BodyConfig, "size", "of a fresh agent's body"),
    config_param("dt", BodyConfig, "dt", "of a fresh agent's body (a trained agent brings its own)"),
    config_param("integrator", BodyConfig, "integrator", "integrator of a fresh agent's body"),
    config_param("brain_type", BrainConfig, "type", "brain of a fresh agent; empty: swg, or mlp for narma",
                 default="", choices=("", *_choices(BrainConfig, "type"))),
    Param("seed", 0, "seed of a fresh agent's random parameters (k, d, SWG phases, brain weights)", "int"),
    config_param("dtype", ExperimentConfig, "dtype", "floating-point type of the live computation", default="float64"),
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
