"""The recorder node as a process: SIGINT keeps every published message, SIGKILL leaves recoverable chunks.

Each test runs the recorder and a publisher as subprocesses on localhost-only DDS in the test session's private
domain (``ros_env`` fixture of conftest.py).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO_ROOT as REPO

from bptsb_ros.bags.errors import BagError
from bptsb_ros.bags.metadata import read_metadata
from bptsb_ros.bags.qos import QosProfile
from bptsb_ros.bags.reader import read_messages
from bptsb_ros.bags.recording import (
    RECORDER_PARAMS,
    RecorderConfig,
    incompatible_offers,
    select_topics,
    subscription_policies,
)
from bptsb_ros.interface.params import ParameterError, validate_values

# Publishes N messages on two reliable topics (keep-all, so none is overwritten before it is acknowledged) once
# the subscriptions of the recorder (of S recorders: optional third argument) have matched, waits for the
# acknowledgements, prints "acked" and idles.
PUBLISHER = r"""
import sys, time
import rclpy
from rclpy.duration import Duration
from rclpy.qos import QoSProfile, QoSHistoryPolicy, QoSReliabilityPolicy
from geometry_msgs.msg import Pose, PoseArray
from std_msgs.msg import Float64MultiArray
n, period = int(sys.argv[1]), float(sys.argv[2])
need = int(sys.argv[3]) if len(sys.argv) > 3 else 1
rclpy.init()
node = rclpy.create_node("test_publisher")
qos = QoSProfile(history=QoSHistoryPolicy.KEEP_ALL, depth=1, reliability=QoSReliabilityPolicy.RELIABLE)
data = node.create_publisher(Float64MultiArray, "/bagtest/data", qos)
poses = node.create_publisher(PoseArray, "bagtest/poses", qos)
deadline = time.monotonic() + 30
while (data.get_subscription_count() < need or poses.get_subscription_count() < need) and time.monotonic() < deadline:
    time.sleep(0.02)
if time.monotonic() >= deadline:
    sys.exit("recorder never subscribed")
for i in range(n):
    data.publish(Float64MultiArray(data=[float(i), 0.5 * i]))
    p = PoseArray(poses=[Pose()] * 3)
    p.poses[0].position.x = float(i)
    poses.publish(p)
    if period:
        time.sleep(period)
ok = data.wait_for_all_acked(Duration(seconds=20)) and poses.wait_for_all_acked(Duration(seconds=20))
print("acked" if ok else "not acked", flush=True)
time.sleep(60)
"""


# Like PUBLISHER, in two parts: message 0, then (after a line on stdin) messages 1..N-1.
TWO_PART_PUBLISHER = PUBLISHER.replace("for i in range(n):", """data.publish(Float64MultiArray(data=[0.0, 0.0]))
poses.publish(PoseArray(poses=[Pose()] * 3))
data.wait_for_all_acked(Duration(seconds=20)) and poses.wait_for_all_acked(Duration(seconds=20))
print("first", flush=True)
sys.stdin.readline()
for i in range(1, n):""")


# Publishes on /bagtest/data at ~200 Hz until killed, printing "publishing" once the recorder has subscribed.
ENDLESS_PUBLISHER = r"""
import time
import rclpy
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from std_msgs.msg import Float64MultiArray
rclpy.init()
node = rclpy.create_node("endless_publisher")
pub = node.create_publisher(Float64MultiArray, "/bagtest/data", QoSProfile(depth=100,
                            reliability=QoSReliabilityPolicy.RELIABLE))
while pub.get_subscription_count() == 0:
    time.sleep(0.02)
print("publishing", flush=True)
i = 0
while True:
    pub.publish(Float64MultiArray(data=[float(i)]))
    i += 1
    time.sleep(0.005)
