"""A recorder on sim time: log times from ``/clock``, and, where it records ``/clock`` itself, no second reader of it.

The recorder runs as a process beside a test publisher of ``/clock`` ticks and stamped ``PoseArray`` messages, on
localhost-only DDS in the test session's private domain (``ros_env`` fixture of conftest.py).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

from bptsb_ros.bags.reader import read_messages

#: sim time step of the test ticks [ns]
DT_NS = 10_000_000

# Waits for a line on stdin (the recorder has subscribed), then (with a third argument 1: a tick at -0.5 s first) for
# k = 1..N publishes the /clock tick k·DT (on NS/clock: the recorder's /clock is remapped there), then a
# PoseArray stamped k·DT on NS/a_poses, in one burst (one participant: the recorder's process receives them in this
# order). Once all are acknowledged, asks the recorder to turn use_sim_time off, then prints one JSON line with the
# number of /clock readers it sees and whether the recorder took the change; idles.
TICKS = r"""
import json, sys, time
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, QoSHistoryPolicy, QoSReliabilityPolicy
from geometry_msgs.msg import PoseArray
from rosgraph_msgs.msg import Clock
n, dt, before_zero, ns = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4]
rclpy.init()
node = rclpy.create_node("tick_publisher")
qos = QoSProfile(history=QoSHistoryPolicy.KEEP_ALL, depth=1, reliability=QoSReliabilityPolicy.RELIABLE)
clock = node.create_publisher(Clock, f"/{ns}/clock", qos)
poses = node.create_publisher(PoseArray, f"/{ns}/a_poses", qos)
print("ready", flush=True)
sys.stdin.readline()
time.sleep(1.0)  # the recorder's graph changes reach this node
if before_zero:  # a tick at -0.5 s first
    bad = Clock()
    bad.clock.sec, bad.clock.nanosec = -1, 500_000_000
    clock.publish(bad)
for k in range(1, n + 1):
    tick = Clock()
    tick.clock.sec, tick.clock.nanosec = divmod(k * dt, 1_000_000_000)
    clock.publish(tick)
    msg = PoseArray()
    msg.header.stamp = tick.clock
    poses.publish(msg)
ok = clock.wait_for_all_acked(Duration(seconds=20)) and poses.wait_for_all_acked(Duration(seconds=20))
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
client = AsyncParameterClient(node, f"recorder_{ns}")
client.wait_for_services(20.0)
future = client.set_parameters([Parameter("use_sim_time", Parameter.Type.BOOL, False)])
rclpy.spin_until_future_complete(node, future, timeout_sec=20.0)
change = future.result().results[0].successful if future.done() else None
print(json.dumps({"acked": ok, "clock_readers": clock.get_subscription_count(), "sim_time_off": change}), flush=True)
time.sleep(60)
"""


@pytest.fixture
def env(ros_env: dict[str, str]) -> dict[str, str]:
    env = dict(ros_env)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _record_ticks(bag: Path, topics: str, n: int, env: dict[str, str], *extra: str,
                  before_zero: bool = False) -> tuple[dict, str]:
    """Record ``topics`` on sim time while the tick publisher runs (``extra``: more recorder arguments;
    ``before_zero``: a tick at -0.5 s first); the publisher's JSON line and the recorder's log."""
    ns = f"ticks_{os.getpid()}_{bag.name}"  # topics and a recorder name of this test alone: other tests' nodes
    # in the domain (a killed one stays visible for a while) neither read its /clock nor answer its parameter call
    publisher = subprocess.Popen([sys.executable, "-c", TICKS, str(n), str(DT_NS), str(int(before_zero)), ns], env=env,
                                 text=True,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    recorder = None
    try:
        assert publisher.stdout.readline().strip() == "ready"
        recorder = subprocess.Popen(
            [sys.executable, "-m", "bptsb_ros.ros.recorder", "--ros-args", "-p", f"bag_path:={bag}",
             "-p", f"topics:={topics.format(ns=ns)}", "-p", "use_sim_time:=true", "-r", f"/clock:=/{ns}/clock",
             "-r", f"__node:=recorder_{ns}", *extra],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        log = []
        for line in recorder.stdout:
            log.append(line)
            if "requested topics subscribed" in line:
                break
        publisher.stdin.write("go\n")
        publisher.stdin.flush()
        result = json.loads(publisher.stdout.readline())
        recorder.send_signal(signal.SIGINT)
        out, _ = recorder.communicate(timeout=30)
        assert recorder.returncode == 0, "".join(log) + out
        return result, "".join(log) + out
    finally:
        for proc in (publisher, recorder):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()


def _topic(bag: Path, name: str) -> str:
    """The test's topic ``name`` (``clock`` or ``a_poses``) as recorded in ``bag``."""
    return f"/ticks_{os.getpid()}_{bag.name}/{name}"


