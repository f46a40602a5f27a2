"""The "last good" checkpoint of a diverged run holds parameters that completed a training window
without diverging (issue 6, finding 5), with periodic checkpoints and with ``checkpoint_every: 0``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from bptsb_ros.config import load_config
from bptsb_ros.tasks import get_task
from bptsb_ros.training.checkpoint import load_agent, read_checkpoint
from bptsb_ros.training.trainer import TrainingDiverged, train

CONFIG = Path(__file__).resolve().parent.parent / "config" / "lissajous_single.yaml"
#: learning rates far above the paper's: the run diverges after a few updates
HOT = ["sim_time=20", "training.lr.k=1.0e+7", "training.lr.l=1.0e+3", "dtype=float64"]


@pytest.mark.parametrize("every", [1, 0])
def test_kept_checkpoint_completes_its_window(tmp_path, every):
    cfg = load_config(CONFIG, [*HOT, f"training.checkpoint_every={every}"])
    with pytest.raises(TrainingDiverged, match=r"last good checkpoint, update (\d+), is kept") as err:
        train(cfg, tmp_path / "run", progress=False)
    report = json.loads((tmp_path / "run" / "diverged.json").read_text())
    kept = read_checkpoint(tmp_path / "run")["extra"]
    assert kept["update"] == report["last_good_update"] == report["update"] - 1 >= 1, str(err.value)
    # independently of the trainer: the kept parameters, from the kept carried state, run the next window
    agent = load_agent(tmp_path / "run")
    task = get_task(cfg.task)(agent, cfg)
    task.prepare()
    task.load_state_dict(kept["task_state"])
    with torch.no_grad():
        loss, _ = task.update_loss(kept["update"])
    assert math.isfinite(float(loss))