"""


# `bptsb bag recover BAG` as its own process (through the subcommand module, as `bptsb` dispatches it).
RECOVER = (
    "import argparse, sys\n"
    "from bptsb_ros.cli import bag_cmd\n"
    "parser = argparse.ArgumentParser()\n"
    "bag_cmd.add_arguments(parser)\n"
    "sys.exit(bag_cmd.run(parser.parse_args(['recover', sys.argv[1]])))\n"
)


@pytest.fixture
def env(ros_env: dict[str, str]) -> dict[str, str]:
    env = dict(ros_env)  # the session's private domain, localhost discovery
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _recorder(bag: Path, env: dict[str, str], *extra: str, cpu: int | None = None) -> subprocess.Popen[str]:
    """The recorder as a process (``cpu``: pinned to that CPU)."""
    cmd = [sys.executable, "-m", "bptsb_ros.ros.recorder", "--ros-args", "-p", f"bag_path:={bag}",
           "-p", "topics:=[/bagtest/data, bagtest/poses]", *extra]
    pin = None if cpu is None else (lambda: os.sched_setaffinity(0, {cpu}))
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=pin)


def _busy(cpu: int, n: int) -> list[subprocess.Popen]:
    """``n`` processes spinning on ``cpu`` (artificial load: the recorder pinned there gets 1/(n+1) of it)."""
    def pin() -> None:
        os.sched_setaffinity(0, {cpu})

    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=pin) for _ in range(n)]


def _publish(n: int, period: float, env: dict[str, str]) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-c", PUBLISHER, str(n), str(period)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = proc.stdout.readline().strip()
    if line != "acked":
        proc.kill()
        pytest.fail(f"publisher: {line} {proc.communicate(timeout=5)[0]}")
    return proc


def _wait_until_file_stable(path: Path, quiet: float, limit: float = 10.0) -> None:
    """Wait until ``path`` exists and its size has not changed for more than ``quiet`` seconds (at most ``limit``)."""
    end = time.monotonic() + limit
    size, since = -1, time.monotonic()
    while time.monotonic() < end:
        now_size = path.stat().st_size if path.exists() else -1
        if now_size != size:
            size, since = now_size, time.monotonic()
        elif size >= 0 and time.monotonic() - since > quiet:
            return
        time.sleep(0.05)


def _stop(proc: subprocess.Popen[str], sig: int) -> tuple[int, str]:
    proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f"process did not stop on signal {sig}:\n{out}")
    return proc.returncode, out



def _kill_leftovers(*procs: subprocess.Popen | None) -> None:
    """Kill and reap any test process still running (a failed assertion must not leave DDS participants)."""
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()


#: What the test publisher's offer looks like to a recorder, in the rosbag2 v9 form (typed here, not produced by our
#: code): reliable, volatile, no deadline or lifespan, automatic liveliness without a lease (rmw reports these as
#: infinite). DDS discovery does not carry history or depth, so rmw reports them as "unknown" and 0, and rosbag2
#: Jazzy records them so.
OFFERED = [{"history": "unknown", "depth": 0, "reliability": "reliable", "durability": "volatile",
            "deadline": {"sec": 9223372036, "nsec": 854775807}, "lifespan": {"sec": 9223372036, "nsec": 854775807},
            "liveliness": "automatic", "liveliness_lease_duration": {"sec": 9223372036, "nsec": 854775807},
            "avoid_ros_namespace_conventions": False}]


def _assert_raw_offered_qos(bag: Path) -> None:
    """The whole offered profile of both topics, read from metadata.yaml and the MCAP channels without our reader."""
    import yaml
    from mcap.reader import make_reader

    expected = {"/bagtest/data": OFFERED, "/bagtest/poses": OFFERED}
    raw = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
            for t in raw["topics_with_message_count"]} == expected
    with open(bag / f"{bag.name}_0.mcap", "rb") as f:
        channels = make_reader(f).get_summary().channels.values()
    assert {c.topic: yaml.safe_load(c.metadata["offered_qos_profiles"]) for c in channels} == expected


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stop_signal_keeps_every_message(tmp_path: Path, env: dict[str, str], sig: int) -> None:
    n = 4000  # one burst: a keep-last-1000 subscription loses part of it before the executor takes it
    bag = tmp_path / "rec"
    # per-topic lines are DEBUG: shown with log_level debug, for one of the two signals
    recorder = _recorder(bag, env, *(["-p", "log_level:=debug"] if sig == signal.SIGINT else []))
    publisher = None
    try:
        publisher = _publish(n, 0.0, env)
        rc, out = _stop(recorder, sig)  # at once: messages may still wait in the reader queue
    finally:
        _kill_leftovers(publisher, recorder)
    assert rc == 0, out
    assert ("Subscribed to /bagtest/poses [geometry_msgs/msg/PoseArray]" in out) == (sig == signal.SIGINT), out
    assert "All 2 requested topics subscribed" in out
    meta = read_metadata(bag)
    assert {t.name: t.message_count for t in meta.topics} == {"/bagtest/data": n, "/bagtest/poses": n}
    _assert_raw_offered_qos(bag)
    data = [m.message.data[0] for m in read_messages(bag, ["/bagtest/data"])]
    assert data == [float(i) for i in range(n)]
    times = [m.timestamp_ns for m in read_messages(bag)]
    assert times == sorted(times) and abs(times[0] - time.time_ns()) < 120e9
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        assert sorted(c.msgcount for c in reader.connections) == [n, n]
        poses = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages() if c.topic == "/bagtest/poses"]
    assert [p.poses[0].position.x for p in poses] == [float(i) for i in range(n)]


@pytest.mark.slow
def test_stop_signal_keeps_every_message_under_load(tmp_path: Path, env: dict[str, str]) -> None:
    """The recorder shares one CPU with 3 busy processes: a burst of 2 × 4000 messages (all acknowledged by the
    recorder's DDS reader, so all waiting in its queue when SIGINT comes) is still recorded whole and the bag
    says nothing was lost. Taking one message per executor call, the recorder used to need more than its 8 s
    stop_timeout for this backlog and closed the bag without the rest ("later ones are lost"), exiting 0."""
    n = 4000
    cpu = min(os.sched_getaffinity(0))
    bag = tmp_path / "loaded"
    busy = _busy(cpu, 3)
    recorder = publisher = None
    try:
        recorder = _recorder(bag, env, cpu=cpu)
        publisher = _publish(n, 0.0, env)
        rc, out = _stop(recorder, signal.SIGINT)
    finally:
        _kill_leftovers(publisher, recorder, *busy)
    assert rc == 0, out
    meta = read_metadata(bag)
    assert {t.name: t.message_count for t in meta.topics} == {"/bagtest/data": n, "/bagtest/poses": n}, out
    assert meta.custom_data["dropped_messages"] == "0" and meta.custom_data["recording_complete"] == "true"
    assert [m.message.data[0] for m in read_messages(bag, ["/bagtest/data"])] == [float(i) for i in range(n)]


@pytest.mark.slow
def test_lost_messages_are_counted_and_fail_the_recorder(tmp_path: Path, env: dict[str, str]) -> None:
    """Two recorders with a 1-message queue (one with allow_loss) are stopped (SIGSTOP) while 2 × 499 messages are
    published, then resumed: each queue keeps only the newest of each topic. The gaps in the publishers' sequence
    numbers are counted: each bag's custom_data says how many were lost per topic (checked here against what was
    published), the log says LOST, and the recorder exits 1, or 0 with allow_loss. Both recorders listen to the same
    publisher run (one run for both settings)."""
    n = 500
    settings = (False, True)  # allow_loss of each recorder
    bags = [tmp_path / f"lossy_{str(allow).lower()}" for allow in settings]
    recorders = [_recorder(bag, env, "-p", "queue_depth:=1", "-p", f"allow_loss:={str(allow).lower()}")
                 for bag, allow in zip(bags, settings)]
    publisher = subprocess.Popen([sys.executable, "-c", TWO_PART_PUBLISHER, str(n), "0", str(len(recorders))],
                                 env=env, text=True, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 stderr=subprocess.STDOUT)
    results = []
    try:
        assert publisher.stdout.readline().strip() == "first"  # message 0 acknowledged by both recorders
        time.sleep(1.0)  # message 0 is taken and written
        for recorder in recorders:
            recorder.send_signal(signal.SIGSTOP)
        publisher.stdin.write("go\n")
        publisher.stdin.flush()
        time.sleep(2.0)  # messages 1..n-1 are sent into the stopped recorders' 1-message queues
        for recorder in recorders:
            recorder.send_signal(signal.SIGCONT)
        assert publisher.stdout.readline().strip() == "acked"
        results = [_stop(recorder, signal.SIGINT) for recorder in recorders]
    finally:
        _kill_leftovers(publisher, *recorders)
    for bag, allow_loss, (rc, out) in zip(bags, settings, results):
        meta = read_metadata(bag)
        counts = {t.name: t.message_count for t in meta.topics}
        assert all(2 <= c < n for c in counts.values()), counts
        assert json.loads(meta.custom_data["dropped_by_topic"]) == {t: n - c for t, c in counts.items()}
        assert meta.custom_data["dropped_messages"] == str(2 * n - sum(counts.values()))
        assert "LOST messages on /bagtest/data" in out and f"the recording LOST {2 * n - sum(counts.values())}" in out
        assert rc == (0 if allow_loss else 1), out


@pytest.mark.slow
def test_messages_published_after_the_stop_are_not_waited_for(tmp_path: Path, env: dict[str, str]) -> None:
    """A publisher that never stops: the recorder stops within a second of SIGINT (it used to keep taking the new
    messages until its stop_timeout, here 60 s, and then report "later ones are lost"; the bound is 15 s for busy
    cores), records every message up to the
    stop signal without a gap, and reports no loss."""
    bag = tmp_path / "endless"
    # a stop_timeout far above the bound below: the old recorder took until it to stop
    recorder = _recorder(bag, env, "-p", "topics:=[/bagtest/data]", "-p", "stop_timeout:=60.0")
    publisher = subprocess.Popen([sys.executable, "-c", ENDLESS_PUBLISHER], env=env, text=True,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        assert publisher.stdout.readline().strip() == "publishing"
        time.sleep(1.5)
        asked = time.monotonic()
        rc, out = _stop(recorder, signal.SIGINT)
        took = time.monotonic() - asked
    finally:
        _kill_leftovers(publisher, recorder)
    assert rc == 0, out
    assert took < 15.0, f"{took:.1f} s to stop\n{out}"
    assert "published after the stop signal, not recorded" in out and "stop_timeout" not in out, out
    data = [m.message.data[0] for m in read_messages(bag, ["/bagtest/data"])]
    assert len(data) > 50 and data == [float(i) for i in range(int(data[0]), int(data[0]) + len(data))]
    assert read_metadata(bag).custom_data["dropped_messages"] == "0"


def test_a_storm_of_stop_signals_never_hangs_the_recorder(tmp_path: Path, env: dict[str, str]) -> None:
    """``kill -INT -PGID`` of a launch gives every node SIGINT twice at once (the group's and launch's), and launch
    escalates to SIGTERM. A stop handler that takes a lock (``threading.Event.set``) deadlocks when the second
    signal's handler runs inside the first's: the recorder then hung until SIGKILL. SIGINT and SIGTERM as fast as they
    can be sent for 1.5 s, many landing inside a running handler: it still stops cleanly within seconds."""
    bag = tmp_path / "storm"
    # a 1.5 s drain keeps the recorder taking stop signals (not yet ignoring them) for the whole storm
    recorder = _recorder(bag, env, "-p", "topics:=[/bagtest/data]", "-p", "drain_quiet:=1.5")
    try:
        lines: list[str] = []
        while not any("Recording to" in line for line in lines) and recorder.poll() is None:
            lines.append(recorder.stdout.readline())
        assert recorder.poll() is None, "".join(lines) + recorder.communicate()[0]
        storm_end = time.monotonic() + 1.5  # a burst coalesces into a few deliveries: keep them coming
        while time.monotonic() < storm_end and recorder.poll() is None:
            os.kill(recorder.pid, signal.SIGINT)
            os.kill(recorder.pid, signal.SIGTERM)
        try:
            out, _ = recorder.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            recorder.kill()
            pytest.fail("the recorder hung on a storm of stop signals:\n" + "".join(lines) + recorder.communicate()[0])
    finally:
        _kill_leftovers(recorder)
    assert recorder.returncode == 0, "".join(lines) + out
    assert "closed: 0 messages" in out and read_metadata(bag).message_count == 0, out


#: A child that calls the recorder's stop handler with a second call nested at every line it runs (its own and those
#: of whatever it calls): what a signal arriving at any moment of the first one's handler does. A handler holding a
#: lock deadlocks here, at once and every time. Then, untraced, a later signal. It prints the nested calls made,
#: the window of the first call and the stop time before and after the later signal.
STOP_REQUEST_CHILD = (
    "import sys, time\n"
    "from bptsb_ros.ros.recorder import StopRequest\n"
    "stop, nested = StopRequest(), [0]\n"
    "def tracer(frame, event, arg):\n"
    "    if event == 'line':\n"
    "        nested[0] += 1\n"
    "        stop()\n"  # untraced: a trace function is not traced itself
    "    return tracer\n"
    "t0 = time.time_ns()\n"
    "sys.settrace(tracer)\n"
    "stop()\n"
    "sys.settrace(None)\n"
    "t1 = time.time_ns()\n"
    "first = stop.ns\n"
    "time.sleep(0.01)\n"
    "stop()\n"
    "print(nested[0], t0, t1, first, stop.ns, flush=True)\n"
)


def test_the_stop_handler_survives_signals_inside_itself(env: dict[str, str]) -> None:
    """The handler alone, a second call nested at each of its lines: no deadlock, and the stop time stays the
    first signal's (a later signal changes nothing)."""
    try:
        run = subprocess.run([sys.executable, "-c", STOP_REQUEST_CHILD], env=env, capture_output=True, text=True,
                             timeout=30)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the stop handler deadlocked on a call nested inside it: {exc.stderr}")
    assert run.returncode == 0, run.stderr
    nested, t0, t1, first, after = map(int, run.stdout.split())
    assert nested >= 1 and t0 <= first <= t1 and after == first


