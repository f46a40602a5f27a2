"""The ``bptsb`` command: one subcommand per module in this package.

Each subcommand module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from bptsb_ros import __version__
from bptsb_ros.cli.common import USAGE

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


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line, ``bptsb <command>: error: <what> (see bptsb <command>
    --help)``, and exit status 2 (``USAGE``), instead of the whole usage block. Subparsers are of the same class
    (argparse makes them of their parent's class), so every subcommand and action gets it."""

    def error(self, message: str) -> NoReturn:
        text = "; ".join(s.strip() for s in str(message).splitlines() if s.strip())
        self.exit(USAGE, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def _tag_progs(parser: argparse.ArgumentParser) -> None:
    """Every subparser below ``parser`` records its ``prog`` in the namespace (``_prog``), the deepest one last."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                sub.set_defaults(_prog=sub.prog)
                _tag_progs(sub)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
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
    _tag_progs(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; a usage error is one line and exit status 2 (:class:`OneLineParser`); a Ctrl-C that
    reaches Python (while the subcommands are imported, or in a command that does not handle it itself) is one
    line and exit status 130, not a traceback."""
    try:
        args, extras = build_parser().parse_known_args(argv)
        if extras:  # argparse would blame the top parser, ``bptsb``; the (sub)command parsed last is the one
            OneLineParser(prog=getattr(args, "_prog", "bptsb")).error(f"unrecognized arguments: {' '.join(extras)}")
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("bptsb: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
