"""The package's architecture, checked from its source (``ast`` only: nothing of the package is imported).

Rooms are the folders under ``bptsb_ros/`` (and the loose root modules); each has a floor, and a room imports only
its own modules and rooms on lower floors (:data:`FLOORS`). Imports inside functions count as much as those at the
top of a module. Besides the floors: ROS client and launch libraries only under ``ros/`` (the bag reader and writer
may use ``rclpy.serialization``), no import circle between modules, at most 8 loose root modules, no file name in
two folders, and the update guard built in one place outside its module (the update loop).

:data:`ALLOWED` lists the edges that break a floor today, each with its reason; it may only shrink (an entry
that no longer exists fails too, so whoever removes an edge removes its line).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import REPO_ROOT

PACKAGE = REPO_ROOT / "bptsb_ros"

#: room → floor, low to high: a room imports its own floor's room and lower floors only. ``bptsb_ros`` (the
#: package's ``__init__``: the version and the lazy public names) may be imported from anywhere.
FLOORS = {
    "files": 0,
    "body": 1, "data": 1,
    "config": 2,
    "brains": 3,
    "agent": 4,
    "interface": 5,
    "bags": 6, "sim": 6,
    "training": 7,
    "tasks": 8,
    "analysis": 9,
    "workflows": 10,
    "jobs": 11, "live": 11,
    "experiments": 12,
    "ros": 13,
    "bench": 14,
    "cli": 15, "api": 15,
}
ROOT = "bptsb_ros"
#: external libraries only ``ros/`` imports (the prefix of the imported name)
ROS_LIBRARIES = ("rclpy", "launch", "launch_ros", "rosidl_runtime_py", "rosbag2_py")
#: what the bag reader and writer may import of them: the message (de)serialisation, nothing of the ROS graph
BAGS_MAY_USE = ("rclpy.serialization",)

#: edges that break the rules today (importer → imported), each with its reason; shrink only
ALLOWED: dict[tuple[str, str], str] = {}


@dataclass(frozen=True)
class Edge:
    """``source`` (a module of the package) imports ``target`` at ``line``: a module of the package (the deepest
    one the imported name names) or, ``external``, another library's dotted name."""

    source: str
    target: str
    line: int
    external: bool
    type_checking: bool


def modules(package: Path) -> dict[str, Path]:
    """Dotted module name → file, for every ``.py`` under ``package`` (a package is its ``__init__``)."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def import_edges(package: Path) -> list[Edge]:
    """Every import of every module under ``package``, wherever it stands (module level, functions, classes)."""
    known = modules(package)
    name = package.name
    edges = []
    for source, path in known.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        checking = _type_checking_lines(tree)
        is_package = path.name == "__init__.py"
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the importing module's package
                    anchor = source.split(".")[: len(source.split(".")) - node.level + (1 if is_package else 0)]
                    base = ".".join([*anchor, *([base] if base else [])])
                names = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else base for alias in node.names]
            else:
                continue
            for target in names:
                internal = target == name or target.startswith(name + ".")
                if internal:
                    while target not in known and "." in target:
                        target = target.rsplit(".", 1)[0]
                edges.append(Edge(source, target, node.lineno, not internal, node.lineno in checking))
    return edges


def room(module: str) -> str:
    """The room of a module: its folder under the package, or the loose module's own name."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ROOT


def floor_violations(edges: list[Edge], floors: dict[str, int] = FLOORS) -> set[tuple[str, str]]:
    """Internal edges from a room to a higher floor, or across two rooms of one floor."""
    bad = set()
    for e in edges:
        if e.external or e.target == ROOT or e.source == ROOT:
            continue
        a, b = room(e.source), room(e.target)
        if a != b and floors[b] >= floors[a]:
            bad.add((e.source, e.target))
    return bad


def ros_library_violations(edges: list[Edge]) -> set[tuple[str, str]]:
    """ROS client or launch libraries imported outside ``ros/`` (``bags/``: only :data:`BAGS_MAY_USE`)."""
    bad = set()
    for e in edges:
        if not e.external or e.target.split(".")[0] not in ROS_LIBRARIES or room(e.source) == "ros":
            continue
        if room(e.source) == "bags" and e.target in BAGS_MAY_USE:
            continue
        bad.add((e.source, e.target))
    return bad


