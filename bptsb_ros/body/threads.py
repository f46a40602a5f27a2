"""Thread counts per workload.

The paper's bodies are tiny (10–33 masses): at batch 1 a second torch thread only adds synchronisation
(measured before this policy: ``bptsb train`` burned 2.0 CPU-seconds per wall-second at the speed of
one core), so small batches run on one thread. A large batch is spread over the cores: torch's intra-op
threads for the torch backend, the numba kernel's ``prange`` over the bodies for the numba backend
(from ``kernel.PARALLEL_MIN_BATCH`` bodies on; below that the kernel runs serially).
"""

from __future__ import annotations

import os

import torch

#: batch size from which torch ops use every core (below it: one thread)
TORCH_PARALLEL_MIN_BATCH = 64


def configure_threads(batch: int, backend: str = "numba") -> dict[str, int]:
    """Set torch's thread count for a workload of ``batch`` bodies; returns the threads each part uses."""
    cores = os.cpu_count() or 1
    torch_threads = 1 if batch < TORCH_PARALLEL_MIN_BATCH else cores
    torch.set_num_threads(torch_threads)
    threads = {"torch": torch_threads}
    if backend == "numba":
        from bptsb_ros.body import kernel

        threads["numba"] = kernel.threads_for(batch)
    return threads
