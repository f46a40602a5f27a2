"""Body shapes: the published geometries (counts, fixed/movable, connectivity) and ``bptsb render``."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pytest

from bptsb_ros.body.shapes import (
    SHAPES,
    Topology,
    build_shape,
    caterpillar,
    double_circle,
    multiple_circle,
    nodes_for_movable,
)


def assert_well_formed(topo: Topology) -> None:
    n = topo.n_masses
    assert topo.positions.shape == (n, 2) and topo.fixed.shape == (n,) and topo.fixed.dtype == bool
    assert topo.springs.shape == (topo.n_springs, 2) and np.issubdtype(topo.springs.dtype, np.integer)
    assert ((topo.springs >= 0) & (topo.springs < n)).all()
    assert (topo.springs[:, 0] != topo.springs[:, 1]).all(), "self-spring"
    pairs = {tuple(sorted(s)) for s in topo.springs.tolist()}
    assert len(pairs) == topo.n_springs, "duplicate spring"
    assert (topo.rest_lengths() > 1e-6).all(), "zero-length spring"
    assert not topo.fixed[topo.springs].all(axis=1).any(), "spring between two fixed masses"
    # One connected network: every mass is reachable from mass 0.
    seen, frontier = {0}, [0]
    neighbours: dict[int, set[int]] = {i: set() for i in range(n)}
    for i, j in topo.springs.tolist():
        neighbours[i].add(j)
        neighbours[j].add(i)
    while frontier:
        for j in neighbours[frontier.pop()] - seen:
            seen.add(j)
            frontier.append(j)
    assert len(seen) == n, "disconnected masses"
    if topo.cmp_index >= 0:
        assert not topo.fixed[topo.cmp_index]
        np.testing.assert_allclose(topo.positions[topo.cmp_index], [0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("nodes,springs,movable", [(25, 48, 13), (33, 64, 17)])
def test_double_circle_counts(nodes: int, springs: int, movable: int) -> None:
    topo = double_circle(nodes)
    assert_well_formed(topo)
    assert (topo.n_masses, topo.n_springs, len(topo.movable)) == (nodes, springs, movable)
    m = (nodes - 1) // 2
    assert topo.fixed[:m].all() and not topo.fixed[m:].any()
    assert topo.cmp_index == nodes - 1
    connected_to_cmp = {i for i, j in topo.springs.tolist() if j == topo.cmp_index}
    connected_to_cmp |= {j for i, j in topo.springs.tolist() if i == topo.cmp_index}
    assert connected_to_cmp == set(range(m, 2 * m)), "every inner mass connects to the CMP"


def test_double_circle_geometry_matches_the_published_layout() -> None:
    topo = double_circle(25, size=4.0)
    radius = np.linalg.norm(topo.positions, axis=1)
    np.testing.assert_allclose(radius[:12], 2.0)  # outer ring, size/2
    np.testing.assert_allclose(radius[12:24], 1.0)  # inner ring, size/4
    np.testing.assert_allclose(topo.positions[0], [0.0, 2.0], atol=1e-12)  # mass 0 on top
    theta = (12 + 0.5) * 2 * math.pi / 12  # inner mass 12 sits half a spacing clockwise of the top
    np.testing.assert_allclose(topo.positions[12], [math.sin(theta), math.cos(theta)], atol=1e-12)
    outer_degree = np.bincount(topo.springs.ravel(), minlength=25)[:12]
    assert (outer_degree == 2).all(), "each outer mass links to its two neighbouring inner masses"


def test_multiple_circle_counts() -> None:
    topo = multiple_circle(17)
    assert_well_formed(topo)
    assert (topo.n_masses, topo.n_springs) == (17, 20)
    assert int(topo.fixed.sum()) == 12 and len(topo.movable) == 5
    topo = multiple_circle(65)
    assert_well_formed(topo)
    assert topo.n_masses == 65 and int(topo.fixed.sum()) == 28 and len(topo.movable) == 37


@pytest.mark.parametrize(
    "shape,n_movable,nodes",
    [("double_circle", 17, 33), ("double_circle", 65, 129), ("double_circle", 4, 7),
     ("multiple_circle", 17, 37), ("multiple_circle", 65, 101), ("multiple_circle", 5, 17),
     ("caterpillar", 10, 10), ("caterpillar", 2, 2)],
)
def test_nodes_for_movable(shape: str, n_movable: int, nodes: int) -> None:
    """The paper's N_mov → masses (hand values; the facts file: multiple circle 37 → 17 movable, 101 → 65),
    checked again by counting the built body's movable masses from its fixed mask."""
    assert nodes_for_movable(shape, n_movable) == nodes
    topo = build_shape(shape, nodes)
    assert int(np.count_nonzero(~topo.fixed)) == n_movable and topo.n_masses == nodes


