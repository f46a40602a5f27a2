"""Faults in the live loop, with node processes and a probe node in the test: a brain that dies
mid-run (the body keeps running with the safe command and says so). The command rules (wrong length, NaN/inf,
stale, ...) are tested without DDS in ``test_live_core.py``.

The brain-dies test runs in a quarantine domain of its own: the brain it kills with SIGKILL stays in DDS
discovery (a stale ``/clock`` subscriber) until its lease expires, which would let a later body in the same
domain start before its real subscribers matched."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from ros_live import Probe, fresh_agent, stamp_ns, start_node, stop

pytestmark = pytest.mark.slow  # each test here runs a launched loop of several seconds

DT_NS = 10_000_000


#: steps of the dying-brain run: long enough that the brain is killed mid-run even where a lockstep step takes
#: well under a millisecond (a 200-step run once finished before the kill on an idle machine)
STEPS = 2000


def test_brain_dies_body_keeps_running_with_safe_command(tmp_path, quarantine_ros):
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros.messages import state_qos
    from bptsb_ros.sim.rollout import swg_rest_lengths

    ros_domain_id, ros_env = quarantine_ros
    probe = Probe(ros_domain_id)
    probe.subscribe(JointState, "/body/rest_length", state_qos(2 * STEPS))
    received = probe.messages["/body/rest_length"]
    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {
        "task": "lissajous", "duration": STEPS * DT_NS / 1e9, "wait_for": ["rest_length"], "command_timeout": 2.0,
        "wait_for_subscribers": ["/body/rest_length:1", "/clock:1"], "summary_path": str(summary),
        "every_step": ["rest_length"],  # on request: the body's rest lengths every step (default: every 10th)
    }, ros_env, tmp_path / "body.log")
    brain = start_node("swg_brain", {"task": "lissajous", "use_sim_time": True}, ros_env,
                       tmp_path / "brain.log")
    try:
        assert probe.spin_until(lambda: len(received) > 40, 60), (tmp_path / "body.log").read_text()
        brain.kill()  # dies without a goodbye: only the command timeout can tell
        brain.wait()
        assert probe.spin_until(lambda: body.poll() is not None, 60)
        probe.spin_until(lambda: len(received) >= STEPS + 1, 10)
    finally:
        stop(body)
        stop(brain)
        probe.close()
    log = (tmp_path / "body.log").read_text()
    assert body.returncode == 0, log
    assert "brain silent: no rest_length command for step" in log and "safe command" in log
    steps = [stamp_ns(m.header.stamp) // DT_NS for m in received]
    assert steps == list(range(STEPS + 1)), "the body must publish every step, before and after the brain died"
    rest = np.array([np.asarray(m.position) for m in received])
    agent = fresh_agent("lissajous")
    base = agent.body.l.numpy()
    safe = np.flatnonzero((rest == base).all(axis=1))
    assert safe.size and safe[0] > 40 and (safe == np.arange(safe[0], STEPS + 1)).all()
    with torch.no_grad():
        swg = swg_rest_lengths(agent.body, agent.brain, 0, int(safe[0])).numpy()
    np.testing.assert_allclose(rest[: safe[0]], swg, rtol=0, atol=1e-12)
    assert json.loads(summary.read_text())["safe_command_steps"] == STEPS + 1 - safe[0]
