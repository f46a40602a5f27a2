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

A third shape, ``paced``, is the anchor of ``bptsb bench --realtime``: ``tick`` publishes a ping at each due time
start + k·period on the body's realtime schedule (it sleeps, and under ``rt_priority`` polls the last ``busy`` seconds
before each due time, as ``body_sim`` does with ``busy_wait``), ``pong`` answers each, and nothing else runs: no
physics, no recorder. ``tick`` keeps each tick's due, start and end times and judges them with the body's rule
(:func:`bptsb_ros.live.step_times.timing_statistics`: a miss is a tick that ended after the next one was due), so its
misses are what the machine's scheduler gives a bare rclpy loop at that rate and priority (:func:`run_paced_anchor`).

Run one side alone: ``python -m bptsb_ros.ros.anchor ping|pong|both|recorder|tick --seconds S`` (the ROS_DOMAIN_ID
of the environment). ``ping``, ``both`` and ``tick`` print one JSON line with the result.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

from bptsb_ros.interface.params import ParameterError
from bptsb_ros.live.scheduling import parse_cpus

#: values in each message (the size of a loop's command: 48 rest lengths and a few more)
VALUES = 50
#: round trips before the timed window
WARM_UP = 200
#: the recorder's round [s]: it sleeps this long, then takes everything waiting
RECORDER_ROUND_S = 0.02
#: topics of the anchor (relative: a namespace keeps two anchors apart)
PING, PONG = "bptsb_anchor/ping", "bptsb_anchor/pong"
SHAPES = ("split", "composed")
#: most ticks of one paced run (its records: 24 bytes a tick)
MAX_TICKS = 10_000_000


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


class _Tick:
    """Publishes a ping at each due time start + k·``period`` (start: one period after :meth:`run` is called) and
    handles the pongs in between, counting them (:func:`serve`, role ``tick``): sleeps until ``busy`` seconds (at most
    half a period) before the due time, then polls the executor until it; keeps each tick's due, start and end times
    (monotonic seconds)."""

    def __init__(self, node: Any, payload: bytes, period: float, busy: float, ticks: int) -> None:
        import numpy as np
        from std_msgs.msg import Float64MultiArray

        self.payload, self.period, self.busy = payload, period, min(busy, period / 2)
        self.pub = node.create_publisher(Float64MultiArray, PING, _qos())
        node.create_subscription(Float64MultiArray, PONG, self._on_pong, _qos(), raw=True)
        self.times = np.zeros((3, ticks))  # due, began, done
        self.pongs = 0

    def _on_pong(self, _data: bytes) -> None:
        self.pongs += 1

    def run(self, executor: Any, stop: list[int]) -> int:
        """Tick until every tick is done or a stop signal; returns the number of ticks done."""
        start = time.monotonic() + self.period
        for k in range(self.times.shape[1]):
            due = start + k * self.period
            while not stop and (left := due - self.busy - time.monotonic()) > 0:
                executor.spin_once(timeout_sec=min(left, 0.05))
            while not stop and time.monotonic() < due:
                executor.spin_once(timeout_sec=0.0)
            if stop:
                return k
            began = time.monotonic()
            self.pub.publish(self.payload)
            self.times[:, k] = due, began, time.monotonic()
        return self.times.shape[1]

    def result(self, done: int) -> dict[str, Any]:
        from bptsb_ros.live.step_times import timing_statistics

        due, began, ended = self.times[:, :done]
        stats = timing_statistics(due, began, began, ended, self.period) if done else {"steps": 0}
        return {"ticks": done, "pongs": self.pongs, "period_ms": self.period * 1e3, **stats}


def _realtime(priority: int, cpus: str) -> tuple[int, str]:
    """Pin this process to ``cpus`` (taskset -c form; '' leaves it) and put its main thread under SCHED_FIFO at
    ``priority`` and its other threads one below (0 leaves them), as ``body_sim`` does; returns the priority got
    (0 where refused: the normal scheduler, as the body goes on) and what was refused ('' when nothing)."""
    from bptsb_ros.live.scheduling import pin_threads, set_fifo_priority_of_process

    problems = [pin_threads(parse_cpus(cpus, "--cpus"))] if cpus else []
    refused = set_fifo_priority_of_process(priority)[0] if priority else ""
    problems.append(refused)
    return (0 if refused else priority), "; ".join(p for p in problems if p)


def _wait_matched(node: Any, topic: str, count: int, executor: Any, timeout: float = 60.0, *,
                  publishers: bool = False) -> bool:
    """Spin until ``topic`` has ``count`` subscribers (``publishers``: publishers) or ``timeout`` passed."""
    deadline = time.monotonic() + timeout
    counter = node.count_publishers if publishers else node.count_subscribers
    while counter(topic) < count:
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=0.05)
    return True


