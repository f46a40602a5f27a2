"""The package's ROS nodes, in one table: every list of nodes is made from it — the executables ``setup.py``
installs (with the :data:`PROCESSES` that run several of them), the params files
(:mod:`bptsb_ros.ros.param_files`), ``bptsb run``'s nodes and help, the brains whose commands ``body_sim``
accepts by default (:data:`bptsb_ros.live.safety.DEFAULT_PUBLISHERS`) and the brain nodes of the loops
(:mod:`bptsb_ros.live.loops`).

Plain data and the standard library only: ``setup.py`` reads this file without importing the package.
"""

from __future__ import annotations

from typing import NamedTuple


class Node(NamedTuple):
    """One ROS node of the package.

    Attributes:
        name: the executable (``ros2 run bptsb_ros <name>``, ``bptsb run <name>``).
        module: the module whose ``main(args=None)`` runs it.
        help: one line for ``bptsb run --help``.
        triggers: topic keys (:data:`bptsb_ros.interface.topics.TOPICS`) a brain-side node answers, besides its
            sim-time ``/clock`` subscription (in a loop).
        publishes: topic keys it publishes in a loop.
        commands: the body input it commands (``rest_length``, ``force``, ``wind``, ``reset``): ``body_sim``
            accepts that input from it by default; None for a node that commands nothing.
        params_file: it has a params file ``config/<name>_params.yaml``.
    """

    name: str
    module: str
    help: str
    triggers: tuple[str, ...] = ()
    publishes: tuple[str, ...] = ()
    commands: str | None = None
    params_file: bool = True


NODES: tuple[Node, ...] = (
    Node("body_sim", "bptsb_ros.ros.body_sim",
         "soft-body simulator: publishes /clock and the body state, integrates brain commands"),
    Node("swg_brain", "bptsb_ros.ros.swg_brain", "sine-wave generator: rest-length commands on each /clock tick",
         ("clock",), ("rest_length_cmd",), "rest_length"),
    Node("feedback_brain", "bptsb_ros.ros.feedback_brain",
         "feedback layer: body state → rest-length commands (closed loop)",
         ("clock", "positions"), ("rest_length_cmd",), "rest_length"),
    Node("task_input", "bptsb_ros.ros.task_input", "streams the task's input series (NARMA u) on each /clock tick",
         ("clock",), ("task_input",)),
    Node("mlp_brain", "bptsb_ros.ros.mlp_brain", "MLP/LIL brain: task input → forces on the movable masses",
         ("task_input",), ("force_cmd",), "force"),
    # body_sim takes its wind only when it awaits a synchronised (stamped) wind: wait_for contains wind
    Node("wind_source", "bptsb_ros.ros.wind_source", "streams a wind schedule on env/wind on each /clock tick",
         ("clock",), ("wind",), "wind"),
    Node("image_streamer", "bptsb_ros.ros.image_streamer",
         "MNIST loop: one IDX image per episode on camera/image (parameters images, labels)",
         ("clock",), ("image", "label")),
    # body/reset: the initial displacements of a released body (loop mnist_drawing)
    Node("mnist_brain", "bptsb_ros.ros.mnist_brain",
         "MNIST loop: camera/image → initial displacements on body/reset (agent: a system file)",
         ("image",), ("reset_cmd",), "reset"),
    Node("recorder", "bptsb_ros.ros.recorder", "records topics to a rosbag2 MCAP bag (parameters bag_path, topics)",
         params_file=False),
)

#: Executables that run several nodes in one process (not nodes themselves; installed beside them):
#: ``bptsb_composed --nodes body_sim,BRAIN,...`` runs body_sim and a loop's brains on one executor
#: (``composed:=true`` of the launch files, ``bptsb launch --composed``).
PROCESSES: dict[str, str] = {"bptsb_composed": "bptsb_ros.ros.composed"}

#: node name → its row
BY_NAME: dict[str, Node] = {node.name: node for node in NODES}


def command_publishers() -> dict[str, tuple[str, ...]]:
    """Body input → the nodes that command it, in table order."""
    out: dict[str, tuple[str, ...]] = {}
    for node in NODES:
        if node.commands is not None:
            out[node.commands] = (*out.get(node.commands, ()), node.name)
    return out
