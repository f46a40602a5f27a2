"""The ``bptsb`` command: one subcommand per module in this package.

Each subcommand module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NoReturn

from bptsb_ros import __version__
from bptsb_ros.cli.options import USAGE

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


#: one line per command for ``bptsb --help`` (each command's own ``--help`` says the rest)
SUMMARIES = {
    "train": "train an agent with BPTSB from a packaged config or a YAML file",
    "simulate": "simulate an agent or a fresh body headless to an .npz (and a GIF)",
    "render": "draw a body with its mass and spring indices",
    "bench": "speed and memory of the standard workloads (JSON)",
    "run": "run one ROS 2 node",
    "launch": "run a whole live loop as ROS 2 processes, recorded to a bag",
    "replay": "metrics, plots and animation of a recorded bag",
    "bag": "inspect a bag, or rebuild a damaged one",
    "reproduce": "run one of the paper's experiments (--list: the table)",
    "report": "gather reproduce results into one Markdown page",
    "sweep": "train one config once per seed, locally or on Dask",
    "data": "download and verify data sets (MNIST)",
    "ipc": "information processing capacity of driven states",
    "config": "list, show or import experiment configs",
}
#: libraries of the optional extras (setup.py) → the extra that installs them
EXTRAS = {"torch": "train", "numba": "train", "sklearn": "train", "distributed": "dask", "rclpy": "ros"}
EPILOG = ("bptsb COMMAND --help explains a command. Start with: bptsb train lissajous_single --out runs/liss; "
          "bptsb reproduce --list.")


class _CommandListFormatter(argparse.HelpFormatter):
    """``bptsb --help``: 100 columns, and every command's summary on its own line (argparse measures the commands
    at one indent less than it prints them, so a 9-letter command would push its summary to the next line)."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=16, width=100)
        self._action_max_length = 14


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
        epilog=EPILOG,
        formatter_class=_CommandListFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in SUBCOMMANDS:
        module = importlib.import_module(f"bptsb_ros.cli.{name}_cmd")
        p = sub.add_parser(name, help=SUMMARIES[name], description=module.HELP,
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
    except BrokenPipeError:  # the reader of stdout went away (`bptsb config list | head -1`): stop quietly
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes
        return 141  # as a process killed by SIGPIPE
    except ModuleNotFoundError as err:  # a library of an extra that this install does not have
        extra = EXTRAS.get((err.name or "").split(".")[0])
        if extra is None:
            raise
        print(f"bptsb: {err.name} is not installed, and this command needs it: pip install "
              f"\"bptsb_ros[{extra}]\" (docs: Getting started, Install)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
