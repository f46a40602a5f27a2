"""Untrusted checkpoints are data, never code.

A crafted ``checkpoint.pt`` whose pickled ``__reduce__`` calls ``exec`` must be refused by every entry
point that loads an agent, with a clear error naming the file, and its payload must never run. A path
stored in a bag is never loaded unless the user passes ``--agent``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import REPO_ROOT as REPO
from ros_live import env_for

from bptsb_ros.cli import main
from bptsb_ros.ros import messages as m

pytestmark = pytest.mark.ros  # every test here builds ROS 2 messages (rclpy and the message packages)

CONFIG = REPO / "config" / "lissajous_single.yaml"
DT_NS = 10_000_000


class _Payload:
    """Unpickling this runs ``exec(code)``: what an attacker hides in a checkpoint."""

    def __init__(self, marker: Path) -> None:
        self.code = f"open({str(marker)!r}, 'w').write('payload ran')"

    def __reduce__(self):
        return (exec, (self.code,))


@pytest.fixture
def evil(tmp_path) -> tuple[Path, Path]:
    """(run directory holding a crafted checkpoint, marker file the payload would create)."""
    marker = tmp_path / "PAYLOAD_RAN"
    run = tmp_path / "evil_run"
    run.mkdir()
    real = torch.load(REPO / "bags" / "lissajous_agent" / "checkpoint.pt", weights_only=True)
    real["extra"]["task_state"] = {"r": _Payload(marker)}
    torch.save(real, run / "checkpoint.pt")
    (run / "config.yaml").write_text((REPO / "bags" / "lissajous_agent" / "config.yaml").read_text())
    return run, marker


def _refused(capsys, code: int, run: Path, marker: Path) -> None:
    err = capsys.readouterr().err
    assert code != 0, err
    assert not marker.exists(), "the checkpoint's payload ran"
    assert f"checkpoint {run / 'checkpoint.pt'} is refused" in err and "GLOBAL exec" in err, err
    assert "Traceback" not in err


def test_cli_entry_points_refuse_a_code_checkpoint(evil, tmp_path, capsys):
    run, marker = evil
    _refused(capsys, main(["simulate", "--agent", str(run), "--steps", "5", "--out", str(tmp_path / "s.npz")]),
             run, marker)
    _refused(capsys, main(["train", str(CONFIG), "--out", str(run), "--resume", "--no-progress"]), run, marker)
    bag = tmp_path / "bag"
    _write_bag(bag, agent=str(run))
    _refused(capsys, main(["replay", str(bag), "--agent", str(run), "--out", str(tmp_path / "r1"), "--no-gif"]),
             run, marker)
    _refused(capsys, main(["launch", "lissajous_open", "--agent", str(run), "--duration", "0.1"]), run, marker)
    assert not (tmp_path / "s.npz").exists()


def test_replay_never_loads_the_agent_a_bag_names(evil, tmp_path, capsys):
    run, marker = evil
    bag = tmp_path / "bag"
    _write_bag(bag, agent=str(run))
    assert main(["replay", str(bag), "--out", str(tmp_path / "r"), "--no-gif"]) == 0
    assert not marker.exists(), "replay loaded the checkpoint named in the bag"
    captured = capsys.readouterr()
    assert f"--agent {run}" in captured.err and "was not loaded" in captured.err
    assert '"agent": null' in captured.out and f'"bag_agent": "{run}"' in captured.out


@pytest.mark.parametrize("node", ["body_sim", "swg_brain"])
def test_nodes_refuse_a_code_checkpoint(evil, ros_env, node):
    run, marker = evil
    proc = subprocess.run([sys.executable, "-m", "bptsb_ros.cli", "run", node, "--ros-args", "-p", f"agent:={run}"],
                          env=env_for(ros_env), cwd=REPO, capture_output=True, text=True, timeout=120)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert not marker.exists(), "the node ran the checkpoint's payload"
    assert f"checkpoint {run / 'checkpoint.pt'} is refused" in out and "Traceback" not in out, out


def _write_bag(bag: Path, agent: str) -> None:
    """A three-step bag of a 3-mass body whose custom_data names ``agent``."""
    import numpy as np

    from bptsb_ros.bags.writer import BagWriter

    with BagWriter(bag, custom_data={"loop": "lissajous_open", "mode": "lockstep", "agent": agent}) as w:
        for k in range(3):
            pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.1 * k]])
            w.write_message("/body/positions", m.pose_array(k, DT_NS, pos, "msdn"), k * DT_NS)
