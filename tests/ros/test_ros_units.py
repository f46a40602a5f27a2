"""Fast, single-process tests of the live-loop pieces that need no ROS graph: command validation,
stamps, parameters, params files, loop wiring, launch files and the topic table."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO_ROOT as REPO

from bptsb_ros.interface.params import Param, ParameterError, params_sections_text, validate_values
from bptsb_ros.interface.topics import TOPICS, dt_to_ns, stamp_to_step, step_to_stamp
from bptsb_ros.live.channels import CommandChannel, TimingStats
from bptsb_ros.live.loops import (
    LOOPS,
    format_parameter,
    node_parameters,
    startup_subscribers,
    topic_names,
    with_feedback_state,
)

NAMES = [f"spring_{e}" for e in range(4)]


def channel(mode: str = "lockstep") -> CommandChannel:
    return CommandChannel("rest_length", 4, NAMES, mode, max_ahead=10, max_age_steps=3)


def off(ch: CommandChannel, *args, **kwargs) -> str | None:
    rejection = ch.offer(*args, **kwargs)
    return None if rejection is None else rejection.message


def test_lockstep_channel_rejects_bad_commands_and_keeps_good_ones():
    ch = channel()
    assert "3 values, expected 4" in off(ch, 5, [1.0, 1.0, 1.0], 5, 0.0)
    assert "NaN/inf at index 2" in off(ch, 5, [1.0, 1.0, np.nan, 1.0], 5, 0.0)
    assert "NaN/inf" in off(ch, 5, [1.0, np.inf, 1.0, 1.0], 5, 0.0)
    assert "joint names" in off(ch, 5, [1.0] * 4, 5, 0.0, names=["a", "b", "c", "d"])
    assert "after that step was integrated" in off(ch, 4, [1.0] * 4, 5, 0.0)
    assert not ch.has(5)
    assert off(ch, 5, [1.0, 2.0, 3.0, 4.0], 5, 0.0, names=NAMES) is None
    assert "already queued" in off(ch, 5, [9.0] * 4, 5, 0.0)
    assert off(ch, 7, [7.0] * 4, 5, 0.0, names=[]) is None  # ahead: buffered
    assert "ahead" in off(ch, 16, [1.0] * 4, 5, 0.0)
    cmd = ch.take(5)
    assert cmd is not None and cmd.step == 5 and cmd.values.tolist() == [1.0, 2.0, 3.0, 4.0]
    assert ch.take(6) is None and ch.take(7).values[0] == 7.0
    counts = ch.counts()
    assert counts["accepted"] == 2
    reasons = ("wrong_length", "non_finite", "wrong_names", "stale", "duplicate", "too_far_ahead")
    assert [counts[f"rejected_{r}"] for r in reasons] == [1, 2, 1, 1, 1, 1]


def test_realtime_channel_uses_newest_and_rejects_old():
    ch = channel("realtime")
    assert off(ch, 10, [1.0] * 4, 10, 0.0) is None
    assert "not newer" in off(ch, 9, [2.0] * 4, 10, 0.0)
    assert "steps old" in off(ch, 11, [2.0] * 4, 15, 0.0)
    assert ch.take(12).values[0] == 1.0  # 2 steps old: usable
    assert ch.take(14) is None  # 4 steps old > max_age_steps = 3


def test_timing_summary_units():
    stats = TimingStats(jitter=[0.001, 0.003], compute=[0.002], age=[0, 2], latency=[0.0005], deadline_misses=1,
                        steps=2)
    s = stats.summary()
    assert s["jitter_ms_mean"] == pytest.approx(2.0) and s["jitter_ms_max"] == pytest.approx(3.0)
    assert s["command_age_steps_max"] == 2 and s["deadline_misses"] == 1 and s["command_latency_ms_p50"] == 0.5


@pytest.mark.parametrize("dt", [0.01, 0.001, 0.0125, 1.0])
def test_stamps_round_trip_exactly(dt):
    ns = dt_to_ns(dt)
    for step in (0, 1, 99, 123_456_789):
        sec, nanosec = step_to_stamp(step, ns)
        assert 0 <= nanosec < 10**9 and stamp_to_step(sec, nanosec, ns) == step
    with pytest.raises(ValueError, match="whole number of nanoseconds"):
        dt_to_ns(1e-10)


def test_parameter_validation_names_the_parameter():
    specs = [Param("rate", 1.0, "rate [Hz]", "float", positive=True),
             Param("mode", "a", "mode", "str", choices=("a", "b")),
             Param("topics", [], "topics", "str_list"), Param("n", 3, "count", "int", minimum=1)]
    ok = validate_values(specs, {"rate": 2, "topics": None})
    assert ok == {"rate": 2.0, "mode": "a", "topics": [], "n": 3}
    for values, pattern in (({"rate": 0.0}, "'rate' must be > 0"), ({"rate": "x"}, "'rate' must be a number"),
                            ({"mode": "c"}, "'mode'.*choose from a, b"), ({"n": 0}, "'n' must be >= 1"),
                            ({"n": 1.5}, "'n' must be an integer"), ({"topics": ["a", 1]}, "'topics' must be a list"),
                            ({"rate": float("nan")}, "'rate' must be finite"), ({"bogus": 1}, "unknown parameter")):
        with pytest.raises(ParameterError, match=pattern):
            validate_values(specs, values)


def test_params_sections_text_types_every_value_and_leaves_out_empty_lists():
    text = params_sections_text({"/**": {"agent": "runs/it's", "rate": 1.0, "n": 3, "enabled": True, "none": [],
                                         "names": ["a", "b"], "empty": ""}},
                                {"/**": ["qos_depth:=40"], "/**/other": ["ignored:=1"]})
    assert text == ("/**:\n"
                    "  ros__parameters:\n"
                    "    agent: 'runs/it''s'\n"
                    "    rate: 1.0\n"
                    "    n: 3\n"
                    "    enabled: true\n"
                    "    names: ['a', 'b']\n"
                    "    empty: ''\n"
                    "    qos_depth: 40\n")
    read = yaml.safe_load(text)["/**"]["ros__parameters"]
    assert read == {"agent": "runs/it's", "rate": 1.0, "n": 3, "enabled": True, "names": ["a", "b"], "empty": "",
                    "qos_depth": 40}


def test_params_files_match_the_declared_parameters():
    from bptsb_ros.ros.param_files import NODES, render

    for node in NODES:
        path = REPO / "config" / f"{node}_params.yaml"
        assert path.read_text() == render(node), f"{path} is stale: python -m bptsb_ros.ros.param_files config"
        import yaml

        params = yaml.safe_load(path.read_text())["/**"]["ros__parameters"]
        assert params["dtype"] == "float64" and ("use_sim_time" in params) == (node != "body_sim")


def test_loop_wiring():
    assert set(LOOPS) == {"lissajous_open", "lissajous_closed", "locomotion_open", "locomotion_closed",
                          "locomotion_headwind", "lissajous_switching", "narma", "mnist_drawing"}
    switching = LOOPS["lissajous_switching"]
    assert switching.wait_for == ("rest_length", "wind") and [b.executable for b in switching.brains] == [
        "swg_brain", "wind_source"]
    narma = LOOPS["narma"]
    assert topic_names(narma.topics())[-2:] == ["/task/input", "/brain/force"]
    counts = dict(e.rsplit(":", 1) for e in startup_subscribers(narma, recording=True))
    # /clock: recorder + task_input (its trigger; mlp_brain takes its sim time from task/input)
    assert counts["/clock"] == "2" and counts["/task/input"] == "2" and counts["/brain/force"] == "2"
    assert counts["/body/positions"] == "1"
    closed = dict(e.rsplit(":", 1) for e in startup_subscribers(LOOPS["lissajous_closed"], recording=False))
    assert closed == {"/clock": "1", "/body/positions": "1", "/brain/rest_length": "1"}
    # the feedback brain reads the state every step: body/positions always, body/mass_states on request
    assert "every_step" not in node_parameters(LOOPS["lissajous_closed"], "body_sim")
    velocity = with_feedback_state(LOOPS["lissajous_closed"], "velocity")
    assert node_parameters(velocity, "body_sim")["every_step"] == ["mass_states"]
    assert "mass_states" not in velocity.step_topics() and "body/mass_states" in [TOPICS[k].name for k in
                                                                                     velocity.topics()]
    body = node_parameters(LOOPS["lissajous_open"], "body_sim", mode="realtime", duration=3.0)
    assert body["wall_duration"] == 3.0 and "duration" not in body and body["wait_for"] == ["rest_length"]
    assert "perturb_at" not in body
    kicked = node_parameters(LOOPS["lissajous_open"], "body_sim", perturb_at=2.5, perturb_sigma=0.3, perturb_seed=7)
    assert (kicked["perturb_at"], kicked["perturb_sigma"], kicked["perturb_seed"]) == (2.5, 0.3, 7)
    brain = node_parameters(LOOPS["lissajous_open"], "swg_brain", agent="runs/x")
    assert brain == {"agent": "runs/x", "use_sim_time": True, "min_subscribers": 1}
    assert node_parameters(narma, "task_input", recording=True)["min_subscribers"] == 2  # mlp_brain, recorder
    with pytest.raises(ValueError, match="no node 'mlp_brain'"):
        node_parameters(LOOPS["lissajous_open"], "mlp_brain")
    assert format_parameter("agent", "123") == "agent:='123'"
    assert format_parameter("topics", ["/a", "y"]) == "topics:=['/a', 'y']"


def test_launch_files_mirror_the_loops():
    files = sorted((REPO / "launch").glob("*.launch.py"))
    assert {f.name.removesuffix(".launch.py") for f in files} == set(LOOPS)
    for f in files:
        tree = ast.parse(f.read_text())
        funcs = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
        assert [fn.name for fn in funcs] == ["generate_launch_description"]
        calls = [n for n in ast.walk(funcs[0]) if isinstance(n, ast.Call)]
        loops = [c.args[0].value for c in calls if getattr(c.func, "id", "") == "ros_launch_description"]
        assert loops == [f.name.removesuffix(".launch.py")]


def test_topic_table_documents_every_topic():
    text = (REPO / "bptsb_ros" / "ros" / "TOPICS.md").read_text()
    rows = {m.group(1): m.group(2) for m in re.finditer(r"^\| `([^`]+)` \| `([^`]+)` \|", text, re.M)}
    for topic in TOPICS.values():
        assert rows.get(topic.name) == topic.type, f"{topic.name} missing or with another type in TOPICS.md"


def test_timing_stats_keep_bounded_windows():
    from bptsb_ros.live.channels import RunningStats

    series = RunningStats([5.0, 1.0, 2.0, 3.0], window=3)
    assert len(series) == 4 and series.mean == pytest.approx(2.75) and series.max == 5.0
    assert list(series.recent) == [1.0, 2.0, 3.0] and series.percentile(50) == 2.0  # last 3 samples only
    stats = TimingStats()
    for k in range(3 * 10_000):
        stats.compute.append(k * 1e-6)
    assert len(stats.compute.recent) == 10_000 and stats.summary()["compute_ms_max"] == pytest.approx(29.999)


def test_recorder_parameters_describe_the_run():
    from bptsb_ros.live.loops import log_dir_of_bag, recorder_parameters

    params = recorder_parameters(LOOPS["lissajous_closed"], "bags/x", mode="realtime", agent="runs/a",
                                 open_loop_steps=30)
    assert params["bag_path"] == "bags/x" and params["topics"] == topic_names(LOOPS["lissajous_closed"].topics())
    assert params["custom_data"] == ["loop=lissajous_closed", "mode=realtime", "agent=runs/a", "open_loop_steps=30"]
    assert "agent=fresh" in recorder_parameters(LOOPS["narma"], "b")["custom_data"]
    assert log_dir_of_bag("bags/x/") == Path("bags/x.launch")


def test_launcher_reports_the_signal_that_stopped_a_node(tmp_path):
    import subprocess
    import sys

    from bptsb_ros.cli.launch_cmd import Child, Launcher

    code = ("import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); "
            "time.sleep(60)")
    child = Child("stubborn", [sys.executable, "-c", code], tmp_path / "stubborn.log")
    child.proc = subprocess.Popen(child.argv, stdout=subprocess.PIPE, text=True)
    try:
        assert child.proc.stdout.readline().strip() == "ready"
        launcher = Launcher([child], child, None, grace=0.5)
        launcher.stop(child)
        assert child.killed == "SIGTERM" and child.code == -15
    finally:
        if child.proc.poll() is None:
            child.proc.kill()
        child.proc.wait()
        child.proc.stdout.close()


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux only")
def test_launched_nodes_die_with_the_launcher():
    """A child started with die_with_parent_hook gets SIGTERM when the launcher is killed outright."""
    import os
    import signal
    import subprocess
    import sys
    import time

    parent = (
        "import subprocess, sys, time\n"
        "from bptsb_ros.cli.launch_cmd import die_with_parent_hook\n"
        "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'], start_new_session=True,\n"
        "                         preexec_fn=die_with_parent_hook())\n"
        "print(child.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True, env=env)
    child = int(proc.stdout.readline())
    dead = False
    try:
        proc.kill()
        proc.wait()
        end = time.monotonic() + 10
        while not dead and time.monotonic() < end:
            try:
                with open(f"/proc/{child}/stat") as f:  # a zombie ('Z') waits for init to reap it: dead too
                    dead = f.read().rsplit(")", 1)[1].split()[0] == "Z"
            except FileNotFoundError:
                dead = True
            time.sleep(0.05)
        assert dead, "the child outlived its killed parent"
    finally:
        proc.stdout.close()
        if not dead:
            os.kill(child, signal.SIGKILL)


def test_executor_parameter_makes_the_executor_it_names():
    """Every value of the nodes' ``executor`` parameter gives that executor, and ``executor_kind`` (what body_sim
    writes into its timing records) names it back; events is the default."""
    rclpy = pytest.importorskip("rclpy")
    pytest.importorskip("rclpy.experimental")
    from rclpy.context import Context

    from bptsb_ros.interface.params import EXECUTOR, EXECUTORS
    from bptsb_ros.ros.runtime import executor_kind, make_executor

    assert EXECUTORS == ("events", "single") and EXECUTOR.default == "events" and EXECUTOR.choices == EXECUTORS
    context = Context()
    rclpy.init(context=context, domain_id=0)
    try:
        for kind, cls in (("events", "EventsExecutor"), ("single", "SingleThreadedExecutor")):
            executor = make_executor(kind, context)
            assert (type(executor).__name__, executor_kind(executor)) == (cls, kind)
            executor.shutdown()
    finally:
        rclpy.shutdown(context=context)


class FakePublisher:
    """A publisher whose subscribers acknowledge after ``acks_after`` polls (None: never) and leave after
    ``leaves_after`` polls (None: never)."""

    def __init__(self, topic: str, subscribers: int, acks_after: int | None, leaves_after: int | None = None):
        self.topic_name, self.subscribers, self.polls = topic, subscribers, 0
        self.acks_after, self.leaves_after = acks_after, leaves_after

    def get_subscription_count(self) -> int:
        gone = self.leaves_after is not None and self.polls >= self.leaves_after
        return 0 if gone else self.subscribers

    def wait_for_all_acked(self, timeout) -> bool:
        self.polls += 1
        return self.acks_after is not None and self.polls >= self.acks_after


class Warnings:
    def __init__(self):
        self.lines: list[str] = []

    def warning(self, text: str) -> None:
        self.lines.append(text)


def test_wait_acked_warns_only_of_subscribers_still_there_and_silent():
    from bptsb_ros.ros.runtime import wait_acked

    log = Warnings()
    quick, slow = FakePublisher("/a", 1, acks_after=1), FakePublisher("/b", 2, acks_after=3)
    wait_acked(log, [quick, slow], 1.0)
    assert log.lines == [] and (quick.polls, slow.polls) == (1, 3)
    # a subscriber that never acknowledges is named; one whose subscribers left (their process ended first) is not,
    # and it is no longer polled once they are gone
    silent, left, unread = (FakePublisher("/silent", 1, None), FakePublisher("/left", 1, None, leaves_after=2),
                            FakePublisher("/unread", 0, None))
    wait_acked(log, [silent, left, unread], 0.05)
    assert len(log.lines) == 1 and "/silent" in log.lines[0] and "/left" not in log.lines[0]
    assert "/unread" not in log.lines[0] and left.polls == 2 and unread.polls == 0 and silent.polls > 2
    assert "(limit 0.05 s)" in log.lines[0]
    wait_acked(log, [FakePublisher("/c", 1, None)], 0.02, "final_ack_timeout")
    assert "(final_ack_timeout 0.02 s)" in log.lines[1]
    log.lines.pop()
    # timeout 0: no wait at all, no warning
    never = FakePublisher("/never", 1, None)
    wait_acked(log, [never], 0.0)
    assert never.polls == 0 and len(log.lines) == 1
