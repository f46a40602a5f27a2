"""A hostile publisher on the body's domain, where only the live graph can tell: a node that is
not an allowed publisher can neither take over the body with commands stamped ahead nor have any command
integrated (body_sim asks the ROS graph who publishes); ``on_divergence: stop`` ends a launched run with a
finalised bag; a forged ``/body/positions`` publisher is recorded as foreign. The rules themselves (bounds,
wrong size, NaN, stale, divergence recovery, perturbation and reset checks) are tested without DDS in
``test_live_core.py``."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from ros_live import Probe, fresh_agent, start_node, stop

pytestmark = pytest.mark.slow  # each test here runs a launched loop of several seconds

DT_NS = 10_000_000
STEPS = 8


def test_an_untrusted_publisher_never_steers_the_body(tmp_path, fresh_ros):
    """The brain ``test_brain`` is the allowed publisher; from step 5 a node ``intruder`` stamps its own rest
    lengths for steps 5..10: none is integrated (the body runs on the brain's commands or the safe command). A
    perturbation sent on body/perturb at step 0 for step 3 is applied there (the topic's wiring)."""
    ros_domain_id, ros_env = fresh_ros  # a domain no earlier test used: the graph shows only this run
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from bptsb_ros.interface.topics import mass_dof_names, spring_names
    from bptsb_ros.ros import messages as m

    agent = fresh_agent("lissajous")
    base = agent.body.l.numpy()
    names = spring_names(base.size)
    dofs = mass_dof_names(agent.body.movable_index.tolist())
    good = [base * (1 + 0.001 * k) for k in range(STEPS + 1)]
    evil = base * 1.5
    brain = Probe(ros_domain_id, "test_brain")
    intruder: list[Probe] = []
    cq = m.command_qos(100)
    rest_pub = brain.node.create_publisher(JointState, "/brain/rest_length", cq)
    perturb_pub = brain.node.create_publisher(JointState, "/body/perturb", cq)

    def on_clock(msg: Clock) -> None:
        k = m.step_of(msg.clock, DT_NS)
        if k == 0:
            assert Probe.wait_matched([rest_pub, perturb_pub], 10.0)
            perturb_pub.publish(m.joint_state(3, DT_NS, dofs, position=np.full(len(dofs), 0.01)))
        if k == 5:  # a node that is not an allowed publisher joins and stamps commands ahead of the brain
            intruder.append(Probe(ros_domain_id, "intruder"))
            pub = intruder[0].node.create_publisher(JointState, "/brain/rest_length", cq)
            assert Probe.wait_matched([pub], 30.0)  # discovery of a new participant: seconds on loaded cores
            for ahead in range(5, STEPS + 3):
                pub.publish(m.joint_state(ahead, DT_NS, names, position=evil))
        rest_pub.publish(m.joint_state(k, DT_NS, names, position=good[k]))

    sq = m.state_qos(100)
    brain.subscribe(Clock, "/clock", sq, on_clock)
    brain.subscribe(JointState, "/body/rest_length", sq)
    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {
        # command_timeout outlasts the intruder's discovery: the brain's step-5 command waits for it (below)
        "task": "lissajous", "max_steps": STEPS, "wait_for": ["rest_length"], "command_timeout": 8.0,
        "wait_for_subscribers": ["/clock:1", "/body/rest_length:1"],
        "summary_path": str(summary), "final_ack_timeout": 1.0, "command_publishers": ["test_brain"],
        "every_step": ["rest_length"],  # the rest lengths in force at every step, read below
    }, ros_env, tmp_path / "body.log")
    try:
        assert brain.spin_until(lambda: body.poll() is not None, 90)
        brain.spin_until(lambda: len(brain.messages["/body/rest_length"]) >= STEPS + 1, 5)
    finally:
        stop(body)
        brain.close()
        for probe in intruder:
            probe.close()
    log = (tmp_path / "body.log").read_text()
    assert body.returncode == 0, log
    # the intruder is named (a participant of an earlier test in this domain may still be listed until its lease ends)
    named = re.findall(r"/brain/rest_length also has publisher\(s\) not in command_publishers \(([^)]*)\)", log)
    assert any("/intruder" in found.split(", ") for found in named), log
    applied = np.array([np.asarray(msg.position) for msg in brain.messages["/body/rest_length"]])
    assert len(applied) == STEPS + 1
    np.testing.assert_array_equal(applied[:5], good[:5])  # before the intruder: the brain's commands
    assert not any(np.array_equal(row, evil) for row in applied), "an intruder's command was integrated"
    assert all(np.array_equal(row, good[k]) or np.array_equal(row, base) for k, row in enumerate(applied))
    counts = json.loads(summary.read_text())
    assert counts["rest_length_rejected_untrusted_publisher"] >= 1 and counts["perturbation_steps"] == [3]


def test_divergence_with_on_divergence_stop_ends_the_run_with_a_finalised_bag(tmp_path, ros_env, ros_domain_id):
    """``on_divergence: stop``: the body ends the run cleanly at the first diverged step; the recorder still
    closes the bag, which holds every step up to the divergence and the ERROR status."""
    import subprocess
    import sys

    from diagnostic_msgs.msg import DiagnosticStatus
    from ros_live import REPO, env_for
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from bptsb_ros.bags.reader import bag_info, read_messages
    from bptsb_ros.interface.topics import mass_dof_names
    from bptsb_ros.ros import messages as m

    dofs = mass_dof_names(fresh_agent("lissajous").body.movable_index.tolist())
    probe = Probe(ros_domain_id, "mlp_brain")  # an allowed force publisher's name (a forged one, here)
    force_pub = probe.node.create_publisher(JointState, "/brain/force", m.command_qos(100))

    def on_clock(msg: Clock) -> None:  # like a brain: the force of step k on /clock t_k; 1e11 N from step 20
        k = m.step_of(msg.clock, DT_NS)
        force_pub.publish(m.joint_state(k, DT_NS, dofs, effort=np.full(len(dofs), 1e11 if k >= 20 else 0.0)))

    probe.subscribe(Clock, "/clock", m.state_qos(100), on_clock)
    bag = tmp_path / "bag"
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", "lissajous_open", "--duration", "2",
                             "--bag", str(bag), "--param", "body_sim:on_divergence:=stop",
                             "--param", "body_sim:max_force:=1e12",
                             "--param", "body_sim:wait_for:=[rest_length, force]", "--timeout", "120"],
                            env=env_for(ros_env), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert probe.spin_until(lambda: proc.poll() is not None, 150)
        out = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        probe.close()
    assert proc.returncode == 1, out  # the body reports the failure ...
    assert "stopping the run (on_divergence: stop)" in out and "Traceback" not in out, out
    assert "recorder        ok" in out and "swg_brain       ok" in out, out  # ... and everything else stopped cleanly
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["divergences"] == 1 and summary["steps"] == 19 and summary["force_accepted"] >= 21
    info = bag_info(bag)  # finalised: metadata.yaml and a complete, indexed MCAP file
    steps = sorted(m.header.stamp.sec * 1_000_000_000 // DT_NS + m.header.stamp.nanosec // DT_NS
                   for *_, m in read_messages(bag, ["/body/positions"]))
    assert info.message_count > 0 and steps == list(range(20))  # steps 0..19; step 20 diverged
    statuses = [s for *_, d in read_messages(bag, ["/diagnostics"]) for s in d.status]
    assert any(s.level == DiagnosticStatus.ERROR and "step 20 diverged" in s.message for s in statuses)


