"""The node table (``bptsb_ros/interface/nodes.py``) is the one list of the package's ROS nodes: the installed
executables, the params files, ``bptsb run``, the brains ``body_sim`` accepts commands from and the loops' brain
nodes all come from it, and it names exactly the node modules under ``ros/`` (found here from their source)."""

from __future__ import annotations

import ast
import runpy

from conftest import REPO_ROOT as REPO


def _node_modules() -> dict[str, str]:
    """Node name → module of every module under ros/ with a ``main`` that starts a node of that name: its
    ``NODE = "<name>"`` constant, or the name it gives ``Node.__init__`` (read from the source, not the table)."""
    found = {}
    for path in sorted((REPO / "bptsb_ros" / "ros").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if not any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body):
            continue
        names = [n.value.value for n in tree.body if isinstance(n, ast.Assign) and isinstance(n.value, ast.Constant)
                 and any(isinstance(t, ast.Name) and t.id == "NODE" for t in n.targets)]
        names += [c.args[0].value for c in ast.walk(tree) if isinstance(c, ast.Call)
                  and isinstance(c.func, ast.Attribute) and c.func.attr == "__init__" and c.args
                  and isinstance(c.args[0], ast.Constant) and isinstance(c.args[0].value, str)]
        if names:
            found[names[0]] = f"bptsb_ros.ros.{path.stem}"
    return found


def test_the_table_names_every_node_module_under_ros_and_nothing_else():
    table = runpy.run_path(str(REPO / "bptsb_ros" / "interface" / "nodes.py"))["NODES"]
    assert {n.name: n.module for n in table} == _node_modules()
    assert len({n.name for n in table}) == len(table) == 9


def test_every_list_of_nodes_is_the_table():
    from importlib.metadata import distribution

    from bptsb_ros.cli.run_cmd import NODES as run_nodes
    from bptsb_ros.interface.nodes import NODES, PROCESSES
    from bptsb_ros.live import loops
    from bptsb_ros.live.safety import DEFAULT_PUBLISHERS
    from bptsb_ros.ros.param_files import NODES as param_nodes

    scripts = {e.name: e.value for e in distribution("bptsb_ros").entry_points if e.group == "console_scripts"}
    assert scripts == {"bptsb": "bptsb_ros.cli:main", **{n.name: f"{n.module}:main" for n in NODES},  # setup.py
                       "bptsb_composed": "bptsb_ros.ros.composed:main"}
    assert PROCESSES == {"bptsb_composed": "bptsb_ros.ros.composed"}
    assert set(run_nodes) == {n.name for n in NODES}
    assert set(param_nodes) == {p.stem.removesuffix("_params") for p in (REPO / "config").glob("*_params.yaml")}
    # the command sources body_sim accepts, by hand: the brains that command each body input
    assert DEFAULT_PUBLISHERS == {"rest_length": ("swg_brain", "feedback_brain"), "force": ("mlp_brain",),
                                 "wind": ("wind_source",), "reset": ("mnist_brain",)}
    brains = {b.executable: b for loop in loops.LOOPS.values() for b in loop.brains}
    for name, spec in brains.items():
        row = next(n for n in NODES if n.name == name)
        assert (spec.triggers, spec.publishes) == (row.triggers, row.publishes) or name == "feedback_brain"
    assert set(brains) == {n.name for n in NODES if n.triggers}
