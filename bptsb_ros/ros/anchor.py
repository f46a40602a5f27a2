"""The anchor of ``bptsb bench --live``: a bare rclpy ping-pong, measured in the same run as the loops.

What the middleware alone gives where the bench runs, at that time: ``ping`` publishes a 50-float
``std_msgs/Float64MultiArray``, ``pong`` answers every ping with one, and ``ping`` sends the next ping when the pong is
in — one round trip, as a lockstep step is one (``/clock`` out, the command back). A ``recorder`` process takes both
topics in rounds of 20 ms, as a bag recorder does. Each side publishes pre-serialized bytes (no message objects) and
handles its messages raw on rclpy's EventsExecutor; every topic has the loops' QoS
(:func:`bptsb_ros.ros.messages.state_qos`: reliable, volatile, keep-last 1000). Nothing else: no stamps checked, no bag
written.

Two shapes: ``split`` (ping, pong and the recorder in three processes, as a loop's body, brain and recorder) and
``composed`` (ping and pong as two nodes in one process on one executor, the recorder in its own; the anchor of a
composed loop, ``composed:=true``). :func:`run_anchor` starts them and returns the round trips per second
over ``seconds`` of wall time after a warm-up.

Run one side alone: ``python -m bptsb_ros.ros.anchor ping|pong|both|recorder --seconds S`` (the ROS_DOMAIN_ID of
the environment). ``ping`` and ``both`` print one JSON line with the result.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

#: values in each message (the size of a loop's command: 48 rest lengths and a few more)
VALUES = 50
#: round trips before the timed window
WARM_UP = 200
#: the recorder's round [s]: it sleeps this long, then takes everything waiting
RECORDER_ROUND_S = 0.02
#: topics of the anchor (relative: a namespace keeps two anchors apart)
PING, PONG = "bptsb_anchor/ping", "bptsb_anchor/pong"
SHAPES = ("split", "composed")


def _payload() -> bytes:
    """The serialized 50-float message every side publishes (made once)."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray

    return bytes(serialize_message(Float64MultiArray(data=[float(i) for i in range(VALUES)])))


def _qos() -> Any:
    from bptsb_ros.interface.topics import DEFAULT_QOS_DEPTH
    from bptsb_ros.ros.messages import state_qos

    return state_qos(DEFAULT_QOS_DEPTH)


