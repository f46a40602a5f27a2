"""Train one config on two backends and report where their loss paths separate.

    .venv/bin/python scripts/backend_divergence.py [CONFIG] [A] [B] [KEY=VALUE ...]

Defaults: ``config/lissajous_single.yaml``, backends ``numba`` and ``fused``, and the overrides
``sim_time=300 dtype=float64 feedback.enabled=false lissajous.eval_periods=1`` (300 updates in float64, no
feedback fit). The two paths compute the same equations and agree to about 1e-15 per update; the script
prints the first update at which the two losses differ by more than each of 1e-14 … 1e-2 (relative) and the
relative difference of the final k and l. Growth by orders of magnitude per few updates means the training
itself amplifies rounding (a chaotic path in parameter space), so the two runs are two draws of one
experiment, not a disagreement between the backends.
"""

from __future__ import annotations

import sys
from pathlib import Path

from bptsb_ros.config import load_config
from bptsb_ros.workflows.train import train

DEFAULTS = ("sim_time=300", "dtype=float64", "feedback.enabled=false", "lissajous.eval_periods=1")


def main() -> None:
    config = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("config/lissajous_single.yaml")
    backends = (sys.argv[2], sys.argv[3]) if len(sys.argv) > 3 else ("numba", "fused")
    overrides = list(sys.argv[4:]) or list(DEFAULTS)
    runs = {}
    for backend in backends:
        cfg = load_config(config, [*overrides, f"training.backend={backend}"])
        res = train(cfg, None, progress=False)
        runs[backend] = (res.agent.body.k.detach().double(), res.agent.body.l.detach().double(), res.losses)
    (k_a, l_a, loss_a), (k_b, l_b, loss_b) = (runs[b] for b in backends)
    rel = [abs(a - b) / max(abs(a), 1e-300) for a, b in zip(loss_a, loss_b)]
    print(f"{config} {overrides}: {len(rel)} updates, {backends[0]} vs {backends[1]}")
    for threshold in (1e-14, 1e-12, 1e-10, 1e-8, 1e-6, 1e-4, 1e-2):
        first = next((i for i, x in enumerate(rel) if x > threshold), None)
        print(f"  first update whose losses differ by more than {threshold:g} (relative): {first}")
    print(f"  final k: max |Δ| / max |k| = {float((k_a - k_b).abs().max() / k_a.abs().max()):.3g}; "
          f"final l: {float((l_a - l_b).abs().max() / l_a.abs().max()):.3g}")


if __name__ == "__main__":
    main()
