"""Definitions shared by several ``bptsb`` subcommands (not a subcommand itself)."""

from __future__ import annotations

DEFAULT_NODES = {"double_circle": 25, "multiple_circle": 17, "caterpillar": 10}
"""Default number of masses (fixed ones included) per body shape for ``--nodes``."""
