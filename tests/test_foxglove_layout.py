"""``config/foxglove_layout.json`` (issue 12): a Foxglove layout that opens a bag of a loop with the body in a 3D
panel, spring-length and CMP plots and the diagnostics. Checked against the package's own topic table and message
types: every panel in the layout tree is configured, every plotted message path resolves to a number in a message
as body_sim publishes it, and the 3D panel follows the frame body_sim stamps."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from bptsb_ros.ros import messages as m
from bptsb_ros.ros.topics import TOPICS, absolute

PATH = re.compile(r"^(?P<topic>/[\w/]+)\.(?P<field>.+)$")


@pytest.fixture(scope="module")
def layout(repo_root):
    return json.loads((repo_root / "config" / "foxglove_layout.json").read_text())


def _leaves(node):
    if isinstance(node, str):
        return [node]
    return _leaves(node["first"]) + _leaves(node["second"])


def _sample(topic: str):
    """A message of ``topic`` as body_sim publishes it for a 25-mass double circle (CMP last) at step 7."""
    from bptsb_ros.body.shapes import double_circle

    topo = double_circle(25)
    n, e = len(topo.positions), len(topo.springs)
    positions = np.asarray(topo.positions) + 0.25  # the CMP (last mass) sits at (0.25, 0.25)
    lengths = np.arange(e, dtype=float) + 0.5
    if topic == "/body/positions":
        return m.pose_array(7, 10_000_000, positions, "msdn")
    if topic in ("/body/spring_lengths", "/body/rest_length"):
        return m.joint_state(7, 10_000_000, [f"spring_{i}" for i in range(e)], position=lengths)
    raise AssertionError(f"no sample for {topic} (n={n})")


def _resolve(msg, field: str):
    value = msg
    for part in re.findall(r"[A-Za-z_]\w*|\[-?\d+\]", field.replace(".", " ")):
        value = value[int(part[1:-1])] if part.startswith("[") else getattr(value, part)
    return value


def test_every_panel_in_the_tree_is_configured(layout):
    leaves = _leaves(layout["layout"])
    assert sorted(leaves) == sorted(layout["configById"])
    kinds = {leaf.split("!")[0] for leaf in leaves}
    assert {"3D", "Plot", "DiagnosticSummary", "DiagnosticStatusPanel"} <= kinds


def test_3d_panel_shows_the_body_in_its_frame(layout):
    from bptsb_ros.ros.body_sim import PARAMS

    frame = next(p.default for p in PARAMS if p.name == "frame_id")
    panel = layout["configById"]["3D!body"]
    assert panel["followTf"] == frame == panel["layers"]["grid"]["frameId"]
    markers = absolute(TOPICS["markers"].name)
    assert panel["topics"][markers]["visible"] is True


def test_plotted_paths_resolve_to_numbers(layout):
    known = {absolute(t.name) for t in TOPICS.values()}
    paths = []
    for key, config in layout["configById"].items():
        if key.startswith("Plot!"):
            paths += [p["value"] for p in config["paths"]]
            if config.get("xAxisVal") == "custom":
                paths.append(config["xAxisPath"]["value"])
            assert config["title"] and "[" in config["title"]  # a unit in every plot title
    assert any("spring_lengths" in p for p in paths) and any("poses[-1]" in p for p in paths)
    for path in paths:
        match = PATH.match(path)
        assert match and match["topic"] in known, path
        value = _resolve(_sample(match["topic"]), match["field"])
        assert isinstance(value, float), (path, value)
    cmp_x = _resolve(_sample("/body/positions"), "poses[-1].position.x")
    assert cmp_x == 0.25  # the CMP is the last mass of the circular bodies


def test_diagnostics_panels_read_the_body_status(layout):
    summary = layout["configById"]["DiagnosticSummary!diagnostics"]
    assert summary["topicToRender"] == absolute(TOPICS["diagnostics"].name)
    status = layout["configById"]["DiagnosticStatusPanel!status"]
    assert status["topicToRender"] == "/diagnostics" and status["selectedName"] == "body_sim: loop"