class _Ping:
    """Sends a ping whenever the pong of the previous one is in; counts round trips and their times."""

    def __init__(self, node: Any, payload: bytes) -> None:
        from std_msgs.msg import Float64MultiArray

        self.node, self.payload = node, payload
        self.pub = node.create_publisher(Float64MultiArray, PING, _qos())
        node.create_subscription(Float64MultiArray, PONG, self._on_pong, _qos(), raw=True)
        self.trips, self.began, self.ended, self.cpu_began, self.cpu_ended = 0, 0.0, 0.0, 0.0, 0.0
        self.sent = 0.0
        self.rtts: list[float] = []

    def _on_pong(self, _data: bytes) -> None:
        now = time.monotonic()
        self.trips += 1
        if self.trips == WARM_UP:
            self.began, self.cpu_began = now, time.process_time()
        elif self.trips > WARM_UP:
            self.rtts.append(now - self.sent)
        self.ended, self.cpu_ended = now, time.process_time()
        self.send()

    def send(self) -> None:
        self.sent = time.monotonic()
        self.pub.publish(self.payload)

    def result(self) -> dict[str, Any]:
        trips = max(self.trips - WARM_UP, 0)
        wall = self.ended - self.began
        rtts = sorted(self.rtts)
        return {"round_trips": trips, "wall_s": round(wall, 4),
                "round_trips_per_s": trips / wall if trips and wall > 0 else 0.0,
                "rtt_p50_ms": 1e3 * rtts[len(rtts) // 2] if rtts else None,
                "ping_cpu_us_per_round_trip": 1e6 * (self.cpu_ended - self.cpu_began) / trips if trips else None}


def _pong(node: Any, payload: bytes) -> None:
    from std_msgs.msg import Float64MultiArray

    pub = node.create_publisher(Float64MultiArray, PONG, _qos())
    node.create_subscription(Float64MultiArray, PING, lambda _data: pub.publish(payload), _qos(), raw=True)


def _wait_matched(node: Any, topic: str, count: int, executor: Any, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while node.count_subscribers(topic) < count:
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def serve(role: str, seconds: float, subscribers: int = 2) -> int:
    """Run one side (``ping``, ``pong``, ``both``: ping and pong in this process, or ``recorder``) until done
    (``ping``, ``both``: ``seconds`` after the warm-up, then one JSON line) or SIGINT/SIGTERM (``pong``,
    ``recorder``). ``subscribers``: how many subscribers ``ping`` waits for on each topic before it starts."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    stop: list[int] = []
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stop.append(signum))
    executor = EventsExecutor()
    payload = _payload()
    nodes = []
    try:
        if role == "recorder":
            return _record(executor, stop)
        node = rclpy.create_node(f"anchor_{role}")
        nodes.append(node)
        executor.add_node(node)
        if role in ("pong", "both"):
            peer = node
            if role == "both":  # a second node in the same process, on the same executor
                peer = rclpy.create_node("anchor_pong")
                nodes.append(peer)
                executor.add_node(peer)
            _pong(peer, payload)
        if role == "pong":
            while not stop:
                executor.spin_once(timeout_sec=0.1)
            return 0
        ping = _Ping(node, payload)
        if not (_wait_matched(node, PING, subscribers, executor) and _wait_matched(node, PONG, subscribers, executor)):
            print(json.dumps({"error": f"the anchor's subscribers did not match within 60 s ({role})"}), flush=True)
            return 1
        time.sleep(0.5)  # both directions matched on the far side too
        ping.send()
        deadline = None
        while not stop:
            executor.spin_once(timeout_sec=0.1)
            if deadline is None and ping.trips >= WARM_UP:
                deadline = time.monotonic() + seconds
            if deadline is not None and time.monotonic() >= deadline:
                break
        result = ping.result()
        result["process_cpu_us_per_round_trip"] = result.pop("ping_cpu_us_per_round_trip")
        print(json.dumps(result), flush=True)
        return 0
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()


def _record(executor: Any, stop: list[int]) -> int:
    """The recorder: raw subscriptions on both topics; every :data:`RECORDER_ROUND_S` it takes what is waiting."""
    import rclpy
    from std_msgs.msg import Float64MultiArray

    node = rclpy.create_node("anchor_recorder")
    executor.add_node(node)
    taken = [0]

    def take(_data: bytes) -> None:
        taken[0] += 1

    for topic in (PING, PONG):
        node.create_subscription(Float64MultiArray, topic, take, _qos(), raw=True)
    try:
        while not stop:
            time.sleep(RECORDER_ROUND_S)
            before = -1
            while taken[0] != before:
                before = taken[0]
                executor.spin_once(timeout_sec=0.0)
        return 0
    finally:
        node.destroy_node()


def run_anchor(shape: str = "split", seconds: float = 5.0, env: dict[str, str] | None = None,
               timeout: float = 120.0) -> dict[str, Any]:
    """Start the anchor in ``shape`` (``split`` or ``composed``, see the module docstring) and return its result:
    ``round_trips_per_s`` over ``seconds`` after the warm-up, ``rtt_p50_ms``, the ping process's CPU per round trip,
    and the shape (or ``error``)."""
    if shape not in SHAPES:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    base = [sys.executable, "-m", "bptsb_ros.ros.anchor"]
    env = dict(os.environ if env is None else env)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    others = [["recorder"]] + ([["pong"]] if shape == "split" else [])
    procs = [subprocess.Popen(base + role + ["--seconds", f"{seconds:g}"], env=env, stdin=subprocess.DEVNULL,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for role in others]
    try:
        main = subprocess.run(base + ["ping" if shape == "split" else "both", "--seconds", f"{seconds:g}"], env=env,
                              stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"shape": shape, "error": f"the anchor did not finish within {timeout:g} s"}
    finally:
        _stop_all(procs)
    lines = [line for line in main.stdout.splitlines() if line.startswith("{")]
    if main.returncode or not lines:
        tail = (main.stderr or main.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"shape": shape, "error": f"the anchor exited {main.returncode}: {tail[0][:200]}"}
    return {"shape": shape, **json.loads(lines[-1])}


def _stop_all(procs: list[subprocess.Popen], grace: float = 10.0) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in procs:
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def main(argv: list[str] | None = None, out: Callable[[str], None] = print) -> int:
    parser = argparse.ArgumentParser(prog="python -m bptsb_ros.ros.anchor", description=__doc__.splitlines()[0])
    parser.add_argument("role", choices=("ping", "pong", "both", "recorder"))
    parser.add_argument("--seconds", type=float, default=5.0, help="timed wall seconds after the warm-up")
    args = parser.parse_args(argv)
    if not args.seconds > 0:
        out("live_anchor: --seconds must be > 0")
        return 2
    return serve(args.role, args.seconds, subscribers=2)


if __name__ == "__main__":
    sys.exit(main())
