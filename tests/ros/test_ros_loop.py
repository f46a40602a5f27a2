"""Whole loops started and stopped by ``bptsb launch`` (separate processes, recorded to a bag):
lockstep runs equal the offline simulation of the same agent, realtime runs report their timing and
stop cleanly on Ctrl-C, and a failing node makes the launch fail. On the session's private ROS domain
(``ros_env`` fixture); the tests run one after the other."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from ros_live import REPO, bag_positions, bptsb, env_for, fresh_agent, save_fitted_agent, stamp_ns, stop

DT_NS = 10_000_000


def check_every_step(stamps: np.ndarray, steps: int) -> None:
    assert stamps.tolist() == [k * DT_NS for k in range(steps + 1)], "steps missing, repeated or out of order"


def launch_ok(args: list[str], ros_env: dict[str, str]) -> str:
    out = bptsb(["launch", *args], ros_env)
    assert out.returncode == 0, out.stdout[-4000:]
    return out.stdout


@pytest.mark.slow
def test_lissajous_open_lockstep_equals_offline(tmp_path, ros_env):
    from bptsb_ros.bags.reader import bag_info, read_messages
    from bptsb_ros.sim.rollout import simulate_open_loop

    bag = tmp_path / "bag"
    out = launch_ok(["lissajous_open", "--duration", "1", "--bag", str(bag)], ros_env)
    for node in ("body_sim", "swg_brain", "recorder"):
        assert f"{node:<15} ok" in out
    stamps, pos = bag_positions(bag)
    check_every_step(stamps, 100)
    agent = fresh_agent("lissajous")
    roll = simulate_open_loop(agent, 100)
    ref = agent.body.full_positions(roll.r[:, 0]).numpy()
    assert np.abs(pos - ref).max() <= 1e-9
    commands = np.array([np.asarray(m.position) for *_, m in read_messages(bag, ["/brain/rest_length"])])
    np.testing.assert_allclose(commands, roll.rest_length[:, 0].numpy(), rtol=0, atol=1e-12)
    # the body's own rest-length topic: every state_every (10) steps (at steps 6 mod 10), stamped with its step
    rest = {stamp_ns(m.header.stamp) // 10_000_000: np.asarray(m.position)
            for *_, m in read_messages(bag, ["/body/rest_length"])}
    assert sorted(rest) == list(range(6, 101, 10))
    for k, values in rest.items():
        np.testing.assert_allclose(values, roll.rest_length[k, 0].numpy(), rtol=0, atol=1e-12)
    counts = {t.name: t.message_count for t in bag_info(bag).topics}
    assert counts["/clock"] == counts["/brain/rest_length"] == counts["/body/positions"] == 101
    assert counts["/body/spring_lengths"] == counts["/body/mass_states"] == 10  # steps 4 and 2 mod 10
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["steps"] == 100 and summary["safe_command_steps"] == 0 and summary["rejected_total"] == 0


@pytest.mark.slow
def test_lissajous_closed_loop_equals_offline(tmp_path, ros_env):
    """SWG for steps 0..30, then the fitted feedback layer: offline open loop followed by closed loop."""
    from bptsb_ros.sim.rollout import simulate_closed_loop, simulate_open_loop
    from bptsb_ros.training.checkpoint import load_agent

    run = tmp_path / "agent"
    save_fitted_agent(run)
    bag = tmp_path / "bag"
    launch_ok(["lissajous_closed", "--agent", str(run), "--open-loop-steps", "30", "--duration", "1.5",
               "--bag", str(bag)], ros_env)
    stamps, pos = bag_positions(bag)
    check_every_step(stamps, 150)
    agent = load_agent(run, dtype=torch.float64)
    body = agent.body
    open_part = simulate_open_loop(agent, 30)
    closed = simulate_closed_loop(body, agent.feedback, 120, state=open_part.final)
    ref = torch.cat([body.full_positions(open_part.r[:, 0]), body.full_positions(closed.r[1:, 0])]).numpy()
    assert np.abs(ref - ref[0]).max() > 0.05  # the body really moves
    assert np.abs(pos - ref).max() <= 1e-9
    # replaying the live bag with its agent finds loop and warm-up in it and gives the offline metric
    from bptsb_ros.analysis.replay import replay

    metrics = replay(bag, tmp_path / "replay", run, gif=False)
    assert metrics["loop"] == "lissajous_closed" and metrics["missing_steps"] == 0
    # the spring lengths of every step, from the positions (body/spring_lengths goes out every 10th step)
    from bptsb_ros.analysis.bag_run import read_run

    lengths = torch.cat([open_part.length[:, 0], closed.length[1:, 0]]).numpy()
    assert np.abs(read_run(bag).spring_lengths - lengths).max() <= 1e-9
    assert any(f.endswith("spring_lengths.png") for f in metrics["files"])
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] <= 1e-9
    assert metrics["live"]["trajectory_mse_shift_min"] == pytest.approx(metrics["offline"]["trajectory_mse_shift_min"])


@pytest.mark.slow
def test_locomotion_headwind_lockstep_equals_offline(tmp_path, ros_env):
    """SWG + wind_source in lockstep: the wind switches on at the stated steps and the run equals the offline
    simulation under the same schedule; replay compares and shades the wind periods."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.analysis.bag_run import read_run
    from bptsb_ros.analysis.replay import replay, wind_periods
    from bptsb_ros.bags.reader import read_messages
    from bptsb_ros.config import validate
    from bptsb_ros.sim.rollout import simulate_open_loop
    from bptsb_ros.training.checkpoint import load_agent, save_checkpoint

    run = tmp_path / "agent"
    cfg = validate({"task": "locomotion", "seed": 2, "dtype": "float64", "feedback": {"enabled": False},
                    "brain": {"amplitude": 0.4},
                    "body": {"shape": "caterpillar", "nodes": 10, "environment": "locomotion", "ground_clamp": True},
                    "locomotion": {"wind_force": -3.0, "wind_period": 0.4}})
    save_checkpoint(run, build_agent(cfg))
    bag = tmp_path / "bag"
    launch_ok(["locomotion_headwind", "--agent", str(run), "--duration", "1", "--bag", str(bag)], ros_env)
    stamps, pos = bag_positions(bag)
    check_every_step(stamps, 100)
    # the schedule by hand: calm for t mod 0.4 in [0, 0.2), blowing (-3 N) in [0.2, 0.4)
    expected = np.array([-3.0 if (k % 40) >= 20 else 0.0 for k in range(101)])
    wind = {int(round((m.header.stamp.sec * 1e9 + m.header.stamp.nanosec) / DT_NS)): m.vector.x
            for *_, m in read_messages(bag, ["/env/wind"])}
    assert [wind[k] for k in range(101)] == expected.tolist()
    agent = load_agent(run, dtype=torch.float64)
    w = torch.zeros(101, 2, dtype=torch.float64)
    w[:, 0] = torch.from_numpy(expected)
    roll = simulate_open_loop(agent, 100, wind=w)
    ref = agent.body.full_positions(roll.r[:, 0]).numpy()
    calm = simulate_open_loop(agent, 100)
    assert np.abs(agent.body.full_positions(calm.r[:, 0]).numpy() - ref).max() > 1e-3  # the wind matters
    assert np.abs(pos - ref).max() <= 1e-9
    force = {stamp_ns(m.header.stamp) // DT_NS: np.asarray(m.effort)
             for *_, m in read_messages(bag, ["/body/external_force"])}  # every 10 steps, at 8 mod 10
    assert sorted(force) == list(range(8, 101, 10))
    np.testing.assert_array_equal([force[k][0] for k in sorted(force)], expected[8::10])  # x force on mass 0
    np.testing.assert_allclose(wind_periods(read_run(bag)), [(0.2, 0.4), (0.6, 0.8), (1.0, 1.01)], atol=1e-12)
    metrics = replay(bag, tmp_path / "replay", run, gif=False)  # the agent only from the user, never from the bag
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] <= 1e-9
    assert (tmp_path / "replay" / "speed.png").is_file()


