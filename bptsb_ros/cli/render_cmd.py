"""``bptsb render``: draw a body shape to PNG with mass and spring indices."""

from __future__ import annotations

import argparse

from bptsb_ros.body.shapes import DEFAULT_NODES
from bptsb_ros.cli.options import USAGE, fail, finite_float

NAME = "render"
HELP = (
    "Draw a body shape (double_circle, multiple_circle, caterpillar) to an image: fixed masses, movable "
    "masses and the CMP in different colours, springs, mass and spring indices, a legend.\n"
    "Example: bptsb render --shape double_circle --nodes 25 --out body.png"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--shape", required=True, choices=sorted(DEFAULT_NODES), help="body shape")
    parser.add_argument("--nodes", type=int, default=None,
                        help="number of masses, fixed ones included (default: 25, 17 or 10 by shape)")
    parser.add_argument("--size", type=finite_float, default=4.0, help="diameter of circular bodies [m] (default 4)")
    parser.add_argument("--neighbours", type=int, default=3,
                        help="caterpillar: each mass connects to the next K masses (default 3)")
    parser.add_argument("--no-spring-labels", action="store_true", help="omit spring indices")
    parser.add_argument("--no-mass-labels", action="store_true", help="omit mass indices")
    parser.add_argument("--dpi", type=int, default=200, help="resolution of raster output (default 200)")
    parser.add_argument("--out", required=True, help="output image (.png, .svg or .pdf)")


def run(args: argparse.Namespace) -> int:
    from bptsb_ros.analysis.render import render_topology
    from bptsb_ros.body.shapes import build_shape

    nodes = DEFAULT_NODES[args.shape] if args.nodes is None else args.nodes
    if not str(args.out).lower().endswith((".png", ".svg", ".pdf")):
        return fail(NAME, f"--out must end in .png, .svg or .pdf, got {args.out}", USAGE)
    if args.size <= 0:
        return fail(NAME, f"--size must be positive, got {args.size}", USAGE)
    try:
        topology = build_shape(args.shape, nodes, size=args.size, neighbours=args.neighbours)
    except ValueError as exc:  # --nodes or --neighbours out of range for the shape
        return fail(NAME, exc, USAGE)
    if args.dpi < 1:
        return fail(NAME, f"--dpi must be >= 1, got {args.dpi}", USAGE)
    try:
        path = render_topology(topology, args.out, mass_labels=not args.no_mass_labels,
                               spring_labels=not args.no_spring_labels, dpi=args.dpi)
    except OSError as exc:
        return fail(NAME, f"cannot write --out {args.out}: {exc.strerror or exc}")
    print(f"wrote {path} ({topology.n_masses} masses, {topology.n_springs} springs)")
    return 0