def serve(role: str, seconds: float, subscribers: int = 2, *, period: float = 0.01, busy: float = 0.0,
          priority: int = 0, cpus: str = "") -> int:
    """Run one side (``ping``, ``pong``, ``both``: ping and pong in this process, ``recorder``, or ``tick``) until
    done (``ping``, ``both``: ``seconds`` after the warm-up, ``tick``: ``seconds`` of ticks every ``period``; then
    one JSON line) or SIGINT/SIGTERM (``pong``, ``recorder``). ``subscribers``: how many subscribers ``ping`` waits
    for on each topic before it starts (``tick`` waits for the pong's subscription and publisher). ``priority``,
    ``cpus`` (``tick``, ``pong``): SCHED_FIFO priority and CPUs (:func:`_realtime`; a refusal is reported and the
    node goes on under the normal scheduler, as ``body_sim`` does), ``busy``: ``tick``'s polling before each due time
    (under a priority only)."""
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
            _, problem = _realtime(priority, cpus)
            if problem:
                print(json.dumps({"warning": problem}), flush=True)
            while not stop:
                executor.spin_once(timeout_sec=0.1)
            return 0
        if role == "tick":
            tick = _Tick(node, payload, period, busy, max(1, round(seconds / period)))
            if not (_wait_matched(node, PING, 1, executor)
                    and _wait_matched(node, PONG, 1, executor, publishers=True)):
                print(json.dumps({"error": "the paced anchor's pong did not match within 60 s"}), flush=True)
                return 1
            time.sleep(0.5)  # the pong's side has matched too
            got, problem = _realtime(priority, cpus)  # as the body: once its peers are there, before stepping
            if not got:
                tick.busy = 0.0  # polling only under a priority, as the body's busy_wait
            result = tick.result(tick.run(executor, stop))
            result.update(rt_priority=got, **({"scheduling_problem": problem} if problem else {}))
            print(json.dumps(result), flush=True)
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


def run_paced_anchor(seconds: float, period: float, *, priority: int = 0, busy: float = 0.002, cpus: str = "",
                     env: dict[str, str] | None = None, timeout: float | None = None) -> dict[str, Any]:
    """Start the ``paced`` anchor (module docstring): ``tick`` every ``period`` for ``seconds`` under SCHED_FIFO
    ``priority`` (0: the normal scheduler) polling the last ``busy`` seconds before each tick (at most half a
    period), ``pong`` at ``priority`` − 1, both on ``cpus`` ('': anywhere); returns the tick's
    :func:`~bptsb_ros.live.step_times.timing_statistics` (``deadline_misses``, ``lateness_*_ms``, ...), ``ticks``,
    ``pongs`` (answers the tick took), the ``rt_priority`` it got and, where refused, ``scheduling_problem`` (the
    tick's) and ``pong_problem``; or ``error`` (also when the pong answered no tick)."""
    import tempfile

    base = [sys.executable, "-m", "bptsb_ros.ros.anchor"]
    env = dict(os.environ if env is None else env)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    common = ["--seconds", f"{seconds!r}", "--period", f"{period!r}", "--cpus", cpus]
    limit = timeout if timeout is not None else seconds + 120.0
    with tempfile.TemporaryFile("w+") as pong_out:
        pong = subprocess.Popen(base + ["pong", *common, "--rt-priority", str(max(1, priority - 1) if priority else 0)],
                                env=env, stdin=subprocess.DEVNULL, stdout=pong_out, stderr=subprocess.STDOUT, text=True)
        try:
            tick = subprocess.run(base + ["tick", *common, "--rt-priority", str(priority), "--busy", f"{busy!r}"],
                                  env=env, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=limit)
        except subprocess.TimeoutExpired:
            return {"error": f"the paced anchor did not finish within {limit:g} s"}
        finally:
            _stop_all([pong])
        pong_out.seek(0)
        said = pong_out.read().strip().splitlines()
    if pong.returncode not in (0, -signal.SIGINT):
        return {"error": f"the paced anchor's pong exited {pong.returncode}: {(said or ['no output'])[-1][:200]}"}
    lines = [json.loads(line) for line in tick.stdout.splitlines() if line.startswith("{")]
    if lines and "error" in lines[-1]:
        return {"error": f"the paced anchor: {lines[-1]['error']}"}
    if tick.returncode or not lines:
        tail = (tick.stderr or tick.stdout).strip().splitlines()[-1:] or ["no output"]
        return {"error": f"the paced anchor exited {tick.returncode}: {tail[0][:200]}"}
    result = lines[-1]
    warnings = [json.loads(line)["warning"] for line in said if line.startswith('{"warning"')]
    if warnings:
        result["pong_problem"] = warnings[-1]
    if result["ticks"] and not result["pongs"]:
        result["error"] = f"the paced anchor's pong answered none of its {result['ticks']} ticks"
    return result


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
    parser.add_argument("role", choices=("ping", "pong", "both", "recorder", "tick"))
    parser.add_argument("--seconds", type=float, default=5.0, help="timed wall seconds after the warm-up")
    parser.add_argument("--period", type=float, default=0.01, help="tick: seconds between ticks")
    parser.add_argument("--busy", type=float, default=0.0, help="tick, under --rt-priority: seconds polled before each")
    parser.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO priority (1-99; 0: normal scheduler)")
    parser.add_argument("--cpus", default="", help="the CPUs to run on (taskset -c form; empty: anywhere)")
    args = parser.parse_args(argv)
    for name, value, ok in (("--seconds", args.seconds, 0 < args.seconds < math.inf),
                            ("--period", args.period, 0 < args.period < math.inf),
                            ("--busy", args.busy, 0 <= args.busy < math.inf),
                            ("--rt-priority", args.rt_priority, 0 <= args.rt_priority <= 99)):
        if not ok:
            out(f"live_anchor: {name} {value:g} is out of range")
            return 2
    if args.role == "tick" and args.seconds / args.period > MAX_TICKS:
        out(f"live_anchor: --seconds / --period is {args.seconds / args.period:.3g} ticks, more than {MAX_TICKS:,}")
        return 2
    try:
        parse_cpus(args.cpus, "--cpus")
    except ParameterError as err:
        out(f"live_anchor: {err}")
        return 2
    return serve(args.role, args.seconds, subscribers=2, period=args.period, busy=args.busy,
                 priority=args.rt_priority, cpus=args.cpus)


if __name__ == "__main__":
    sys.exit(main())
