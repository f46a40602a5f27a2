"""Replay analysis on a bag written (without a ROS graph) with the live nodes' own message builders."""

from pathlib import Path

import numpy as np
import pytest
import torch

from bptsb_ros.analysis.replay import read_run, replay
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.config import load_config
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.topics import dt_to_ns, spring_names
from bptsb_ros.sim.rollout import simulate_closed_loop
from bptsb_ros.sim.trajectory import trajectory_from_rollout
from bptsb_ros.training.checkpoint import load_agent
from bptsb_ros.training.trainer import train

CONFIG = Path(__file__).resolve().parents[1] / "config" / "lissajous_single.yaml"


@pytest.fixture(scope="module")
def agent_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("agent")
    cfg = load_config(CONFIG, ["sim_time=20", "feedback.fit_time=10", "lissajous.eval_periods=2"])
    train(cfg, out, progress=False)
    return out


def _write_closed_loop_bag(agent_dir: Path, bag: Path, steps: int, drop: int | None = None) -> np.ndarray:
    agent = load_agent(agent_dir, dtype=torch.float64)
    body = agent.body
    traj = trajectory_from_rollout(body, simulate_closed_loop(body, agent.feedback, steps))
    ns = dt_to_ns(body.dt)
    names = spring_names(body.topology.n_springs)
    topo = body.topology
    with BagWriter(bag, custom_data={"loop": "lissajous_closed", "mode": "lockstep", "agent": str(agent_dir)}) as w:
        for k in range(steps + 1):
            if k == drop:
                continue
            t = k * ns
            pos = traj.positions[k]
            lengths = np.linalg.norm(pos[topo.springs[:, 0]] - pos[topo.springs[:, 1]], axis=1)
            w.write_message("/body/positions", m.pose_array(k, ns, traj.positions[k], "msdn"), t)
            w.write_message("/body/spring_lengths", m.joint_state(k, ns, names, position=lengths), t)
            w.write_message("/body/rest_length", m.joint_state(k, ns, names, position=traj.rest_length[k]), t)
            if k % 50 == 0:
                strain = lengths / traj.rest_length[k] - 1
                w.write_message("/body/markers", m.body_markers(k, ns, traj.positions[k], topo.springs, topo.fixed,
                                                                topo.cmp_index, strain, "msdn", 0.1), t)
    return traj.positions


def test_replay_rebuilds_the_run_and_matches_offline(agent_dir, tmp_path):
    positions = _write_closed_loop_bag(agent_dir, tmp_path / "bag", 400)
    run = read_run(tmp_path / "bag")
    agent = load_agent(agent_dir)
    assert np.array_equal(run.springs, agent.body.topology.springs)
    assert np.array_equal(run.fixed, agent.body.topology.fixed)
    assert run.cmp_index == agent.body.topology.cmp_index
    assert run.dt == pytest.approx(0.01) and run.missing_steps == []
    assert np.array_equal(run.positions, positions)
    metrics = replay(tmp_path / "bag", tmp_path / "out", agent_dir, gif=False)  # loop found in custom_data
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] == 0.0
    assert metrics["live"]["trajectory_mse_shift_min"] == pytest.approx(metrics["offline"]["trajectory_mse_shift_min"])
    assert (tmp_path / "out" / "metrics.json").is_file() and (tmp_path / "out" / "lissajous.png").is_file()


def test_replay_reports_missing_steps(agent_dir, tmp_path):
    _write_closed_loop_bag(agent_dir, tmp_path / "bag", 250, drop=120)
    metrics = replay(tmp_path / "bag", tmp_path / "out", agent_dir, gif=True)
    assert metrics["missing_steps"] == 1
    assert (tmp_path / "out" / "replay.gif").is_file()


def test_replay_needs_the_body_topics(tmp_path):
    with BagWriter(tmp_path / "bag") as w:
        w.write_message("/other", m.clock_msg(1, 10_000_000), 10_000_000)
    with pytest.raises(BagError, match="no /body/positions"):
        read_run(tmp_path / "bag")