def circles(edges: list[Edge]) -> list[list[str]]:
    """The module circles (strongly connected components of more than one module, or a module importing itself)
    of the run-time imports (``TYPE_CHECKING`` blocks apart), by Tarjan's algorithm."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        if not e.external and not e.type_checking:
            graph.setdefault(e.source, set()).add(e.target)
            graph.setdefault(e.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph[v]:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def loose_root_modules(package: Path) -> list[str]:
    return sorted(p.stem for p in package.glob("*.py") if p.name != "__init__.py")


def repeated_basenames(package: Path) -> dict[str, list[str]]:
    seen: dict[str, list[str]] = {}
    for path in package.rglob("*.py"):
        if path.name not in ("__init__.py", "__main__.py"):
            seen.setdefault(path.name, []).append(str(path.relative_to(package)))
    return {name: sorted(paths) for name, paths in seen.items() if len(paths) > 1}


def guard_sites(package: Path) -> list[str]:
    """The files that construct an ``UpdateGuard`` (a call of that name, or of a name it is imported as), its own
    module aside."""
    sites = []
    for path in sorted(package.rglob("*.py")):
        rel = str(path.relative_to(package))
        if rel == "training/guard.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        names = {"UpdateGuard"} | {alias.asname for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
                                   for alias in node.names if alias.name == "UpdateGuard" and alias.asname}
        for node in ast.walk(tree):
            func = node.func if isinstance(node, ast.Call) else None
            if (isinstance(func, ast.Name) and func.id in names) or (
                    isinstance(func, ast.Attribute) and func.attr == "UpdateGuard"):
                sites.append(rel)
                break
    return sites


# ------------------------------------------------------------------------------------------ the package itself

@pytest.fixture(scope="module")
def edges() -> list[Edge]:
    return import_edges(PACKAGE)


def test_every_room_has_a_floor():
    rooms = {room(m) for m in modules(PACKAGE)} - {ROOT}
    assert sorted(rooms - set(FLOORS)) == []


def test_no_room_imports_a_higher_floor_beyond_the_listed_exceptions(edges):
    bad = floor_violations(edges) | ros_library_violations(edges)
    assert sorted(bad - set(ALLOWED)) == [], "imports against the floors (FLOORS in this file)"
    assert sorted(set(ALLOWED) - bad) == [], "listed exceptions that no longer exist: remove them from ALLOWED"


def test_live_bags_analysis_and_every_room_below_them_import_nothing_from_ros(edges):
    lower = {"live", "bags", "analysis", "interface", "body", "brains", "sim", "training", "tasks", "config", "files",
             "data", "agent", "workflows", "jobs"}
    assert sorted({(e.source, e.target) for e in edges if room(e.source) in lower and room(e.target) == "ros"}) == []
    assert sorted(ros_library_violations([e for e in edges if room(e.source) in lower])) == []


def test_training_imports_neither_tasks_nor_analysis_sim_not_tasks_tasks_not_analysis(edges):
    rules = {"training": {"tasks", "analysis", "workflows"}, "sim": {"tasks", "training"}, "tasks": {"analysis"}}
    bad = sorted((e.source, e.target, e.line) for e in edges if not e.external
                 and room(e.target) in rules.get(room(e.source), ()))
    assert bad == []


def test_no_import_circle(edges):
    assert circles(edges) == []


def test_at_most_eight_loose_root_modules_and_no_file_name_twice():
    assert len(loose_root_modules(PACKAGE)) <= 8, loose_root_modules(PACKAGE)
    assert repeated_basenames(PACKAGE) == {}


def test_body_sim_stays_at_most_250_lines():
    assert len((PACKAGE / "ros" / "body_sim.py").read_text(encoding="utf-8").splitlines()) <= 250


def test_the_update_guard_is_built_in_the_update_loop_alone():
    assert guard_sites(PACKAGE) == ["training/loop.py"]


# ------------------------------------------------------------------------------------------ the checks, planted

def _plant(tmp_path: Path, files: dict[str, str]) -> Path:
    package = tmp_path / "bptsb_ros"
    for rel, text in files.items():
        path = package / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in {p.parent for p in package.rglob("*.py")}:
        (folder / "__init__.py").touch()
    return package


CLEAN = {
    "body/msdn.py": "import numpy\n",
    "training/loop.py": "from bptsb_ros.body.msdn import numpy\nfrom bptsb_ros.training import guard\n",
    "training/guard.py": "class UpdateGuard: ...\nUpdateGuard()\n",
    "tasks/lissajous.py": "def f():\n    from bptsb_ros.training.loop import x\n    UpdateGuard()\n",
    "ros/node.py": "import rclpy\nfrom bptsb_ros.tasks.lissajous import f\n",
    "bags/writer.py": "def f():\n    from rclpy.serialization import serialize_message\n",
    "analysis/plots.py": "from bptsb_ros import __version__\nfrom typing import TYPE_CHECKING\n"
                         "if TYPE_CHECKING:\n    from bptsb_ros.analysis import style\n",
    "analysis/style.py": "from bptsb_ros.analysis import plots\n",
    "agent.py": "from .body import msdn\n",
}


def test_a_planted_clean_package_passes_every_check(tmp_path):
    package = _plant(tmp_path, CLEAN)
    edges = import_edges(package)
    assert ("bptsb_ros.agent", "bptsb_ros.body.msdn") in {(e.source, e.target) for e in edges}  # relative import
    assert floor_violations(edges) == set()
    assert ros_library_violations(edges) == set()
    assert circles(edges) == []  # plots → style only under TYPE_CHECKING
    assert repeated_basenames(package) == {}
    assert guard_sites(package) == ["tasks/lissajous.py"]


@pytest.mark.parametrize("rel, text, expected", [
    ("body/forces.py", "def f():\n    from bptsb_ros.training.loop import x\n",
     ("bptsb_ros.body.forces", "bptsb_ros.training.loop")),
    ("training/fused.py", "from bptsb_ros.tasks import lissajous\n",
     ("bptsb_ros.training.fused", "bptsb_ros.tasks.lissajous")),
    ("sim/rollout.py", "from bptsb_ros.ros.node import x\n", ("bptsb_ros.sim.rollout", "bptsb_ros.ros.node")),
    ("bags/reader.py", "from bptsb_ros.sim import rollout\n", ("bptsb_ros.bags.reader", "bptsb_ros.sim.rollout")),
])
def test_an_import_against_the_floors_is_found(tmp_path, rel, text, expected):
    package = _plant(tmp_path, {**CLEAN, "sim/rollout.py": "x = 1\n", rel: text})
    assert expected in floor_violations(import_edges(package))


@pytest.mark.parametrize("rel, text, expected", [
    ("live/loops.py", "def f():\n    from launch.actions import TimerAction\n",
     ("bptsb_ros.live.loops", "launch.actions")),
    ("bags/writer.py", "import rclpy\n", ("bptsb_ros.bags.writer", "rclpy")),
    ("analysis/plots.py", "from rclpy.node import Node\n", ("bptsb_ros.analysis.plots", "rclpy.node")),
])
def test_a_ros_library_outside_ros_is_found(tmp_path, rel, text, expected):
    package = _plant(tmp_path, {**CLEAN, rel: text})
    assert ros_library_violations(import_edges(package)) == {expected}


def test_a_circle_through_a_function_level_import_is_found(tmp_path):
    package = _plant(tmp_path, {**CLEAN, "analysis/plots.py": "def f():\n    from bptsb_ros.analysis import style\n"})
    assert circles(import_edges(package)) == [["bptsb_ros.analysis.plots", "bptsb_ros.analysis.style"]]


def test_a_repeated_file_name_nine_root_modules_and_a_third_guard_site_are_found(tmp_path):
    package = _plant(tmp_path, {**CLEAN, "sim/msdn.py": "x = 1\n", "live/steps.py": "UpdateGuard(1)\n",
                                "jobs/run.py": "from bptsb_ros.training.guard import UpdateGuard as G\nG()\n",
                                **{f"m{i}.py": "x = 1\n" for i in range(8)}})
    assert repeated_basenames(package) == {"msdn.py": ["body/msdn.py", "sim/msdn.py"]}
    assert len(loose_root_modules(package)) == 9
    assert guard_sites(package) == ["jobs/run.py", "live/steps.py", "tasks/lissajous.py"]
