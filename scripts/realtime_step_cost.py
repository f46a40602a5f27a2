"""The cost of one realtime body step in one process, without DDS peers: integrate, publish, handle messages.

    ROS_DOMAIN_ID=N .venv/bin/python scripts/realtime_step_cost.py [events|single] [STEPS]

Builds ``body_sim`` on the example agent (``bags/lissajous_agent``) in realtime mode with the given executor
(default events), runs 200 warm-up steps, then STEPS (default 3000) steps of ``BodyCore.integrate``, the node's
``publish`` (markers every fifth step) and ``drain`` (``spin_once(0)`` until no message is left), and prints p50
and p99 of each in milliseconds. Run it with a private ROS_DOMAIN_ID; compare versions in interleaved runs.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import rclpy

from bptsb_ros.ros.body_sim import BodySim
from bptsb_ros.ros.runtime import StopFlag


def main(executor: str = "events", steps: int = 3000) -> None:
    rclpy.init(args=["--ros-args", "-p", "agent:=bags/lissajous_agent", "-p", "mode:=realtime",
                     "-p", f"executor:={executor}"])
    node = BodySim(StopFlag())
    times: list[tuple[float, float, float]] = []

    def run(n: int, state):
        for k in range(n):
            t0 = time.perf_counter()
            out = node.core.integrate(state, k)
            t1 = time.perf_counter()
            node.publish(out)
            t2 = time.perf_counter()
            node.drain()
            times.append((t1 - t0, t2 - t1, time.perf_counter() - t2))
            state = out.state
        return state

    state = run(200, None)
    del times[:]
    run(steps, state)
    ms = np.array(times) * 1e3
    print(f"executor {node.executor_name}, {steps} steps: " + "; ".join(
        f"{name} p50 {np.percentile(ms[:, i], 50):.3f} p99 {np.percentile(ms[:, i], 99):.3f} ms"
        for i, name in enumerate(("integrate", "publish", "drain"))))
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "events", int(sys.argv[2]) if len(sys.argv) > 2 else 3000)
