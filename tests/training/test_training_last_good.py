"""The "last good" checkpoint of a diverged run holds parameters that completed a training window
without diverging, with periodic checkpoints and with ``checkpoint_every: 0``.

Since the update guard undoes a diverging update, a training only stops as diverged when the parameters it
would restore diverge too. Planted here with a physical cause no parameters survive: a headwind of 1e12 N
that starts blowing at t = 8.5 s, inside window 4 (steps 801-1000) of a caterpillar trained in 2 s windows.
Update 4 diverges and is undone (parameters of update 3 restored, the carried state not advanced); update 5
runs window 4 again with them, diverges again, and nothing is left to undo."""

from __future__ import annotations

import json
import math

import pytest
import torch
from conftest import REPO_ROOT

from bptsb_ros.config import load_config
from bptsb_ros.tasks import get_task
from bptsb_ros.training.checkpoint import load_agent, read_checkpoint
from bptsb_ros.workflows.train import TrainingDiverged, train

CONFIG = REPO_ROOT / "config" / "locomotion_forward.yaml"
#: 6 windows of 200 steps; calm for the first 8.5 s of the 17 s wind period, then 1e12 N against the robot
STORM = ["sim_time=12", "locomotion.warmup_windows=0", "locomotion.wind_force=-1.0e+12", "locomotion.wind_period=17",
         "feedback.enabled=false", "dtype=float64"]


@pytest.mark.parametrize("every", [1, 0])
def test_kept_checkpoint_completes_its_window(tmp_path, every):
    cfg = load_config(CONFIG, [*STORM, f"training.checkpoint_every={every}"])
    with pytest.raises(TrainingDiverged, match=r"update 5: simulation diverged.*nothing to undo.*last good "
                                               r"checkpoint, update 3, is kept") as err:
        train(cfg, tmp_path / "run", progress=False)
    report = json.loads((tmp_path / "run" / "diverged.json").read_text())
    kept = read_checkpoint(tmp_path / "run")["extra"]
    assert kept["update"] == report["last_good_update"] == 3 and report["update"] == 5, str(err.value)
    assert [(e["update"], e["reason"]) for e in report["guard"]["events"]] == [(4, "diverged")]
    assert "k in [" in report["parameters"]
    assert torch.isfinite(kept["task_state"]["r"]).all() and torch.isfinite(kept["task_state"]["v"]).all()
    # independently of the trainer: the kept parameters, from the kept carried state, run the next window
    agent = load_agent(tmp_path / "run")
    task = get_task(cfg.task)(agent, cfg)
    task.prepare()
    task.load_state_dict(kept["task_state"])
    with torch.no_grad():
        loss, _ = task.update_loss(kept["update"])
    assert math.isfinite(float(loss))
