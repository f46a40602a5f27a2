#!/usr/bin/env bash
# The main job, end to end: train a Lissajous agent with BPTSB (SWG brain + double-circle body),
# fit its feedback layer, simulate it offline (plots + animation), run the closed loop live as ROS 2
# nodes in lockstep while recording a rosbag2 MCAP bag, then replay the bag and compare with offline.
# Run through `make demo` (which prepares .venv). Outputs go to runs/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-77}"
BPTSB="${BPTSB:-.venv/bin/bptsb}"
OUT="${DEMO_OUT:-runs/demo}"
SIM_TIME="${DEMO_SIM_TIME:-2000}"      # seconds of simulated training (the paper's and the config's: 2000)
rm -rf "$OUT"
mkdir -p "$OUT"

echo "== 1/5 train: config/lissajous_single.yaml, sim_time=${SIM_TIME} s (BPTSB, truncated 100-step windows)"
"$BPTSB" train config/lissajous_single.yaml --set sim_time="$SIM_TIME" --out "$OUT/agent"

echo "== 2/5 simulate the trained agent offline (float64) with an animation"
"$BPTSB" simulate --agent "$OUT/agent" --steps 500 --dtype float64 --out "$OUT/offline.npz" --gif "$OUT/offline.gif"

echo "== 3/5 live closed loop through ROS 2 (body_sim + feedback_brain, lockstep), recorded to MCAP"
# The SWG drives the first 2 s (200 steps), then the feedback layer closes the loop (as in the paper).
"$BPTSB" launch lissajous_closed --agent "$OUT/agent" --duration 10 --open-loop-steps 200 --mode lockstep \
  --bag "$OUT/bag"

echo "== 4/5 bag info"
"$BPTSB" bag info "$OUT/bag"

echo "== 5/5 replay the bag: metrics, plots, animation, comparison with the offline closed loop"
"$BPTSB" replay "$OUT/bag" --agent "$OUT/agent" --out "$OUT/replay"

echo
echo "Done. Results:"
echo "  training:  $OUT/agent/{metrics.json,loss.png,lissajous.png}"
echo "  offline:   $OUT/offline.npz, $OUT/offline.gif"
echo "  live bag:  $OUT/bag/ (metadata.yaml + .mcap; open the .mcap in Foxglove)"
echo "  replay:    $OUT/replay/ (metrics.json, plots, animation)"
