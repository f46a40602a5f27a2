"""Definitions shared by several ``bptsb`` subcommands (not a subcommand itself)."""

from __future__ import annotations

import argparse
import math

DEFAULT_NODES = {"double_circle": 25, "multiple_circle": 17, "caterpillar": 10}
"""Default number of masses (fixed ones included) per body shape for ``--nodes``."""


def finite_float(text: str) -> float:
    """argparse ``type`` for a float argument: NaN and ±inf are rejected (``--perturb nan`` is an error, not 0)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text[:40]!r}")
    return value