@pytest.mark.slow
def test_narma_lockstep_equals_offline(tmp_path, ros_env):
    from bptsb_ros.sim.inputs import narma_inputs
    from bptsb_ros.sim.rollout import held_inputs, simulate_open_loop

    bag = tmp_path / "bag"
    launch_ok(["narma", "--duration", "1", "--bag", str(bag)], ros_env)
    stamps, pos = bag_positions(bag)
    check_every_step(stamps, 100)
    agent = fresh_agent("narma")
    n = agent.config["narma"]
    u = narma_inputs(n["eval_seed"], n["n_inputs"])
    inputs = torch.from_numpy(held_inputs(u, n["tau"], 100)).to(torch.float64) * n["input_scale"]
    roll = simulate_open_loop(agent, 100, inputs=inputs)
    ref = agent.body.full_positions(roll.r[:, 0]).numpy()
    assert np.abs(ref - ref[0]).max() > 1e-3
    assert np.abs(pos - ref).max() <= 1e-9


def _node_pids(launcher: int, nodes: tuple[str, ...]) -> dict[str, int]:
    """The process ids of ``nodes`` among the launcher's children (from /proc)."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) != launcher:  # the parent's pid, after the command's name
            continue
        for node in nodes:
            if f"bptsb_ros.ros.{node}" in cmdline:
                out[node] = int(entry.name)
    return out


def _threads_cpus(pid: int) -> list[str]:
    """Each thread's ``Cpus_allowed_list`` (from /proc/PID/task/*/status)."""
    lists = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            status = (task / "status").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        lists += [line.split(":", 1)[1].strip() for line in status.splitlines()
                  if line.startswith("Cpus_allowed_list:")]
    return lists


