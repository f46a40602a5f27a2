"""Helpers shared by the time-series experiments (NARMA emulation, memory task, IPC): the 1-D chain
counter-example, thread settings, parallel jobs."""

from __future__ import annotations

import numpy as np
import torch

from bptsb_ros.body.shapes import Topology


def chain_topology(n_movable: int = 8, spacing: float = 0.5) -> Topology:
    """Masses on the x-axis joined to their nearest and next-nearest neighbours, both ends fixed: the
    supplement's counter-example of a body that stays linear when forces act along the line only."""
    n = n_movable + 2
    positions = np.stack([spacing * np.arange(n), np.zeros(n)], axis=1)
    springs = [(i, i + 1) for i in range(n - 1)] + [(i, i + 2) for i in range(n - 2)]
    fixed = np.zeros(n, dtype=bool)
    fixed[[0, -1]] = True
    return Topology("chain", positions, np.array(springs), fixed, -1)


def one_torch_thread() -> None:
    """Run torch on one thread: the bodies are tiny (tens of masses), so per-op overhead dominates and a second
    thread only adds synchronisation (measured here: ~3,000 vs ~100 batched steps/s on a busy 2-core machine).
    Parallelism comes from independent jobs instead (see :func:`run_jobs`)."""
    torch.set_num_threads(1)
