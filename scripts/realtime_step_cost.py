"""The cost of one realtime body step in one process, without DDS peers: integrate, publish, handle messages.

    ROS_DOMAIN_ID=N .venv/bin/python scripts/realtime_step_cost.py [events|single] [STEPS] [--gap MS] [--rehearse]

Builds ``body_sim`` on the example agent (``bags/lissajous_agent``) in realtime mode with the given executor
(default events), runs 200 warm-up steps, then STEPS (default 3000) steps of ``BodyCore.integrate``, the node's
``publish`` (markers every fifth step) and ``drain`` (``spin_once(0)`` until no message is left), and prints p50
and p99 of each in milliseconds. ``--gap MS``: sleep MS milliseconds before each step (as a realtime body does
between steps: its caches go cold while other processes run); ``--rehearse``: then, right before the step, the
node's ``rehearse`` (what a body under ``rt_priority`` does in its ``busy_wait``). The stepping thread runs under
SCHED_FIFO 10 where it may. Run it with a private ROS_DOMAIN_ID; compare versions in interleaved runs.
"""

from __future__ import annotations

import time

import numpy as np
import rclpy

from bptsb_ros.ros.body_sim import BodySim
from bptsb_ros.ros.runtime import StopFlag


def main(executor: str = "events", steps: int = 3000, gap: float = 0.0, rehearse: bool = False) -> None:
    rclpy.init(args=["--ros-args", "-p", "agent:=bags/lissajous_agent", "-p", "mode:=realtime",
                     "-p", f"executor:={executor}"])
    node = BodySim(StopFlag())
    times: list[tuple[float, float, float]] = []

    from bptsb_ros.live.scheduling import set_fifo_priority

    set_fifo_priority(10)

    def run(n: int, state):
        for k in range(n):
            if gap:
                time.sleep(gap)
            if rehearse:
                node.rehearse(state)
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
    print(f"executor {node.executor_name}, {steps} steps, gap {gap * 1e3:g} ms{', rehearsed' if rehearse else ''}: "
          + "; ".join(
        f"{name} p50 {np.percentile(ms[:, i], 50):.3f} p99 {np.percentile(ms[:, i], 99):.3f} ms"
        for i, name in enumerate(("integrate", "publish", "drain"))))
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("executor", nargs="?", default="events", choices=("events", "single"))
    parser.add_argument("steps", nargs="?", type=int, default=3000)
    parser.add_argument("--gap", type=float, default=0.0, metavar="MS")
    parser.add_argument("--rehearse", action="store_true")
    a = parser.parse_args()
    main(a.executor, a.steps, a.gap / 1e3, a.rehearse)
