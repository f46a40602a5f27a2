"""``config/foxglove_layout.json``: a Foxglove layout that opens a bag of a loop with the body in a 3D
panel, spring-length and CMP plots and the diagnostics. Checked against the package's own topic table and message
types: every panel in the layout tree is configured, every plotted message path resolves to a number in a message
as body_sim publishes it, and the 3D panel follows the frame body_sim stamps."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from bptsb_ros.interface.topics import TOPICS, absolute
from bptsb_ros.ros import messages as m

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


@pytest.mark.ros
def test_3d_panel_shows_the_body_in_its_frame(layout):
    from bptsb_ros.ros.body_sim import PARAMS

    frame = next(p.default for p in PARAMS if p.name == "frame_id")
    panel = layout["configById"]["3D!body"]
    assert panel["followTf"] == frame == panel["layers"]["grid"]["frameId"]
    markers = absolute(TOPICS["markers"].name)
    assert panel["topics"][markers]["visible"] is True


@pytest.mark.ros
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


def _strings(node):
    if isinstance(node, dict):
        return [s for k, v in node.items() for s in [k, *_strings(v)]]
    if isinstance(node, list):
        return [s for v in node for s in _strings(v)]
    return [node] if isinstance(node, str) else []


def test_the_layout_and_the_rviz_config_of_a_namespaced_robot(layout, repo_root):
    """For a robot in /robot1: every loop topic of the layout (keys, plotted paths, diagnostics) in /robot1, every
    frame robot1/msdn (the frame the launchers give its body), nothing else changed; RViz's fixed frame the same."""
    from bptsb_ros.live.loops import LOOPS, node_parameters
    from bptsb_ros.live.viewers import foxglove_layout, rviz_config_text

    frame = node_parameters(LOOPS["lissajous_open"], "body_sim", namespace="/robot1")["frame_id"]
    assert frame == "robot1/msdn"
    ns = foxglove_layout(layout, "/robot1")
    panel = ns["configById"]["3D!body"]
    assert panel["followTf"] == frame == panel["layers"]["grid"]["frameId"]
    assert panel["topics"]["/robot1/body/markers"]["visible"] is True and "/body/markers" not in panel["topics"]
    assert ns["configById"]["DiagnosticSummary!diagnostics"]["topicToRender"] == "/robot1/diagnostics"
    loop_topics = {absolute(t.name) for t in TOPICS.values()}
    before, after = _strings(layout), _strings(ns)
    assert len(before) == len(after)
    for old, new in zip(before, after, strict=True):
        topic = PATH.match(old)["topic"] if PATH.match(old) else old
        if old == "msdn":
            assert new == "robot1/msdn"
        elif topic in loop_topics:
            assert new == "/robot1" + old, old
        else:
            assert new == old  # titles, other tools' topics (/clicked_point ...), settings
    assert foxglove_layout(layout, "") == layout
    rviz = rviz_config_text((repo_root / "config" / "bptsb.rviz").read_text(), "/robot1")
    import yaml

    cfg = yaml.safe_load(rviz)["Visualization Manager"]
    assert cfg["Global Options"]["Fixed Frame"] == "robot1/msdn"
    assert rviz.count("robot1") == 1  # the topics stay relative: rviz2 in the namespace resolves them
