"""The simulator services of a running ``body_sim`` through rclpy (one short lockstep run): ``~/step`` while
paused advances exactly ``step_count`` steps and holds, ``~/reset`` and ``~/resume`` answer, and each call is on
``/diagnostics`` (what a bag records) with its callers. The services follow the command-source rule
(``control_callers``): a call is refused while a node not allowed has a client, and a bag and replay say so. A paused
``bptsb launch`` says so and ends after ``pause_timeout``. The semantics in detail are tested without DDS in
``test_sim_control``. And a real brain node that fell behind answers only the newest tick (the latch alone:
``test_newest``)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time

import pytest
from ros_live import REPO, Probe, env_for, start_node, stop

#: the node name ``ros2 service call`` uses for a Trigger call: the default control_callers
CLI_CALLER = "_ros2cli_requester_std_srvs_Trigger"


def _call(probe: Probe, name: str, service: str = "/body_sim", keep: bool = False):
    from std_srvs.srv import Trigger

    client = probe.node.create_client(Trigger, f"{service}/{name}")
    assert client.wait_for_service(timeout_sec=30), f"no {service}/{name} service"
    future = client.call_async(Trigger.Request())
    assert probe.spin_until(future.done, 30)
    if not keep:
        probe.node.destroy_client(client)
    return future.result()


def _control_statuses(probe: Probe) -> list[dict[str, str]]:
    return [dict((v.key, v.value) for v in s.values) for d in probe.messages["/diagnostics"]
            for s in d.status if s.name == "body_sim: control"]


@pytest.mark.slow
def test_step_reset_resume_services_on_a_running_body(tmp_path, ros_env, ros_domain_id):
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock

    from bptsb_ros.ros import messages as m

    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {"task": "lissajous", "mode": "lockstep", "start_paused": True, "step_count": 3,
                                   "max_steps": 30, "startup_timeout": 1.0, "final_ack_timeout": 0.0,
                                   "summary_path": str(summary), "control_callers": ["test_probe"]},
                      ros_env, tmp_path / "body.log")
    probe = Probe(ros_domain_id)
    try:
        probe.subscribe(Clock, "/clock", m.state_qos(1000))
        probe.subscribe(DiagnosticArray, "/diagnostics", m.state_qos(1000))
        clocks = probe.messages["/clock"]
        assert probe.spin_until(lambda: probe.node.count_publishers("/clock") >= 1, 30)
        step = _call(probe, "step")
        assert step.success, step.message
        assert probe.spin_until(lambda: len(clocks) >= 3, 30)
        probe.spin_until(lambda: len(clocks) > 3, 0.5)  # held: no fourth step
        assert [c.clock.nanosec for c in clocks] == [0, 10_000_000, 20_000_000]
        reset, resume = _call(probe, "reset"), _call(probe, "resume")
        assert reset.success and resume.success and resume.message == "resumed after step 2"
        assert body.wait(timeout=60) == 0, (tmp_path / "body.log").read_text()[-2000:]
        # what is still on its way (busy cores), then a little more: an extra message would show
        probe.spin_until(lambda: len(clocks) >= 31 and len(_control_statuses(probe)) >= 3, 10)
        probe.spin_until(lambda: False, 0.3)
        control = _control_statuses(probe)
        assert [(c["call"], c["step"]) for c in control] == [("step", "-1"), ("reset", "2"), ("resume", "2")]
        assert {c["callers"] for c in control} == {"/test_probe"} and {c["untrusted_callers"] for c in control} == {""}
        assert len(clocks) == 31
    finally:
        probe.close()
        stop(body)
    s = json.loads(summary.read_text())
    assert s["steps"] == 30 and s["control_calls"] == 3 and s["paused"] is False


@pytest.mark.slow
def test_a_call_is_refused_while_a_foreign_node_has_a_client_and_the_record_names_it(tmp_path, ros_env,
                                                                                   ros_domain_id):
    """The reset rule of the body's topics holds for its services: a node in another namespace calling ``~/reset``
    (and ``~/pause``) is refused, the state is not reset, and ``/diagnostics`` names it; the allowed caller's calls
    go through before and after."""
    from diagnostic_msgs.msg import DiagnosticArray

    from bptsb_ros.ros import messages as m

    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {"task": "lissajous", "mode": "lockstep", "start_paused": True, "max_steps": 5,
                                   "startup_timeout": 1.0, "final_ack_timeout": 0.0, "summary_path": str(summary),
                                   "pause_timeout": 0.0}, ros_env, tmp_path / "body.log")
    probe = Probe(ros_domain_id, CLI_CALLER)
    intruder = Probe(ros_domain_id, "intruder", namespace="/evil")
    try:
        probe.subscribe(DiagnosticArray, "/diagnostics", m.state_qos(1000))
        assert _call(probe, "pause").success  # the default control_callers: the ros2 command line's node
        for name in ("reset", "pause"):
            answer = _call(intruder, name, keep=True)
            assert not answer.success and answer.message.startswith(
                f"refused: ~/{name} has client(s) not in control_callers (/evil/intruder)")
        refused = _call(probe, "pause")  # while the intruder has a client of ~/pause: refused for anyone
        assert not refused.success and "/evil/intruder" in refused.message
        assert _call(probe, "step").success  # ~/step has no foreign client
        intruder.close()
        intruder = None
        deadline = time.monotonic() + 20
        while True:  # once the graph has forgotten the intruder's clients, the allowed caller gets through
            answer = _call(probe, "resume")
            if answer.success or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert answer.success, answer.message
        assert body.wait(timeout=60) == 0, (tmp_path / "body.log").read_text()[-2000:]
        probe.spin_until(lambda: any(c["call"] == "resume" and c["accepted"] == "True"
                                     for c in _control_statuses(probe)), 10)  # still on its way, on busy cores
        probe.spin_until(lambda: False, 0.3)
        control = _control_statuses(probe)
        foreign = [c for c in control if c["untrusted_callers"]]
        assert [c["call"] for c in foreign][:3] == ["reset", "pause", "pause"]
        assert all(c["accepted"] == "False" and "/evil/intruder" in c["callers"] for c in foreign)
        assert control[-1]["call"] == "resume" and control[-1]["accepted"] == "True"
        assert control[-1]["callers"] == f"/{CLI_CALLER}"
    finally:
        if intruder is not None:
            intruder.close()
        probe.close()
        stop(body)
    s = json.loads(summary.read_text())
    assert s["steps"] == 5 and s["control_calls_refused"] >= 3


@pytest.mark.slow
def test_a_paused_launch_says_so_and_ends_after_pause_timeout(tmp_path, ros_env, ros_domain_id):
    """``bptsb launch`` without --timeout, paused by a call: the body says it is paused, then ends the run after
    ``pause_timeout`` (exit 1, named); the bag records the call with its caller, and replay lists it."""
    from bptsb_ros.analysis.control_calls import control_calls

    bag = tmp_path / "bag"
    launch = subprocess.Popen([sys.executable, "-m", "bptsb_ros.cli", "launch", "lissajous_open", "--duration", "60",
                               "--bag", str(bag), "--param", "body_sim:pause_timeout:=8",  # notices at 1 s, 2 s, ...
                               "--param", "body_sim:pause_notice_period:=1"], env=env_for(ros_env), cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    from rosgraph_msgs.msg import Clock

    from bptsb_ros.ros import messages as m

    probe = Probe(ros_domain_id, CLI_CALLER)
    try:
        # called once the loop runs (the recorder is up then: a call before it would not be in the bag)
        probe.subscribe(Clock, "/clock", m.state_qos(1000))
        assert probe.spin_until(lambda: len(probe.messages["/clock"]) > 0, 60)
        assert _call(probe, "pause").success
        out, _ = launch.communicate(timeout=120)
    finally:
        probe.close()
        if launch.poll() is None:
            launch.kill()
            launch.communicate()
    assert launch.returncode == 1, out[-3000:]
    assert "no step is taken until ~/resume or ~/step is called; the run ends if it stays paused for 8 s" in out
    assert re.search(r"still paused after step \d+, for \d+ s", out), out[-3000:]  # the notice repeats
    assert "for 8 s without ~/resume or ~/step (pause_timeout): ending the run" in out
    summary = json.loads((tmp_path / "bag.launch" / "body_summary.json").read_text())
    assert summary["pause_expired"] is True and summary["steps"] < 6000  # the 60 s run did not finish
    calls = control_calls(bag)
    assert [(c["call"], c["accepted"], c["callers"], c["foreign"]) for c in calls] == [
        ("pause", True, [f"/{CLI_CALLER}"], False)]


def test_replay_flags_calls_from_foreign_callers_and_forged_statuses():
    """Planted statuses (what a bag of a run with a refused foreign call, or a forged /diagnostics, holds)."""
    from bptsb_ros.analysis import control_calls as cc

    calls = [{"call": "reset", "step": 4, "accepted": False, "callers": ["/evil/x"], "untrusted_callers": ["/evil/x"],
              "publisher": "/body_sim", "foreign": True},
             {"call": "pause", "step": 9, "accepted": True, "callers": ["/a"], "untrusted_callers": [],
              "publisher": "/body_sim", "foreign": False}]
    assert cc.summary(calls)["foreign"] == 1 and cc.summary(calls)["count"] == 2
    lines = cc.warnings(calls, "b")
    assert lines == ["replay: b: a ~/reset call after step 4 came from outside the loop (/evil/x); the body refused "
                     "it"]


@pytest.mark.slow
def test_a_real_brain_behind_by_176_ticks_answers_only_the_newest(ros_domain_id):
    """``swg_brain`` in this process (own context): 177 ``/clock`` ticks delivered before it spins; its loop
    answers tick 276 only (the SWG value of step 276) and counts 176 dropped."""
    import threading

    import rclpy
    import torch
    from rclpy.duration import Duration
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.runtime import StopFlag
    from bptsb_ros.ros.swg_brain import SwgBrain
    from bptsb_ros.sim.rollout import swg_rest_lengths

    rclpy.init(args=["--ros-args", "-p", "task:=lissajous", "-p", "startup_timeout:=10.0"], domain_id=ros_domain_id)
    stop = StopFlag()
    probe = Probe(ros_domain_id, "tick_probe")
    try:
        brain = SwgBrain(stop)
        ticks = probe.node.create_publisher(Clock, "/clock", m.state_qos(1000))
        probe.subscribe(JointState, "/brain/rest_length", m.command_qos(1000))
        assert Probe.wait_matched([ticks, brain.pub], 20)
        for k in range(100, 277):
            ticks.publish(m.clock_msg(k, brain.dt_ns))
        assert ticks.wait_for_all_acked(Duration(seconds=20))  # all 177 are in the brain's subscription
        runner = threading.Thread(target=brain.run)
        runner.start()
        got = probe.messages["/brain/rest_length"]
        assert probe.spin_until(lambda: bool(got), 20)
        probe.spin_until(lambda: False, 0.5)
        stop.set("test")
        runner.join(timeout=20)
        assert [m.step_of(msg.header.stamp, brain.dt_ns) for msg in got] == [276]
        with torch.no_grad():
            want = swg_rest_lengths(brain.agent.body, brain.agent.brain, 276, 1)[0].double().numpy()
        assert list(got[0].position) == list(want)
        assert sum(latch.dropped for latch in brain.latches) == 176
        # use_sim_time without rclpy's own /clock subscription: the node's clock reads the tick it answered
        assert brain.sim_time_fed and brain.get_clock().now().nanoseconds == 276 * brain.dt_ns
        assert [e.node_name for e in brain.get_subscriptions_info_by_topic("/clock")].count("swg_brain") == 1
        brain.destroy_node()
    finally:
        stop.set("test")
        probe.close()
        rclpy.shutdown()