def test_a_recorder_that_records_the_clock_follows_its_own_ticks(tmp_path: Path, env: dict[str, str]) -> None:
    """Recording ``/clock``: the recorder is its only reader (rclpy's own sim-time subscription is gone), each tick
    is logged at its own time, and each pose, which arrives after its tick, is logged at a tick no earlier than its
    stamp and no later than the last. The burst and rounds 0.1 s apart let ticks and poses pile up, so that a round
    can begin with the poses (``a_poses``, subscribed first: the graph lists topics alphabetically)."""
    n = 150
    bag = tmp_path / "ticks"
    result, log = _record_ticks(bag, "[/{ns}/clock, /{ns}/a_poses]", n, env, "-p", "batch_wait:=0.1")
    assert result == {"acked": True, "clock_readers": 1, "sim_time_off": False}, log
    ticks = [(m.timestamp_ns, m.message.clock) for m in read_messages(bag, [_topic(bag, "clock")])]
    assert [t for t, _ in ticks] == [k * DT_NS for k in range(1, n + 1)]
    assert all(t == c.sec * 1_000_000_000 + c.nanosec for t, c in ticks)
    poses = [(m.timestamp_ns, m.message.header.stamp) for m in read_messages(bag, [_topic(bag, "a_poses")])]
    assert len(poses) == n
    for logged, stamp in poses:
        assert logged % DT_NS == 0 and stamp.sec * 1_000_000_000 + stamp.nanosec <= logged <= n * DT_NS


def test_a_recorder_that_does_not_record_the_clock_keeps_rclpys_subscription(tmp_path: Path,
                                                                               env: dict[str, str]) -> None:
    """Not recording ``/clock``: rclpy's sim-time subscription stays (one reader), and the poses are logged at
    ticks the publisher sent."""
    n = 60
    bag = tmp_path / "poses_only"
    result, log = _record_ticks(bag, "[/{ns}/a_poses]", n, env)
    assert result == {"acked": True, "clock_readers": 1, "sim_time_off": False}, log
    logged = [m.timestamp_ns for m in read_messages(bag, [_topic(bag, "a_poses")])]
    assert len(logged) == n and all(t % DT_NS == 0 and 0 <= t <= n * DT_NS for t in logged)
    assert logged[-1] > 0  # the clock moved: log times are the ticks, not the wall clock nor zero throughout


def test_a_tick_before_time_zero_is_recorded_not_followed(tmp_path: Path, env: dict[str, str]) -> None:
    """A ``/clock`` tick at -0.5 s: the recorder says so once, records it at the sim time so far (0), does not set
    its clock to it, and records the rest as usual."""
    n = 20
    bag = tmp_path / "before_zero"
    result, log = _record_ticks(bag, "[/{ns}/clock, /{ns}/a_poses]", n, env, before_zero=True)
    assert result == {"acked": True, "clock_readers": 1, "sim_time_off": False}, log
    assert log.count("a tick before time 0 (-500000000 ns); the sim time stays where it was") == 1, log
    ticks = [(m.timestamp_ns, m.message.clock.sec) for m in read_messages(bag, [_topic(bag, "clock")])]
    assert ticks == [(0, -1)] + [(k * DT_NS, 0) for k in range(1, n + 1)]
    assert len(list(read_messages(bag, [_topic(bag, "a_poses")]))) == n
