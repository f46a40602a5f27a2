#!/usr/bin/env bash
# The package as a user installs it, away from this checkout (`make check-install`; CI runs it after the tests):
#   1. `python -m build` makes the wheel and the sdist; `twine check --strict` accepts both;
#   2. the training route: a fresh venv, the CPU build of torch first, then the wheel with its `train` extra;
#      from an unrelated directory it runs the README's Python example (taken from README.md itself),
#      `bptsb config show`, `bptsb train NAME` and `bptsb reproduce lissajous-closed-loop --scale smoke`;
#   3. the light route: a fresh venv with the wheel alone (no torch, no numba): `bptsb bag info` and `bptsb replay`
#      of the packaged example bag, `bptsb ipc` of a planted system; none of them may import torch.
# Prints each venv's installed size (du). Needs the dev tools of .venv (build, twine) and network or a local
# index for the dependencies. KEEP=DIR keeps the venvs and outputs in DIR instead of a temporary folder.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
REPO=$(pwd)
PYTHON=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
VPY=${VPY:-$REPO/.venv/bin/python}

if [ -n "${KEEP:-}" ]; then
    work=$KEEP
    mkdir -p "$work"
else
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
fi
export PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_PROGRESS_BAR=off
pip_quiet() { "$@" 2>&1 | sed -u -e "/Location 'file:.*' is ignored/d" | grep -v "^\(Requirement already\|Collecting\|Downloading\|Processing\|Using cached\|Installing collected\)" || true; }
step() { echo "check-install: $*"; }

step "building the wheel and the sdist"
rm -rf "$work/dist"
"$VPY" -m build --outdir "$work/dist" . >"$work/build.log" 2>&1 || { tail -30 "$work/build.log"; exit 1; }
"$VPY" -m twine check --strict "$work/dist"/*
wheel=$(ls "$work"/dist/bptsb_ros-*.whl)

elsewhere="$work/elsewhere"
rm -rf "$elsewhere" && mkdir -p "$elsewhere"

step "training route: torch==$TORCH_VERSION (CPU) first, then the wheel with [train]"
rm -rf "$work/train-venv"
"$PYTHON" -m venv "$work/train-venv"
T="$work/train-venv/bin"
pip_quiet "$T/pip" install "torch==$TORCH_VERSION"
pip_quiet "$T/pip" install "$wheel[train]"
"$T/pip" check
test -n "$("$T/python" -c 'import torch; print(torch.__version__)' | grep '+cpu' || true)" \
    || { echo "check-install: torch is not the CPU build"; exit 1; }

# The README's Python example: the ```python block after its "## Python" heading, run as it is.
"$VPY" - "$REPO/README.md" "$elsewhere/readme_example.py" <<'EOF'
import re, sys
text = open(sys.argv[1], encoding="utf-8").read()
section = text.split("\n## Python", 1)[1]
block = re.search(r"```python\n(.*?)```", section, re.S)
assert block, "README.md has no ```python block under ## Python"
open(sys.argv[2], "w", encoding="utf-8").write(block.group(1))
EOF
cd "$elsewhere"
step "README example from $(pwd)"
"$T/python" readme_example.py | tee readme_example.out
grep -q "CMP error" readme_example.out
step "bptsb config show / list, bptsb train NAME"
"$T/bptsb" config show lissajous_single --set sim_time=5 >config_show.txt && grep -q "sim_time: 5" config_show.txt
"$T/bptsb" config list >config_list.txt && grep -qx narma config_list.txt
"$T/bptsb" train lissajous_single --set sim_time=5 --set feedback.fit_time=5 --out train_run --no-progress >/dev/null
test -f train_run/checkpoint.pt
step "bptsb reproduce lissajous-closed-loop --scale smoke"
"$T/bptsb" reproduce lissajous-closed-loop --scale smoke --out smoke_run --no-progress
test -f smoke_run/result.json
cd "$REPO"

step "light route: the wheel alone"
rm -rf "$work/light-venv"
"$PYTHON" -m venv "$work/light-venv"
L="$work/light-venv/bin"
pip_quiet "$L/pip" install "$wheel"
"$L/pip" check
cd "$elsewhere"
bag=$("$L/python" -c 'from bptsb_ros.files.package_data import example_bag; print(example_bag())')
"$L/bptsb" bag info "$bag" >light_bag_info.txt && head -4 light_bag_info.txt
"$L/bptsb" replay "$bag" --out light_replay --no-gif >light_replay.txt && tail -3 light_replay.txt
test -f light_replay/metrics.json
"$L/python" - <<'EOF'
import importlib.util, json, sys
import numpy as np
from bptsb_ros.cli import main
for name in ("torch", "numba", "sklearn"):
    assert importlib.util.find_spec(name) is None, f"{name} is installed in the light venv"
# IPC of a planted system: x(t) = u(t-1) + 0.5 (u(t-2)^2 - 1/3) holds a linear and a quadratic memory
rng = np.random.default_rng(0)
u = rng.uniform(-1, 1, 4000)
x = np.zeros_like(u)
x[2:] = u[1:-1] + 0.5 * (u[:-2] ** 2 - 1 / 3)
np.savez("planted.npz", u=u, states=x[:, None])
assert main(["ipc", "--input", "planted.npz", "--out", "light_ipc", "--max-degree", "2", "--max-delay", "4",
             "--surrogates", "50"]) == 0
ipc = json.load(open("light_ipc/ipc.json"))["states"][0]
# variances: u(t-1) 1/3, 0.5 (u² - 1/3) 1/45, so the capacities are 15/16 (degree 1) and 1/16 (degree 2)
print(f"IPC of the planted system: degree 1 {ipc['by_degree']['1']:.3f} (15/16 = 0.9375), degree 2 "
      f"{ipc['by_degree']['2']:.3f} (1/16 = 0.0625)")
assert abs(ipc["by_degree"]["1"] - 15 / 16) < 0.02 and abs(ipc["by_degree"]["2"] - 1 / 16) < 0.02, ipc["by_degree"]
assert "torch" not in sys.modules
EOF
cd "$REPO"

step "installed sizes (du of each venv)"
du -sm "$work/train-venv" "$work/light-venv" | sed "s|$work/||"
step "done"