def test_sigkill_leaves_recoverable_chunks(tmp_path: Path, env: dict[str, str]) -> None:
    n = 200
    bag = tmp_path / "killed"
    flush_period = 0.2
    recorder = _recorder(bag, env, "-p", f"flush_period:={flush_period}", "-p", "chunk_size:=2048")
    publisher = None
    try:
        publisher = _publish(n, 0.001, env)
        # the recorder closes and writes its last chunk within flush_period of the last message, also when loaded
        _wait_until_file_stable(bag / f"{bag.name}_0.mcap", quiet=3 * flush_period)
        rc, out = _stop(recorder, signal.SIGKILL)
    finally:
        _kill_leftovers(publisher, recorder)
    assert rc == -signal.SIGKILL
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(BagError, match="bptsb bag recover"):
        list(read_messages(bag))
    result = subprocess.run([sys.executable, "-c", RECOVER, str(bag)], env=env, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stderr
    chunks = re.search(r"recovered (\d+) messages in (\d+) complete chunks", result.stdout)
    assert chunks is not None and int(chunks[1]) == 2 * n and int(chunks[2]) > 1, result.stdout
    meta = read_metadata(bag)
    assert meta.message_count == 2 * n
    assert [m.message.data[0] for m in read_messages(bag, "/bagtest/data")] == [float(i) for i in range(n)]


def test_bad_parameters_exit_with_a_clear_error(tmp_path: Path, env: dict[str, str]) -> None:
    cmd = [sys.executable, "-m", "bptsb_ros.ros.recorder", "--ros-args", "-p", "compression:=gzip",
           "-p", f"bag_path:={tmp_path / 'x'}"]
    result = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "'compression'" in result.stderr and "gzip" in result.stderr
    result = subprocess.run(cmd[:3], env=env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "'bag_path' is required" in result.stderr
    existing = tmp_path / "full"
    existing.mkdir()
    (existing / "f").write_text("x")
    result = subprocess.run(cmd[:4] + ["-p", f"bag_path:={existing}"], env=env, capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2 and "already exists" in result.stderr


def _config(**values: object) -> RecorderConfig:
    return RecorderConfig.from_values(validate_values(RECORDER_PARAMS, {"bag_path": "b", **values}))


def test_config_topic_selection_and_qos_rules() -> None:
    config = _config(topics=["/clock", "body/positions", "/clock"], custom_data=["agent=runs/a", "x=1=2"])
    assert config.topics == ("/clock", "/body/positions") and config.custom_data == {"agent": "runs/a", "x": "1=2"}
    namespaced = RecorderConfig.from_values(validate_values(RECORDER_PARAMS, {"bag_path": "b", "topics": ["p"]}), "/ns")
    assert namespaced.topics == ("/ns/p",)
    graph = [("/clock", ["rosgraph_msgs/msg/Clock"]), ("/body/positions", ["geometry_msgs/msg/PoseArray"]),
             ("/rosout", ["rcl_interfaces/msg/Log"]), ("/_hidden/x", ["std_msgs/msg/Empty"])]
    assert select_topics(graph, config) == {"/clock": ["rosgraph_msgs/msg/Clock"],
                                            "/body/positions": ["geometry_msgs/msg/PoseArray"]}
    everything = _config(exclude_topics=["rosout"])
    assert list(select_topics(graph, everything)) == ["/clock", "/body/positions"]
    assert list(select_topics(graph, _config(include_hidden_topics=True))) == [t for t, _ in graph]
    for bad, match in (({"bag_path": " "}, "'bag_path' is required"), ({"topics": ["a b"]}, "not a valid topic"),
                       ({"custom_data": ["novalue"]}, "key=value"), ({"queue_depth": -1}, "'queue_depth'"),
                       ({"flush_period": 0.0}, "'flush_period'"), ({"compression": "gzip"}, "'compression'")):
        with pytest.raises(ParameterError, match=match):
            _config(**bad)
    reliable, best_effort = QosProfile(), QosProfile(reliability="best_effort")
    latched = QosProfile(durability="transient_local")
    assert subscription_policies([reliable, reliable]) == ("reliable", "volatile")
    assert subscription_policies([reliable, best_effort]) == ("best_effort", "volatile")
    assert subscription_policies([latched]) == ("reliable", "transient_local")
    assert subscription_policies([latched, reliable]) == ("reliable", "volatile")
    assert incompatible_offers([reliable, best_effort], ("reliable", "volatile")) == [best_effort]
    assert incompatible_offers([reliable, best_effort], ("best_effort", "volatile")) == []
    assert incompatible_offers([latched, reliable], ("reliable", "transient_local")) == [reliable]
