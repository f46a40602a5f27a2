"""CPU per lockstep step of the live body's own work, in one process: decoding a command, the step with its checks,
and writing the step's messages, beside what the middleware costs to send them.

    ROS_DOMAIN_ID=N .venv/bin/python scripts/live_step_cost.py [STEPS] [--objects]

Builds ``body_sim`` for the closed Lissajous loop (a fresh float64 Lissajous agent, lockstep, awaiting rest lengths)
and, per step, hands it one rest-length command as the bytes a brain publishes (``--objects``: as a deserialized
message object, the way the node took commands before), then runs ``BodyCore.integrate`` and the node's ``publish``
(its templates; ``body/positions`` every step, the slower topics and markers at their rates), with ``/clock``
announced first. It times each part with ``time.thread_time`` (CPU of this thread) over STEPS steps (default 3000)
after 300 of warm-up, once with the publishers' ``publish`` replaced by a no-op (the body's own work) and once
sending to a subscriber process (the body's work plus the middleware's), and prints p50 and p99 in µs. Run it with
a private ROS_DOMAIN_ID.
"""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np


def _subscriber() -> None:
    """A process that takes every body topic raw (the recorder's part of the middleware's cost)."""
    import rclpy
    from rclpy.experimental import EventsExecutor

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.body_sim import OUTPUTS

    rclpy.init()
    node = rclpy.create_node("cost_subscriber")
    for key, kind in OUTPUTS:
        topic = "/clock" if key == "clock" else f"body/{key}" if key != "diagnostics" else "/diagnostics"
        node.create_subscription(kind, topic, lambda _data: None, m.state_qos(1000), raw=True)
    executor = EventsExecutor()
    executor.add_node(node)
    while True:
        executor.spin_once(timeout_sec=0.1)


def main(steps: int = 3000, objects: bool = False) -> None:
    import rclpy
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.body_sim import BodySim
    from bptsb_ros.ros.runtime import StopFlag

    rclpy.init(args=["--ros-args", "-p", "task:=lissajous", "-p", "dtype:=float64", "-p", "wait_for:=[rest_length]",
                     "-p", "startup_timeout:=1.0"])
    node = BodySim(StopFlag())
    core = node.core
    names, base = core.spring_names, core.base.numpy()
    if objects:  # the bytes rclpy's serializer makes (what the brains sent before)
        def render(k: int, x: np.ndarray) -> bytes:
            return serialize_message(m.joint_state(k, node.dt_ns, names, position=x))
    else:
        from bptsb_ros.ros.raw_out import RawTemplate

        render = RawTemplate(lambda k, x: m.joint_state(k, node.dt_ns, names, position=x), [(len(names),)],
                             deserialize_message, node.dt_ns).render
    rng = np.random.default_rng(0)
    commands = [base * (1 + 0.02 * rng.standard_normal(base.size)) for _ in range(64)]
    core.counting = True

    def run(first: int, n: int, state, times):
        for k in range(first, first + n):
            data = render(k, commands[k % 64])
            c0 = time.thread_time()
            core.announce(k, time.monotonic())
            node.announce(k)
            c1 = time.thread_time()
            node._on_input("rest_length", deserialize_message(data, JointState) if objects else data)
            c2 = time.thread_time()
            out = core.integrate(state, k)
            c3 = time.thread_time()
            node.publish(out)
            c4 = time.thread_time()
            times.append((c2 - c1, c3 - c2, c4 - c3 + c1 - c0))
            state = out.state
        return state

    def measure(label: str, first: int):
        times: list[tuple[float, float, float]] = []
        state = run(first, 300, None if first == 0 else measure.state, [])
        measure.state = run(first + 300, steps, state, times)
        us = np.array(times) * 1e6
        total = us.sum(axis=1)
        parts = "; ".join(f"{name} p50 {np.percentile(us[:, i], 50):.1f}" for i, name in
                          enumerate(("command", "step", "publish")))
        print(f"{label}: total p50 {np.percentile(total, 50):.1f} µs, p99 {np.percentile(total, 99):.1f} µs ({parts})")

    publishers = {key: pub.publish for key, pub in node.pubs.items()}
    for pub in node.pubs.values():
        pub.publish = lambda _msg: None
    measure("the body's own work (publish is a no-op)", 0)
    sub = subprocess.Popen([sys.executable, __file__, "--subscriber"])
    try:
        for key, pub in node.pubs.items():
            pub.publish = publishers[key]
        deadline = time.monotonic() + 30
        while node.pubs["positions"].get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        measure("with the middleware sending to a subscriber process", 300 + steps)
    finally:
        sub.kill()
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    if "--subscriber" in sys.argv:
        _subscriber()
    else:
        args = [a for a in sys.argv[1:] if not a.startswith("--")]
        main(int(args[0]) if args else 3000, "--objects" in sys.argv)
