"""Where a live node gets its body and brain: a trained agent's run directory, an experiment YAML
(fresh, untrained agent) or a few shape parameters (fresh agent of a task's default body).

Every node of a loop reads the same source parameters, so body and brains agree on the agent. A
fresh agent is built by ``bptsb_ros.agent.build_agent`` from a seeded config, exactly as training
starts, so two processes with the same parameters hold the same random parameters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bptsb_ros.body.shapes import SHAPES
from bptsb_ros.interface.params import Param

if TYPE_CHECKING:
    pass

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
          choices=("", *SHAPES)),
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
