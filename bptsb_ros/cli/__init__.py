"""The ``bptsb`` command: one subcommand per module in this package.

Each subcommand module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from bptsb_ros import __version__

SUBCOMMANDS = (
    "train",
    "simulate",
    "render",
    "bench",
    "run",
    "launch",
    "replay",
    "bag",
    "reproduce",
    "report",
    "sweep",
    "data",
    "ipc",
    "config",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bptsb",
        description="Backpropagation through soft body: train brain-body systems offline, run them "
        "live as ROS 2 nodes, record and replay bags.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"bptsb_ros.cli.{name}_cmd")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; a Ctrl-C that reaches Python (while the subcommands are imported, or in a command
    that does not handle it itself) is one line and exit status 130, not a traceback."""
    try:
        args = build_parser().parse_args(argv)
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("bptsb: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