def test_forged_body_positions_are_recorded_as_foreign_and_ignored_by_replay(tmp_path, fresh_ros):
    """A node named ``forger`` publishes /body/positions (all masses at (7, 7)) for every step of a lockstep run,
    from the moment it sees the recorder (30 s of simulated time, so discovery under load leaves it many steps):
    the bag keeps its messages on a channel marked with its node and GID, next to the body's; replay uses only
    body_sim's, reports the forger's by name and count, and the replayed run equals the offline one."""
    ros_domain_id, ros_env = fresh_ros  # a domain no earlier test used: the graph shows only this run
    import subprocess
    import sys

    from geometry_msgs.msg import PoseArray
    from mcap.reader import make_reader
    from ros_live import REPO, env_for
    from rosgraph_msgs.msg import Clock

    from bptsb_ros.agent import build_agent
    from bptsb_ros.analysis.replay import replay
    from bptsb_ros.config import validate
    from bptsb_ros.ros import messages as m
    from bptsb_ros.training.checkpoint import save_checkpoint

    run = tmp_path / "agent"
    save_checkpoint(run, build_agent(validate({"task": "lissajous", "seed": 0, "dtype": "float64",
                                               "feedback": {"enabled": False}})))
    n_masses = fresh_agent("lissajous").body.topology.n_masses
    forged = np.full((n_masses, 2), 7.0)
    forger = Probe(ros_domain_id, "forger")
    pub = forger.node.create_publisher(PoseArray, "/body/positions", m.state_qos(100))
    sent: list[int] = []

    def on_clock(msg: Clock) -> None:  # forge the state of every step the body announces, once the recorder listens
        if pub.get_subscription_count() >= 1:
            k = m.step_of(msg.clock, DT_NS)
            pub.publish(m.pose_array(k, DT_NS, forged, "msdn"))
            sent.append(k)

    forger.subscribe(Clock, "/clock", m.state_qos(100), on_clock)
    # the body's first step waits for the forger's /clock subscription too, so the forger is discovered before
    # the run starts (a loaded CI machine once ran all 301 steps before it was; none of its messages landed)
    from bptsb_ros.live.loops import LOOPS, startup_subscribers

    waits = [f"{topic}:{int(n) + (topic == '/clock')}" for topic, n in
             (e.rsplit(":", 1) for e in startup_subscribers(LOOPS["lissajous_open"], recording=True))]
    assert any(w.startswith("/clock:") for w in waits), waits
    bag = tmp_path / "bag"
    # --allow-loss: the forger publishes without waiting for the recorder, so on a loaded machine its queue drops
    # forged messages (144 of 301 once in CI) and the recording counts them as lost; that every message of the
    # body itself is in the bag is asserted below
    proc = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", "lissajous_open", "--agent", str(run),
                             "--duration", "30", "--bag", str(bag), "--timeout", "120", "--allow-loss",
                             "--param", f"body_sim:wait_for_subscribers:=[{', '.join(repr(w) for w in waits)}]"],
                            env=env_for(ros_env), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert forger.spin_until(lambda: proc.poll() is not None, 150)
        out = proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        forger.close()
    assert proc.returncode == 0, out[-4000:]
    metrics = replay(bag, tmp_path / "replay", run, gif=False)
    assert metrics["offline_comparison"]["max_abs_position_difference_m"] <= 1e-9  # the forged states are not used
    assert metrics["recorded_steps"] == 3001 and metrics["missing_steps"] == 0
    from bptsb_ros.bags.reader import read_published

    by_node: dict[str, list[int]] = {}
    for (_, _, _, msg), publisher in read_published(bag, ["/body/positions"]):
        by_node.setdefault(publisher.name, []).append(m.step_of(msg.header.stamp, DT_NS))
    assert sorted(by_node["/body_sim"]) == list(range(3001))
    # how many forged steps land depends on how soon the forger and the recorder match (24 of 301 once on a
    # loaded CI machine; a lockstep loop now runs 301 steps in well under a second, so the run is 3,001 steps long
    # to leave the recorder time to discover the forger): a forged message recorded among the body's, on several steps
    assert set(by_node) == {"/body_sim", "/forger"} and len(by_node["/forger"]) >= 10, {k: len(v) for k, v in
                                                                                       by_node.items()}
    with open(bag / "bag_0.mcap", "rb") as f:  # the forger's channel, read without our reader
        reader = make_reader(f)
        channels = [c for c in reader.get_summary().channels.values() if c.topic == "/body/positions"]
        named_at_close = {k: v for r in reader.iter_metadata() if r.name == "bptsb_ros.publishers"
                          for k, v in r.metadata.items()}
    gids = [c.metadata["publisher_gid"] for c in channels]
    assert len(set(gids)) == 2
    # a channel names its node as the graph knew it at the first message ('' when discovery had not named it
    # yet); the record written at close names every publisher
    assert all(c.metadata["publisher_node"] in ("", named_at_close[c.metadata["publisher_gid"]].rpartition("/")[2])
               for c in channels)
    assert sorted(named_at_close[g] for g in gids) == ["/body_sim", "/forger"]
    assert metrics["publishers"]["checked"] is True
    assert metrics["publishers"]["foreign"] == {"/body/positions": {"/forger": len(by_node["/forger"])}}
    assert metrics["publishers"]["duplicates"] == {}
