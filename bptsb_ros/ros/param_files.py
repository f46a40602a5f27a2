"""The params files ``config/<node>_params.yaml``: every declared parameter of a node with its default
and description, in the standard ``/**: ros__parameters:`` layout.

``python -m bptsb_ros.ros.param_files config`` rewrites them from the nodes' parameter specs; a test
checks that the committed files match.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from bptsb_ros.files.safe_write import write_atomic
from bptsb_ros.interface.nodes import NODES as ALL_NODES
from bptsb_ros.interface.params import render_params_yaml

#: node name -> module holding its ``PARAMS`` (brains also get COMMON_PARAMS): the node table's nodes with a params
#: file (:data:`bptsb_ros.interface.nodes.NODES`)
NODES: dict[str, str] = {node.name: node.module for node in ALL_NODES if node.params_file}
SIM_TIME = ("use_sim_time", True, "brains run on the body's /clock (sim time)")


def render(node: str) -> str:
    """The params file text of ``node``."""
    module = importlib.import_module(NODES[node])
    if node == "body_sim":
        return render_params_yaml(node, module.PARAMS)
    from bptsb_ros.ros.brain_node import COMMON_PARAMS

    return render_params_yaml(node, COMMON_PARAMS + tuple(module.PARAMS), extra=[SIM_TIME])


def write_all(config_dir: str | Path) -> list[Path]:
    """Write ``<config_dir>/<node>_params.yaml`` for every node; returns the paths."""
    out = []
    for node in NODES:
        path = Path(config_dir) / f"{node}_params.yaml"
        write_atomic(path, render(node))
        out.append(path)
    return out


if __name__ == "__main__":
    for written in write_all(sys.argv[1] if len(sys.argv) > 1 else "config"):
        print(written)
