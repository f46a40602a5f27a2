"""Definitions shared by several ``bptsb`` subcommands (not a subcommand itself)."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path


def finite_float(text: str) -> float:
    """argparse ``type`` for a float argument: NaN and ±inf are rejected (``--perturb nan`` is an error, not 0)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text[:40]!r}")
    return value


USAGE = 2
"""Exit status of a command whose arguments are invalid (argparse's own errors, option combinations, option
values out of range, an unknown experiment name, an unknown ``--set`` key or a ``--set`` value of the wrong type)."""
FAILURE = 1
"""Exit status of a command whose arguments were fine but whose work failed: a bad or missing file (config, bag,
checkpoint, result.json, MNIST data), training or simulation divergence, an unwritable output, a locked run
directory, a failed scheduler connection."""


class UsageError(ValueError):
    """Raised by a subcommand's helpers when the command-line arguments themselves are at fault (exit ``USAGE``)."""


def fail(command: str, message: object, code: int = FAILURE) -> int:
    """Print ``bptsb <command>: <message>`` as one line to stderr and return ``code`` (the exit status).

    ``message`` (an exception or a text) is flattened to one line: its lines, stripped, joined with ``"; "``, every
    control character left escaped (``\\x1b``: a name read from a file cannot drive the terminal).
    """
    from bptsb_ros.files.untrusted_yaml import printable

    text = "; ".join(printable(s.strip()) for s in str(message).splitlines() if s.strip()) or "failed"
    print(f"bptsb {command}: {text}", file=sys.stderr)
    return code


def config_error_code(path: str | Path, overrides: Sequence[str] = (), seed: int | None = None) -> int:
    """Exit status for a ConfigError from ``load_config(path, overrides, seed)``: ``FAILURE`` when the file alone
    does not load (it is the file's fault), ``USAGE`` when it does (``--set`` or ``--seed`` broke it).

    Called only after the error, so it costs one more read of a small YAML file.
    """
    from bptsb_ros.config import ConfigError, load_config

    if not overrides and seed is None:
        return FAILURE
    try:
        load_config(path)
    except ConfigError:
        return FAILURE
    return USAGE
