"""The simulator services of a running ``body_sim`` through rclpy (one short lockstep run): ``~/step`` while
paused advances exactly ``step_count`` steps and holds, ``~/reset`` and ``~/resume`` answer, and each call is on
``/diagnostics`` (what a bag records). The semantics in detail are tested without DDS in ``test_sim_control``.
And a real brain node that fell behind answers only the newest tick (the latch alone: ``test_newest``)."""

from __future__ import annotations

import json

from ros_live import Probe, start_node, stop


def _call(probe: Probe, name: str):
    from std_srvs.srv import Trigger

    client = probe.node.create_client(Trigger, f"/body_sim/{name}")
    assert client.wait_for_service(timeout_sec=30), f"no /body_sim/{name} service"
    future = client.call_async(Trigger.Request())
    assert probe.spin_until(future.done, 30)
    return future.result()


def test_step_reset_resume_services_on_a_running_body(tmp_path, ros_env, ros_domain_id):
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock

    from bptsb_ros.ros import messages as m

    summary = tmp_path / "summary.json"
    body = start_node("body_sim", {"task": "lissajous", "mode": "lockstep", "start_paused": True, "step_count": 3,
                                   "max_steps": 30, "startup_timeout": 1.0, "final_ack_timeout": 0.0,
                                   "summary_path": str(summary)}, ros_env, tmp_path / "body.log")
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
        probe.spin_until(lambda: False, 0.3)
        control = [dict((v.key, v.value) for v in s.values) for d in probe.messages["/diagnostics"]
                   for s in d.status if s.name == "body_sim: control"]
        assert [(c["call"], c["step"]) for c in control] == [("step", "-1"), ("reset", "2"), ("resume", "2")]
        assert len(clocks) == 31
    finally:
        probe.close()
        stop(body)
    s = json.loads(summary.read_text())
    assert s["steps"] == 30 and s["control_calls"] == 3 and s["paused"] is False


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
