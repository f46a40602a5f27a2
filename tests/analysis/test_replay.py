"""Replay analysis on a bag written (without a ROS graph) with the live nodes' own message builders."""

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import REPO_ROOT

from bptsb_ros.analysis.bag_run import read_run
from bptsb_ros.analysis.replay import replay
from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.writer import BagWriter
from bptsb_ros.config import load_config
from bptsb_ros.interface.topics import dt_to_ns, spring_names
from bptsb_ros.ros import messages as m
from bptsb_ros.sim.rollout import simulate_closed_loop
from bptsb_ros.sim.trajectory import trajectory_from_rollout
from bptsb_ros.training.checkpoint import load_agent
from bptsb_ros.workflows.train import train

pytestmark = pytest.mark.ros  # every test here builds ROS 2 messages (rclpy and the message packages)

CONFIG = REPO_ROOT / "config" / "lissajous_single.yaml"


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


def _lissajous_target(t: np.ndarray) -> np.ndarray:
    """The paper's figure-eight for the default config, typed here: X = Y = 4 m / 20, (α, β, δ) = (1, 2, 0), ω = 2π."""
    return np.stack([0.2 * np.cos(2 * np.pi * t), 0.2 * np.sin(4 * np.pi * t)], axis=-1)


def _write_planted_bag(bag: Path, positions: np.ndarray, cmp_index: int = -1, markers: bool = True) -> None:
    """A bag of given positions (T+1, N, 2) at steps 0..T (dt = 0.01 s); masses 0 and 1 fixed, springs to the last."""
    ns = dt_to_ns(0.01)
    n = positions.shape[1]
    springs = np.array([[i, n - 1] for i in range(n - 1)])
    fixed = np.arange(n) < 2
    with BagWriter(bag) as w:
        for k, pos in enumerate(positions):
            w.write_message("/body/positions", m.pose_array(k, ns, pos, "msdn"), k * ns)
            if markers and k % 50 == 0:
                w.write_message("/body/markers", m.body_markers(k, ns, pos, springs, fixed, cmp_index,
                                                                np.zeros(len(springs)), "msdn", 0.1), k * ns)


def test_replay_lissajous_metric_of_a_planted_run(tmp_path):
    """A CMP 30 steps behind the target and 0.01 m off in x and y: the best shift (70 steps) leaves exactly
    1e-4 m² in every period; the unshifted MSE is computed here from the raw positions."""
    steps = 500
    t = np.arange(steps + 1) * 0.01
    cmp = _lissajous_target(t - 0.30) + 0.01
    positions = np.zeros((steps + 1, 3, 2))
    positions[:, 0], positions[:, 1] = (-1.0, 0.0), (1.0, 0.0)
    positions[:, 2] = cmp
    _write_planted_bag(tmp_path / "bag", positions, cmp_index=2)
    metrics = replay(tmp_path / "bag", tmp_path / "out", task="lissajous", gif=False)
    live = metrics["live"]
    assert metrics["recorded_steps"] == steps + 1 and metrics["missing_steps"] == 0
    assert live["trajectory_mse"] == pytest.approx(float(np.mean((cmp - _lissajous_target(t)) ** 2)), rel=1e-12)
    assert live["trajectory_mse"] > 0.01  # unshifted, the delay dominates
    assert live["trajectory_mse_shift_min"] == pytest.approx(1e-4, rel=1e-9)
    assert live["trajectory_mse_shift_min_second_half"] == pytest.approx(1e-4, rel=1e-9)


def test_replay_locomotion_speed_of_a_planted_walk(tmp_path):
    steps = 400
    t = np.arange(steps + 1) * 0.01
    positions = np.zeros((steps + 1, 4, 2))
    positions[..., 0] = np.array([0.0, 0.2, 0.4, 0.6]) + 0.25 * t[:, None] + 0.03 * np.sin(2 * np.pi * t)[:, None]
    positions[..., 1] = 0.1 + 0.02 * np.cos(2 * np.pi * t)[:, None]
    _write_planted_bag(tmp_path / "bag", positions, markers=False)
    metrics = replay(tmp_path / "bag", tmp_path / "out", task="locomotion", gif=False)
    # (mean x at 4 s − mean x at 0) / 4 s from the raw positions: 0.25 m/s (the wobble is back at its start)
    expected = (positions[-1, :, 0].mean() - positions[0, :, 0].mean()) / 4.0
    assert expected == pytest.approx(0.25, abs=1e-12)
    assert metrics["live"]["mean_forward_speed"] == pytest.approx(expected, rel=1e-12)
