#!/usr/bin/env bash
# Train the shipped experiment configs at their full settings and print the results table that
# docs/training.md quotes (every number comes from the runs' metrics.json). About 15 minutes on 2 cores.
#   bash scripts/experiments.sh [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
BPTSB="${BPTSB:-.venv/bin/bptsb}"
PY="${PY:-.venv/bin/python}"
OUT="${1:-runs/experiments}"
mkdir -p "$OUT"
"$BPTSB" train config/lissajous_single.yaml --out "$OUT/lissajous" --no-progress --force
"$BPTSB" train config/locomotion_forward.yaml --out "$OUT/locomotion" --no-progress --force
"$BPTSB" train config/narma.yaml --set epochs=300 --out "$OUT/narma_sgd" --no-progress --force
"$BPTSB" train config/narma_adam.yaml --out "$OUT/narma_adam" --no-progress --force
"$PY" - "$OUT" <<'PYEOF'
import json, sys
from pathlib import Path
import numpy as np
out = Path(sys.argv[1])
print("| run | command | updates | loss: first 10 → last 10 (mean) | metric |")
print("|---|---|---|---|---|")
for name, cmd in [("lissajous", "config/lissajous_single.yaml"), ("locomotion", "config/locomotion_forward.yaml"),
                  ("narma_sgd", "config/narma.yaml --set epochs=300"), ("narma_adam", "config/narma_adam.yaml")]:
    m = json.loads((out / name / "metrics.json").read_text())
    loss, ev = np.array(m["loss"]), m["evaluation"]
    key = ev["metric"]
    extra = ""
    if "closed_over_open" in ev:
        extra = f"; closed/open = {ev['closed_over_open']:.3g}"
    if key == "mean_forward_speed":
        extra = f" (target {ev['target_speed_end_of_training']:.3g})" + extra
    print(f"| {name} | `bptsb train {cmd}` | {m['updates']} | {loss[:10].mean():.3g} → {loss[-10:].mean():.3g} "
          f"| {key} = {ev[key]:.3g}{extra} |")
PYEOF