@pytest.mark.parametrize("shape,n_movable", [("double_circle", 3), ("multiple_circle", 4), ("multiple_circle", 16),
                                             ("multiple_circle", 18), ("caterpillar", 1), ("triangle", 17)])
def test_nodes_for_movable_rejects_counts_no_body_has(shape: str, n_movable: int) -> None:
    with pytest.raises(ValueError, match="movable|n_masses|unknown shape"):
        nodes_for_movable(shape, n_movable)


def test_caterpillar_counts_and_layout() -> None:
    topo = caterpillar(10)
    assert_well_formed(topo)
    assert (topo.n_masses, topo.n_springs) == (10, 24)
    assert not topo.fixed.any() and topo.cmp_index == -1
    x = np.arange(10) - 5 + 0.5
    y = np.where(np.arange(10) % 2 == 0, 4 * (1 - (2 * x / 10) ** 2), 0.0)
    np.testing.assert_allclose(topo.positions, np.stack([x, y], 1))
    assert caterpillar(10, neighbours=2).n_springs == 17


@pytest.mark.parametrize(
    "shape,nodes,kwargs,match",
    [
        ("double_circle", 24, {}, "odd"),
        ("double_circle", 5, {}, ">= 7"),
        ("multiple_circle", 18, {}, "4c"),
        ("multiple_circle", 5, {}, "4c"),
        ("caterpillar", 1, {}, "n_masses >= 2"),
        ("caterpillar", 10, {"neighbours": 0}, "neighbours >= 1"),
        ("triangle", 10, {}, "unknown shape"),
    ],
)
def test_invalid_sizes_raise(shape: str, nodes: int, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        build_shape(shape, nodes, **kwargs)


def test_build_shape_knows_every_shape() -> None:
    for name, nodes in zip(SHAPES, (25, 17, 10)):
        assert build_shape(name, nodes).name == name


def render_cli(argv: list[str]) -> int:
    from bptsb_ros.cli import render_cmd

    parser = argparse.ArgumentParser()
    render_cmd.add_arguments(parser)
    return render_cmd.run(parser.parse_args(argv))


@pytest.mark.parametrize("shape,nodes", [("double_circle", 25), ("multiple_circle", 17), ("caterpillar", 10)])
def test_render_writes_a_png(tmp_path, shape: str, nodes: int) -> None:
    from PIL import Image

    out = tmp_path / f"{shape}.png"
    assert render_cli(["--shape", shape, "--nodes", str(nodes), "--dpi", "80", "--out", str(out)]) == 0
    with Image.open(out) as image:
        assert image.format == "PNG" and image.width > 300 and image.height > 150  # the caterpillar: ≈ 460 × 200
        colors = image.convert("RGB").getcolors(maxcolors=1 << 16)
    assert colors is not None and len(colors) > 20  # a drawing, not a blank canvas


def test_render_rejects_bad_input(tmp_path, capsys) -> None:
    assert render_cli(["--shape", "double_circle", "--nodes", "24", "--out", str(tmp_path / "x.png")]) == 2
    assert "odd" in capsys.readouterr().err
    assert render_cli(["--shape", "caterpillar", "--out", str(tmp_path / "x.jpg")]) == 2
    assert ".png" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
