"""Faults in the live loop, with node processes and a probe node in the test: a brain that dies
mid-run (the body keeps running with the safe command and says so) and wrong-length, NaN/inf and
stale commands (rejected with a log line, never integrated). On the session's private ROS domain (``ros_env``,
``ros_domain_id`` fixtures); the tests run one after the other.

The brain-dies test runs in a quarantine domain of its own: the brain it kills with SIGKILL stays in DDS
discovery (a stale ``/clock`` subscriber) until its lease expires, which would let a later body in the same
domain start before its real subscribers matched."""

from __future__ import annotations

import json

import numpy as np
import torch
from ros_live import Probe, fresh_agent, stamp_ns, start_node, stop

DT_NS = 10_000_000


def test_bad_commands_are_rejected_and_never_integrated(tmp_path, ros_env, ros_domain_id):
    from geometry_msgs.msg import Vector3Stamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.topics import mass_dof_names, spring_names

    agent = fresh_agent("lissajous")
    base = agent.body.l.numpy()
    names = spring_names(base.size)
    dofs = mass_dof_names(agent.body.movable_index.tolist())
    good_rest = [base * (1 + 0.01 * k) for k in range(3)]
    good_force = [np.full(len(dofs), 0.1 * k) for k in range(3)]
    probe = Probe(ros_domain_id)
    cq = m.command_qos(100)
    rest_pub = probe.node.create_publisher(JointState, "/brain/rest_length", cq)
    force_pub = probe.node.create_publisher(JointState, "/brain/force", cq)
    wind_pub = probe.node.create_publisher(Vector3Stamped, "/env/wind", cq)

    def on_clock(msg: Clock) -> None:
        k = m.step_of(msg.clock, DT_NS)
        if k == 0:  # like a brain: send only once the body's subscriptions are matched
            assert Probe.wait_matched([rest_pub, force_pub, wind_pub], 10.0)
            rest_pub.publish(m.joint_state(0, DT_NS, names[:-1], position=base[:-1]))  # wrong length
            bad = base.copy()
            bad[3] = np.nan
            rest_pub.publish(m.joint_state(0, DT_NS, names, position=bad))
            rest_pub.publish(m.joint_state(0, DT_NS, ["x"] * len(names), position=base))  # wrong names
            force_pub.publish(m.joint_state(0, DT_NS, [], effort=np.zeros(len(dofs) + 2)))
            force_pub.publish(m.joint_state(0, DT_NS, [], effort=np.full(len(dofs), np.inf)))
            wind = Vector3Stamped()
            wind.vector.x = float("nan")
            wind_pub.publish(wind)
        if k == 1:
            rest_pub.publish(m.joint_state(0, DT_NS, names, position=base * 2))  # stale: step 0 is done
        rest_pub.publish(m.joint_state(k, DT_NS, names, position=good_rest[k]))
        force_pub.publish(m.joint_state(k, DT_NS, dofs, effort=good_force[k]))

    sq = m.state_qos(100)
    probe.subscribe(Clock, "/clock", sq, on_clock)
    probe.subscribe(JointState, "/body/rest_length", sq)
    probe.subscribe(JointState, "/body/external_force", sq)
    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {
        "task": "lissajous", "max_steps": 2, "wait_for": ["rest_length", "force"], "command_timeout": 10.0,
        "wait_for_subscribers": ["/clock:1", "/body/rest_length:1", "/body/external_force:1"],
        "summary_path": str(summary), "final_ack_timeout": 1.0, "command_publishers": ["test_probe"],
    }, ros_env, tmp_path / "body.log")
    try:
        assert probe.spin_until(lambda: body.poll() is not None, 60)
        probe.spin_until(lambda: len(probe.messages["/body/external_force"]) >= 3, 5)
    finally:
        stop(body)
        probe.close()
    log = (tmp_path / "body.log").read_text()
    assert body.returncode == 0, log
    for line in ("rejected rest_length command for step 0: 47 values, expected 48; not integrated",
                 "rejected rest_length command for step 0: NaN/inf at index 3",
                 "rejected rest_length command for step 0: joint names do not match",
                 "rejected force command for step 0: 28 values, expected 26",
                 "rejected force command for step 0: NaN/inf at index 0",
                 "rejected rest_length command for step 0 arrived after that step was integrated",
                 "rejected wind [nan, 0.0]: NaN/inf"):
        assert line in log, f"missing log line: {line}\n{log}"
    applied_rest = [np.asarray(msg.position) for msg in probe.messages["/body/rest_length"]]
    applied_force = [np.asarray(msg.effort) for msg in probe.messages["/body/external_force"]]
    assert len(applied_rest) == len(applied_force) == 3
    for k in range(3):
        assert (applied_rest[k] == good_rest[k]).all() and (applied_force[k] == good_force[k]).all()
    counts = json.loads(summary.read_text())
    assert counts["rest_length_rejected_wrong_length"] == counts["rest_length_rejected_non_finite"] == 1
    assert counts["rest_length_rejected_wrong_names"] == counts["rest_length_rejected_stale"] == 1
    assert counts["force_rejected_wrong_length"] == counts["force_rejected_non_finite"] == 1
    assert counts["rest_length_accepted"] == counts["force_accepted"] == 3 and counts["safe_command_steps"] == 0


def test_brain_dies_body_keeps_running_with_safe_command(tmp_path, quarantine_ros):
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros.messages import state_qos
    from bptsb_ros.sim.rollout import swg_rest_lengths

    ros_domain_id, ros_env = quarantine_ros
    probe = Probe(ros_domain_id)
    probe.subscribe(JointState, "/body/rest_length", state_qos(1000))
    received = probe.messages["/body/rest_length"]
    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {
        "task": "lissajous", "duration": 2.0, "wait_for": ["rest_length"], "command_timeout": 2.0,
        "wait_for_subscribers": ["/body/rest_length:1", "/clock:2"], "summary_path": str(summary),
    }, ros_env, tmp_path / "body.log")
    brain = start_node("swg_brain", {"task": "lissajous", "use_sim_time": True}, ros_env,
                       tmp_path / "brain.log")
    try:
        assert probe.spin_until(lambda: len(received) > 40, 60), (tmp_path / "body.log").read_text()
        brain.kill()  # dies without a goodbye: only the command timeout can tell
        brain.wait()
        assert probe.spin_until(lambda: body.poll() is not None, 60)
        probe.spin_until(lambda: len(received) >= 201, 5)
    finally:
        stop(body)
        stop(brain)
        probe.close()
    log = (tmp_path / "body.log").read_text()
    assert body.returncode == 0, log
    assert "brain silent: no rest_length command for step" in log and "safe command" in log
    steps = [stamp_ns(m.header.stamp) // DT_NS for m in received]
    assert steps == list(range(201)), "the body must publish every step, before and after the brain died"
    rest = np.array([np.asarray(m.position) for m in received])
    agent = fresh_agent("lissajous")
    base = agent.body.l.numpy()
    safe = np.flatnonzero((rest == base).all(axis=1))
    assert safe.size and safe[0] > 40 and (safe == np.arange(safe[0], 201)).all()
    with torch.no_grad():
        swg = swg_rest_lengths(agent.body, agent.brain, 0, int(safe[0])).numpy()
    np.testing.assert_allclose(rest[: safe[0]], swg, rtol=0, atol=1e-12)
    assert json.loads(summary.read_text())["safe_command_steps"] == 201 - safe[0]
