"""Time NARMA / memory-task training updates on the numba path and with the fused episodes, alternating.

    .venv/bin/python scripts/time_narma_update.py [SECONDS] [ROUNDS] [KEY=VALUE ...]

Each measurement is ``bench._measure_narma_task`` (what ``bptsb bench`` runs for its NARMA task rows) in its own
process for SECONDS (default 10), ROUNDS times (default 2) numba then fused; KEY=VALUE items are ``--set``
overrides of ``config/narma.yaml`` (default ``brain.type=mlp``). Example, the memory task's LIL on the multiple
circle at Δt = 8:

    .venv/bin/python scripts/time_narma_update.py 10 2 brain.type=lil body.shape=multiple_circle body.nodes=37 \\
        narma.target=memory narma.delay=8 narma.brain_input=symmetric
"""

from __future__ import annotations

import os
import sys
from dataclasses import replace

from bptsb_ros.bench.suite import NARMA_TASK_OVERRIDES, WORKLOADS, _ratio, measure_isolated


def main() -> None:
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    overrides = tuple(sys.argv[3:]) or NARMA_TASK_OVERRIDES
    print(f"overrides {list(overrides)}; load average at start {os.getloadavg()[0]:.2f}")
    task = replace(WORKLOADS["narma"], name="narma_task", task=True, overrides=overrides)
    for r in range(1, rounds + 1):
        row = {b: measure_isolated(task, True, min_seconds=seconds, backend=b) for b in ("numba", "fused")}
        rate = {b: m.get("train_steps_per_s") for b, m in row.items()}
        print(f"round {r}: " + "; ".join(f"{b} {m.get('train_steps_per_s', m.get('error'))} steps/s, "
                                         f"{m.get('ms_per_update')} ms per update" for b, m in row.items())
              + f"; fused / numba {_ratio(rate['fused'], rate['numba'])}")
    print(f"load average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