@pytest.mark.slow
def test_realtime_loop_stops_cleanly_on_ctrl_c(tmp_path, ros_env):
    """Also the body's per-step timing records (``timing_path``, what ``bptsb bench --realtime`` reads), written at
    a Ctrl-C stop too, with the executor the body was given (single here; the other runs use the default); and the
    body and its brain on one CPU (their ``cpus``): every thread of both processes allowed on that CPU only."""
    from bptsb_ros.bench.realtime import condition_result
    from bptsb_ros.live.step_times import load_step_times

    bag, times = tmp_path / "bag", tmp_path / "times.npz"
    cpu = max(os.sched_getaffinity(0))
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", "lissajous_open", "--mode", "realtime",
                             "--duration", "60", "--bag", str(bag), "--param", f"body_sim:timing_path:={times}",
                             "--param", "body_sim:executor:=single", "--param", f"body_sim:cpus:={cpu}",
                             "--param", f"swg_brain:cpus:={cpu}"], env=env_for(ros_env), cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []

    def read_output() -> None:  # in a thread, so that waiting for a line never blocks the test past its deadline
        for line in proc.stdout:
            lines.append(line)

    reader = threading.Thread(target=read_output, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 60
        while not any("[body_sim]" in line and "running" in line for line in list(lines)):
            assert proc.poll() is None, "launch exited before body_sim started:\n" + "".join(lines)[-4000:]
            assert time.monotonic() < deadline, "body_sim never started:\n" + "".join(lines)[-4000:]
            time.sleep(0.05)
        time.sleep(1.5)  # ~150 steps at 100 Hz
        allowed = {node: _threads_cpus(pid) for node, pid in _node_pids(proc.pid, ("body_sim", "swg_brain")).items()}
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        reader.join(timeout=10)
    finally:
        stop(proc)  # SIGINT, then SIGKILL: no launcher (nor, through it, node) outlives a failed test
    text = "".join(lines)
    assert proc.returncode == 0, text[-4000:]
    assert "stopping (SIGINT)" in text and "body_sim        ok" in text and "recorder        ok" in text
    stamps, _ = bag_positions(bag)
    assert len(stamps) >= 50
    check_every_step(stamps, len(stamps) - 1)
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["mode"] == "realtime" and summary["steps"] == len(stamps) - 1
    for key in ("jitter_ms_p99", "command_latency_ms_p99", "command_age_steps_max", "deadline_misses"):
        assert key in summary
    assert summary["jitter_ms_p50"] < 20.0 and summary["cpus"] == str(cpu)
    for node in ("body_sim", "swg_brain"):
        assert any(line.startswith(f"[{node}]") and f"running on CPU(s) {cpu}" in line for line in lines), text[-4000:]
    assert set(allowed) == {"body_sim", "swg_brain"} and all(len(cpus) > 3 for cpus in allowed.values()), allowed
    if len(os.sched_getaffinity(0)) > 1:  # with one CPU allowed, pinned and not pinned look the same
        assert all(set(cpus) == {str(cpu)} for cpus in allowed.values()), allowed  # every thread, the middleware's
    records = load_step_times(times)
    # one record per integrated step, 0..steps (the summary's steps, like the bag's stamps, count from step 0)
    assert records["step"].tolist() == list(range(summary["steps"] + 1)) and records["period"] == pytest.approx(0.01)
    r = condition_result(summary, records)  # the records' misses by the body's own rule: its counter
    assert r["executor"] == "single" and r["steps"] == summary["steps"] + 1 and r["rt_priority"] == 0
    assert r["deadline_misses"] == summary["deadline_misses"] == r["deadline_misses_counted_by_body"]
    assert 0 < r["compute_p50_ms"] <= r["compute_p99_ms"] <= r["compute_max_ms"]


@pytest.mark.slow
def test_failing_node_fails_the_launch(tmp_path, ros_env):
    out = bptsb(["launch", "lissajous_open", "--duration", "0.3", "--log-dir", str(tmp_path),
                 "--param", "swg_brain:dtype:=float16", "--param", "body_sim:startup_timeout:=5.0"], ros_env)
    assert out.returncode == 1, out.stdout[-4000:]
    assert "parameter 'dtype'" in out.stdout
    assert "swg_brain       failed (exited on its own before the end, code 2)" in out.stdout
    assert "stopping (swg_brain exited early with code 2; the loop is broken)" in out.stdout
    assert "body_sim        ok" in out.stdout


@pytest.mark.parametrize("args, message", [
    (["lissajous_closed", "--duration", "1"], "needs --agent"),
    (["narma", "--param", "swg_brain:x:=1"], "not part of this loop"),
])
def test_launch_rejects_bad_arguments(args, message, ros_env):
    out = bptsb(["launch", *args], ros_env)
    assert out.returncode == 2 and message in out.stdout


def test_launch_help_lists_the_loops(ros_env):
    out = bptsb(["launch", "--help"], ros_env)
    assert out.returncode == 0
    for loop in ("lissajous_open", "lissajous_closed", "locomotion_open", "locomotion_closed", "narma"):
        assert loop in out.stdout


@pytest.mark.slow
def test_run_starts_one_node_and_validates_its_parameters(tmp_path, ros_env):
    summary = tmp_path / "summary.json"
    ok = bptsb(["run", "body_sim", "--ros-args", "--params-file", "config/body_sim_params.yaml", "-p", "max_steps:=2",
                "-p", "final_ack_timeout:=0.0", "-p", f"summary_path:={summary}"], ros_env)
    assert ok.returncode == 0, ok.stdout
    assert json.loads(summary.read_text())["steps"] == 2
    bad = bptsb(["run", "body_sim", "--ros-args", "-p", "mode:=fast"], ros_env)
    assert bad.returncode == 2 and "parameter 'mode': 'fast' not allowed; choose from lockstep, realtime" in bad.stdout


@pytest.mark.slow
def test_two_namespaced_loops_in_one_domain_each_equal_offline(tmp_path, ros_env):
    """Two robots at once in one domain (``--namespace r1`` and ``r2``, different seeds): each bag holds exactly its
    own robot's topics (its ``/rN/clock`` and ``/rN/diagnostics`` too), and each equals its own offline simulation."""
    from bptsb_ros.analysis.bag_run import read_run
    from bptsb_ros.bags.reader import bag_info, read_messages
    from bptsb_ros.interface.topics import TOPICS
    from bptsb_ros.ros.messages import pose_array_positions
    from bptsb_ros.sim.rollout import simulate_open_loop

    results: dict[str, subprocess.CompletedProcess] = {}

    def run(ns: str, seed: int) -> None:
        results[ns] = bptsb(["launch", "lissajous_open", "--namespace", ns, "--seed", str(seed), "--duration", "1",
                             "--bag", str(tmp_path / ns), "--param", "body_sim:state_every:=1"], ros_env)

    threads = [threading.Thread(target=run, args=(ns, seed)) for ns, seed in (("r1", 0), ("r2", 5))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for ns, seed in (("r1", 0), ("r2", 5)):
        out = results[ns]
        assert out.returncode == 0, out.stdout[-4000:]
        bag = tmp_path / ns
        names = {t.name for t in bag_info(bag).topics}
        own = {f"/{ns}/{TOPICS[k].name.lstrip('/')}" for k in ("clock", "diagnostics", "positions", "rest_length_cmd")}
        assert own <= names and all(n.startswith(f"/{ns}/") for n in names), names
        pos = np.array([pose_array_positions(m) for *_, m in read_messages(bag, [f"/{ns}/body/positions"])])
        agent = fresh_agent("lissajous", seed=seed)
        ref = agent.body.full_positions(simulate_open_loop(agent, 100).r[:, 0]).numpy()
        assert pos.shape == ref.shape and np.abs(pos - ref).max() <= 1e-9
        run = read_run(bag)  # what bptsb replay reads: the bag's custom_data names the namespace
        assert run.custom["namespace"] == f"/{ns}" and np.abs(run.positions - ref).max() <= 1e-9
        layout = json.loads((tmp_path / f"{ns}.launch" / "foxglove_layout.json").read_text())  # this robot's viewer
        assert layout["configById"]["3D!body"]["followTf"] == f"{ns}/msdn"
        assert f"Fixed Frame: {ns}/msdn" in (tmp_path / f"{ns}.launch" / "bptsb.rviz").read_text()
        markers = [m for *_, m in read_messages(bag, [f"/{ns}/body/markers"])]
        assert {mk.header.frame_id for m in markers for mk in m.markers} == {f"{ns}/msdn"}
        # state_every:=1: the body's rest lengths every step, as asked (by default every 10th)
        assert run.rest_length is not None and run.rest_length.shape == (101, agent.body.topology.n_springs)
    first = fresh_agent("lissajous", seed=0)
    # r2's bag is r2's run: robot r1's offline trajectory (seed 0) is not in it
    assert np.abs(first.body.full_positions(simulate_open_loop(first, 100).r[:, 0]).numpy() - pos).max() > 1e-6


@pytest.mark.slow
def test_a_loop_without_its_brain_fails_the_launch(tmp_path, ros_env):
    """swg_brain publishes where body_sim does not listen: the body starts without it (startup_timeout), runs every
    step on the safe command and exits 0 itself, but the launch fails with one line naming the silent brain."""
    out = bptsb(["launch", "lissajous_open", "--duration", "0.3", "--log-dir", str(tmp_path / "logs"),
                 "--param", "swg_brain:topics.rest_length_cmd:=/nowhere", "--param", "body_sim:startup_timeout:=1.0",
                 "--param", "body_sim:command_timeout:=0.2"], ros_env)
    assert out.returncode == 1, out.stdout[-4000:]
    assert "body_sim        ok" in out.stdout  # the body itself ended cleanly: the launcher decides
    summary = json.loads((tmp_path / "logs" / "body_summary.json").read_text())
    assert summary["silent_brain_steps"] == {"rest_length": 31}
    assert ("[launch] FAILED: body_sim ran on the safe command for lack of its brain (rest_length silent on 31 of "
            "steps 0..30)") in out.stdout

