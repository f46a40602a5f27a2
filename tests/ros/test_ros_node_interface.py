"""What a ROS 2 user meets at a node: ``--help`` and unknown arguments, live parameters with a
validating callback and read-only reasons, ``use_sim_time`` defaults, a stop signal delivered twice, readable
summaries, and command topics that hand late joiners no backlog."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from ros_live import REPO, Probe, env_for, start_node

from bptsb_ros.interface import params as P
from bptsb_ros.ros.declare_params import declare_parameters
from bptsb_ros.ros.runtime import DUPLICATE_WINDOW, StopFlag

FRESH_BODY = {"task": "lissajous", "mode": "realtime", "startup_timeout": 1.0, "final_ack_timeout": 0.0}


# -- stop signals ---------------------------------------------------------------------------------------
def test_stop_signal_twice_within_the_window_is_one_request():
    stop = StopFlag()
    assert stop.signal("SIGINT", now=100.0) is False and stop.reason == "SIGINT"
    assert stop.signal("SIGINT", now=100.0 + 0.01) is False  # the launcher's forwarded copy
    assert stop.signal("SIGTERM", now=100.0 + DUPLICATE_WINDOW) is False
    assert stop.duplicates == 2
    assert stop.signal("SIGINT", now=100.0 + DUPLICATE_WINDOW + 0.5) is True  # a later one: exit now


def _wait_for(path, text: str, proc: subprocess.Popen, timeout: float) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        out = path.read_text()
        if text in out:
            return out
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    raise AssertionError(f"{text!r} not logged within {timeout} s:\n{path.read_text()[-3000:]}")


@pytest.mark.slow
def test_group_sigint_delivered_twice_stops_the_body_cleanly(tmp_path, ros_env):
    """What a supervisor's group SIGINT does under non-interactive ``ros2 launch``: the node gets SIGINT from the
    group and again from the launcher. It must stop cleanly and log its run summary, not exit 1."""
    log = tmp_path / "body.log"
    proc = start_node("body_sim", FRESH_BODY, ros_env, log)
    try:
        _wait_for(log, "startup", proc, 90)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out = log.read_text()
    assert proc.returncode == 0, out[-3000:]
    assert "stopped by SIGINT after" in out and "interrupted twice" not in out, out[-3000:]
    assert "rest-length commands" in out  # the multi-line summary was logged


# -- --help and arguments -------------------------------------------------------------------------------
def _node(args: list[str], ros_env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], env=env_for(ros_env), cwd=REPO, capture_output=True,
                          text=True, timeout=120)


@pytest.mark.slow
def test_node_help_lists_parameters_and_exits(ros_env):
    from bptsb_ros.ros.body_sim import PARAMS

    out = _node(["bptsb_ros.ros.body_sim", "--help"], ros_env)
    assert out.returncode == 0, out.stderr
    for p in PARAMS:
        assert f"\n  {p.name}: " in out.stdout
    assert "rate_scale: 1.0\n      realtime: sim seconds per wall second" in out.stdout
    assert "[dynamic:" in out.stdout and "[read-only: the timing loop" in out.stdout


def _all_node_specs():
    """Every node's parameter specs, by node name: the params-file nodes (``param_files.NODES``) and the recorder."""
    import importlib

    from bptsb_ros.bags.recording import RECORDER_PARAMS
    from bptsb_ros.ros.brain_node import COMMON_PARAMS
    from bptsb_ros.ros.param_files import NODES

    specs = {"recorder": ("bptsb_ros.ros.recorder", RECORDER_PARAMS)}
    for node, module in NODES.items():
        own = importlib.import_module(module).PARAMS
        specs[node] = (module, own if node == "body_sim" else COMMON_PARAMS + tuple(own))
    return specs


def test_every_node_help_lists_all_its_parameters(capsys):
    """``<node> --help`` (its main(), in this process: the help exits before rclpy starts) lists every
    parameter the node declares, wind_source included."""
    import importlib

    for node, (module, specs) in _all_node_specs().items():
        assert importlib.import_module(module).main(["--help"]) == 0, node
        out = capsys.readouterr().out
        assert out.startswith(f"usage: ros2 run bptsb_ros {node} "), (node, out[:200])
        missing = [p.name for p in specs if f"\n  {p.name}: " not in out]
        assert not missing, (node, missing)


@pytest.mark.slow
def test_unknown_node_argument_is_an_error(ros_env):
    for module in ("bptsb_ros.ros.body_sim", "bptsb_ros.ros.recorder"):
        out = _node([module, "--agent", "x", "--ros-args", "-p", "task:=lissajous"], ros_env)
        assert out.returncode == 2, (module, out.stdout, out.stderr)
        assert "unrecognized argument(s) --agent x" in out.stderr
        assert "startup" not in out.stdout + out.stderr  # nothing was started


def test_check_cli_accepts_only_ros_arguments():
    from bptsb_ros.ros.runtime import check_cli

    spec = (P.Param("x", 1, "an x", "int"),)
    assert check_cli("n", ["--ros-args", "-p", "x:=2", "-r", "a:=b"], spec) is None
    assert check_cli("n", [], spec) is None
    assert check_cli("n", ["--ros-args", "-p", "x:=2", "--", "extra"], spec) == 2
    assert check_cli("n", ["-h"], spec) == 0


def test_check_cli_refuses_unknown_or_malformed_ros_arguments_in_one_line(capsys):
    from bptsb_ros.ros.runtime import check_cli

    spec = (P.Param("x", 1, "an x", "int"),)
    assert check_cli("n", ["--ros-args", "-p", "x:=2", "--zzz"], spec) == 2
    err = capsys.readouterr().err
    assert err.startswith("n: unknown ROS argument(s) --zzz after --ros-args") and err.count("\n") == 1
    assert check_cli("n", ["--ros-args", "-p", "x"], spec) == 2
    err = capsys.readouterr().err
    assert err.startswith("n: invalid ROS arguments: Couldn't parse parameter override rule: '-p x'")
    assert err.count("\n") == 1 and ".c:" not in err  # no C source locations
    assert check_cli("n", ["--ros-args", "--log-level", "warn"], spec) is None  # a known one still passes


# -- parameter tables -------------------------------------------------------------------------------------
def _node_specs():
    from bptsb_ros.bags.recording import RECORDER_PARAMS
    from bptsb_ros.ros import body_sim, feedback_brain, image_streamer, mlp_brain, mnist_brain, swg_brain, task_input
    from bptsb_ros.ros.brain_node import COMMON_PARAMS

    return {"body_sim": body_sim.PARAMS, "recorder": RECORDER_PARAMS,
            **{m.NODE: COMMON_PARAMS + m.PARAMS for m in (feedback_brain, mlp_brain, swg_brain, task_input,
                                                         image_streamer, mnist_brain)}}


def test_live_parameters_are_the_documented_ones():
    dynamic = {node: {p.name for p in specs if p.dynamic} for node, specs in _node_specs().items()}
    assert dynamic == {
        "body_sim": {"wind", "rate_scale", "marker_every", "state_every", "diagnostics_period", "step_count",
                     "log_level", "pause_notice_period"},
        "feedback_brain": {"gain", "noise", "log_level"},
        "recorder": {"log_level"}, "mlp_brain": {"log_level"}, "swg_brain": {"log_level"},
        "task_input": {"log_level"}, "image_streamer": {"log_level"}, "mnist_brain": {"log_level"},
    }


def test_every_read_only_parameter_says_why():
    for node, specs in _node_specs().items():
        P.check_specs(specs)
        for p in specs:
            text = P.describe(p)
            if p.dynamic:
                assert text.endswith("[dynamic: ros2 param set applies it while the node runs]")
            else:
                reason = P.read_only_reason(p)
                assert reason != P.DEFAULT_READ_ONLY_REASON, (node, p.name)  # every one has its own reason
                assert text.endswith(f"[read-only: {reason}]")


def test_apply_changes_validates_and_refuses_as_a_whole():
    specs = (P.Param("rate", 1.0, "r", "float", positive=True, dynamic=True),
             P.Param("wind", [0.0, 0.0], "w", "float_list", size=2, dynamic=True),
             P.Param("mode", "a", "m", "str", choices=("a", "b")))
    values = {"rate": 1.0, "wind": [0.0, 0.0], "mode": "a"}
    seen = []
    changes = [("rate", 2), ("use_sim_time", True)]
    assert P.apply_changes(specs, values, changes, lambda n, v: seen.append((n, v))) == ""
    assert values["rate"] == 2.0 and isinstance(values["rate"], float) and seen == [("rate", 2.0)]
    assert P.apply_changes(specs, values, [("rate", 3.0), ("wind", [1.0])]) == (
        "parameter 'wind' must have 2 values, got 1")
    assert values["rate"] == 2.0  # nothing of a refused set is applied
    assert P.apply_changes(specs, values, [("rate", -1.0)]) == "parameter 'rate' must be > 0, got -1.0"
    assert P.apply_changes(specs, values, [("wind", [float("nan"), 0.0])]).startswith("parameter 'wind' must be finite")
    assert P.apply_changes(specs, values, [("mode", "b")]) == (
        "parameter 'mode' is read-only: the timing loop (lockstep or realtime) is chosen at startup")

    def veto(name, value):
        raise P.ParameterError(f"{name} vetoed")

    assert P.apply_changes(specs, values, [("wind", [0.5, 0.0])], veto) == "wind vetoed"
    assert values["wind"] == [0.0, 0.0] and values["mode"] == "a"


# -- run summary ------------------------------------------------------------------------------------------
def test_body_summary_is_a_few_readable_lines():
    from bptsb_ros.live.summary import summary_text

    summary = {"mode": "lockstep", "dt": 0.01, "sim_time": 1.0, "steps": 100, "jitter_ms_mean": 0.123456,
               "jitter_ms_max": 2.0, "command_age_steps_max": 1.0, "rest_length_accepted": 100,
               "rest_length_rejected_stale": 0, "rest_length_rejected_non_finite": 2, "force_accepted": 0,
               "force_rejected_stale": 0, "wind_accepted": 3, "rejected_total": 2}
    lines = summary_text(summary).splitlines()
    assert len(lines) == 6 and all(len(line) < 120 for line in lines)
    assert lines[0].split() == ["run", "mode=lockstep,", "dt=0.01,", "sim_time=1,", "steps=100,", "rejected_total=2"]
    assert lines[1].split() == ["jitter", "[ms]", "mean=0.1235,", "max=2"]
    assert lines[2].split() == ["command", "age", "[steps]", "max=1"]
    assert lines[3].split() == ["rest-length", "commands", "accepted=100,", "rejected_non_finite=2"]
    assert lines[4].split() == ["force", "commands", "accepted=0,", "rejected=0"]
    assert lines[5].split() == ["wind", "accepted=3"]
    assert {len(line) - len(line.lstrip()) for line in lines} == {2}


# -- list parameters: declared with their array type -------------------------------------------------------
def _declare_in_own_context(specs, ros_args: list[str]):
    """Declare ``specs`` on a plain node of a private rclpy context started with ``ros_args``; returns
    (values, {name: (declared type, value type)})."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node

    ctx = Context()
    rclpy.init(context=ctx, args=["t", "--ros-args", *ros_args])
    try:
        node = Node("list_types", context=ctx)
        try:
            values = declare_parameters(node, specs)
            names = [p.name for p in specs]
            types = {d.name: (d.type, node.get_parameter(d.name).type_.value)
                     for d in node.describe_parameters(names)}
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return values, types


def test_list_parameters_are_declared_with_their_array_type():
    """An empty list default reads back as a string array (``ros2 param get`` said 'Byte values are: []'
    before): every list parameter of every node is declared STRING_ARRAY / DOUBLE_ARRAY, not dynamically
    typed, with or without a value given."""
    from rcl_interfaces.msg import ParameterType as T

    array_type = {"str_list": T.PARAMETER_STRING_ARRAY, "float_list": T.PARAMETER_DOUBLE_ARRAY}
    checked = set()
    for node, (_module, specs) in _all_node_specs().items():
        lists = [p for p in specs if p.kind in array_type]
        values, types = _declare_in_own_context(lists, [])
        for p in lists:
            assert types[p.name] == (array_type[p.kind], array_type[p.kind]), (node, p.name, types[p.name])
            assert values[p.name] == p.default
            checked.add((node, p.name, bool(p.default)))
    assert {("body_sim", "wait_for", False), ("body_sim", "command_publishers", False),
            ("recorder", "topics", False), ("body_sim", "perturb_publishers", True),
            ("body_sim", "wind", True)} <= checked
    # given values keep the type; an empty -p list (which rcl passes on as unset) is an empty string array,
    # also where the default is not empty
    from bptsb_ros.ros.body_sim import PARAMS

    lists = [p for p in PARAMS if p.name in ("wait_for", "perturb_publishers", "command_publishers", "wind")]
    values, types = _declare_in_own_context(lists, ["-p", "wait_for:=[rest_length]", "-p", "perturb_publishers:=[]",
                                                    "-p", "wind:=[0.5, 0.0]"])
    assert values == {"wait_for": ["rest_length"], "perturb_publishers": [], "command_publishers": [],
                      "wind": [0.5, 0.0]}
    assert {t for pair in types.values() for t in pair} == {T.PARAMETER_STRING_ARRAY, T.PARAMETER_DOUBLE_ARRAY}
    # a value of another type is one clear error naming the parameter
    with pytest.raises(P.ParameterError, match=r"^parameter 'wait_for' must be a list of strings"):
        _declare_in_own_context(lists, ["-p", "wait_for:=5"])
    with pytest.raises(P.ParameterError, match=r"^parameter 'wind' must be a list of numbers with a decimal point"):
        _declare_in_own_context(lists, ["-p", "wind:=[1, 0]"])


# -- live parameters on running nodes ---------------------------------------------------------------------
def _set(probe: Probe, node: str, name: str, value):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    client = probe.node.create_client(SetParameters, f"/{node}/set_parameters")
    assert client.wait_for_service(timeout_sec=30)
    future = client.call_async(SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()]))
    assert probe.spin_until(future.done, 30)
    return future.result().results[0]


def _get(probe: Probe, node: str, names: list[str]):
    from rcl_interfaces.srv import DescribeParameters, GetParameters
    from rclpy.parameter import parameter_value_to_python

    get = probe.node.create_client(GetParameters, f"/{node}/get_parameters")
    describe = probe.node.create_client(DescribeParameters, f"/{node}/describe_parameters")
    assert get.wait_for_service(timeout_sec=30) and describe.wait_for_service(timeout_sec=30)
    f1 = get.call_async(GetParameters.Request(names=names))
    f2 = describe.call_async(DescribeParameters.Request(names=names))
    assert probe.spin_until(lambda: f1.done() and f2.done(), 30)
    return ([parameter_value_to_python(v) for v in f1.result().values],
            {d.name: d for d in f2.result().descriptors})


@pytest.mark.slow
def test_live_parameters_on_running_nodes(tmp_path, ros_env, ros_domain_id):
    body_log, brain_log = tmp_path / "body.log", tmp_path / "brain.log"
    body = start_node("body_sim", {**FRESH_BODY, "wait_for": ["rest_length"], "command_timeout": 30.0},
                      ros_env, body_log)
    brain = start_node("swg_brain", {"task": "lissajous"}, ros_env, brain_log)
    probe = Probe(ros_domain_id)
    try:
        ok = _set(probe, "body_sim", "rate_scale", 2.0)
        assert ok.successful, ok.reason
        bad = _set(probe, "body_sim", "rate_scale", -1.0)
        assert not bad.successful and bad.reason == "parameter 'rate_scale' must be > 0, got -1.0"
        wind = _set(probe, "body_sim", "wind", [1e9, 0.0])
        assert not wind.successful and "outside [-" in wind.reason
        assert _set(probe, "body_sim", "wind", [0.5, 0.0]).successful
        ro = _set(probe, "body_sim", "mode", "lockstep")
        assert not ro.successful and "read-only" in ro.reason
        values, described = _get(probe, "body_sim", ["rate_scale", "wind", "mode", "use_sim_time"])
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters

        get = probe.node.create_client(GetParameters, "/body_sim/get_parameters")
        future = get.call_async(GetParameters.Request(names=["wait_for_subscribers", "command_publishers"]))
        assert probe.spin_until(future.done, 30)  # empty lists, read back as string arrays (ros2 param get)
        assert [(v.type, list(v.string_array_value)) for v in future.result().values] == [
            (ParameterType.PARAMETER_STRING_ARRAY, [])] * 2
        assert values == [2.0, [0.5, 0.0], "realtime", False]  # the refused values left the old ones
        assert described["mode"].read_only and not described["rate_scale"].read_only
        reason = "[read-only: the timing loop (lockstep or realtime) is chosen at startup]"
        assert reason in described["mode"].description
        brain_values, _ = _get(probe, "swg_brain", ["use_sim_time"])
        assert brain_values == [True]  # the brain's default, not rclpy's
        assert _set(probe, "swg_brain", "log_level", "debug").successful
        assert not _set(probe, "swg_brain", "log_level", "loud").successful
        out = _wait_for(body_log, "wind set to (0.5, 0) N", body, 20)
        assert "parameter rate_scale set to 2.0" in out and "refused parameter change" in out
    finally:
        probe.close()
        for proc in (brain, body):
            proc.send_signal(signal.SIGINT)
        for proc in (brain, body):
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    assert "use_sim_time" not in brain_log.read_text()  # no warning (nor note) in the documented way of running
    assert body.returncode == 0 and brain.returncode == 0, body_log.read_text()[-2000:]


@pytest.mark.slow
def test_a_brain_publishes_only_once_it_hears_its_inputs(tmp_path, fresh_ros):
    """swg_brain alone has no publisher on its command topic while nothing publishes ``/clock`` (and says why after
    2 s); once a ``/clock`` publisher appears, its own does: the body's startup wait for a publisher on each command
    topic then means the brain's ``/clock`` subscription has matched the body's publisher (a first tick sent before
    that match is lost)."""
    from rosgraph_msgs.msg import Clock

    from bptsb_ros.ros import messages as m

    domain, env = fresh_ros
    log = tmp_path / "brain.log"
    brain = start_node("swg_brain", {"task": "lissajous"}, env, log)
    probe = Probe(domain, "clock_probe")
    try:
        _wait_for(log, "waiting for a publisher on /clock before publishing", brain, 90)
        node = probe.node
        assert probe.spin_until(lambda: node.count_subscribers("/clock") >= 1, 30)  # the probe sees the brain
        assert not probe.spin_until(lambda: node.count_publishers("/brain/rest_length") > 0, 1.0)
        node.create_publisher(Clock, "/clock", m.state_qos(10))
        assert probe.spin_until(lambda: node.count_publishers("/brain/rest_length") == 1, 30)
    finally:
        probe.close()
        brain.send_signal(signal.SIGINT)
        try:
            brain.wait(timeout=30)
        except subprocess.TimeoutExpired:
            brain.kill()
            brain.wait()
    assert brain.returncode == 0, log.read_text()[-2000:]


# -- QoS of command topics ----------------------------------------------------------------------------------
def test_late_joiner_of_a_command_topic_gets_no_backlog(ros_domain_id):
    """A subscriber that joins late with the QoS ``ros2 topic echo`` picks (the durability every publisher offers)
    receives only what is published after it joined."""
    from rclpy.qos import DurabilityPolicy
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros import messages as m

    probe = Probe(ros_domain_id, "qos_probe")
    try:
        pub = probe.node.create_publisher(JointState, "/qos_probe/rest_length", m.command_qos(1000))
        first = []
        probe.node.create_subscription(JointState, "/qos_probe/rest_length", first.append, m.state_qos(1000))
        assert Probe.wait_matched([pub], 20)
        for k in range(50):
            pub.publish(m.joint_state(k, 10_000_000, ["spring_0"], position=[1.0]))
        assert probe.spin_until(lambda: len(first) == 50, 20)
        offered = [info.qos_profile for info in probe.node.get_publishers_info_by_topic("/qos_probe/rest_length")]
        qos = m.state_qos(1000)
        if all(o.durability == DurabilityPolicy.TRANSIENT_LOCAL for o in offered):
            qos.durability = DurabilityPolicy.TRANSIENT_LOCAL  # what `ros2 topic echo` does
        late: list = []
        probe.node.create_subscription(JointState, "/qos_probe/rest_length", late.append, qos)
        end = time.monotonic() + 20
        while pub.get_subscription_count() < 2 and time.monotonic() < end:
            time.sleep(0.01)
        probe.spin_until(lambda: bool(late), 1.0)
        pub.publish(m.joint_state(50, 10_000_000, ["spring_0"], position=[1.0]))
        assert probe.spin_until(lambda: len(first) == 51 and len(late) >= 1, 20)
        probe.spin_until(lambda: False, 0.3)
        assert [msg.header.stamp.nanosec for msg in late] == [500_000_000]  # step 50 only: no stale backlog
    finally:
        probe.close()


@pytest.mark.parametrize("node", ["swg_brain", "feedback_brain", "mlp_brain", "task_input", "image_streamer",
                                  "mnist_brain"])
def test_brains_default_to_sim_time_and_the_params_files_agree(node, repo_root):
    import yaml

    from bptsb_ros.ros.brain_node import USE_SIM_TIME_DEFAULT

    data = yaml.safe_load((repo_root / "config" / f"{node}_params.yaml").read_text())
    assert data["/**"]["ros__parameters"]["use_sim_time"] is USE_SIM_TIME_DEFAULT is True


def test_feedback_gain_and_noise_perturb_the_fitted_layer():
    """``gain`` g and ``noise`` σ of feedback_brain: l·(1 + g·(W·[s + ε, 1])), computed here by hand."""
    import numpy as np
    import torch

    from bptsb_ros.brains.feedback import FeedbackLayer
    from bptsb_ros.live.feedback_loop import perturbed_rest_length

    layer = FeedbackLayer(3, 2, dtype=torch.float64)
    w = np.array([[0.1, -0.2, 0.3, 0.05], [0.0, 0.4, -0.1, -0.02]])
    layer.load_fit(w)
    layer.requires_grad_(False)  # as the node holds it
    base = torch.tensor([1.0, 2.0], dtype=torch.float64)
    s = np.array([0.5, 1.5, -1.0])
    features = torch.from_numpy(s).unsqueeze(0)
    signal = w[:, :3] @ s + w[:, 3]

    def rest(gain, noise, seed=0):
        return perturbed_rest_length(layer, base, features, gain, noise, np.random.default_rng(seed))[0].numpy()

    assert np.allclose(rest(1.0, 0.0), [1.0, 2.0] * (1 + signal), rtol=0, atol=1e-15)
    assert np.allclose(rest(0.5, 0.0), [1.0, 2.0] * (1 + 0.5 * signal), rtol=0, atol=1e-15)
    assert np.allclose(rest(0.0, 0.0), [1.0, 2.0], rtol=0, atol=0)
    eps = 0.3 * np.random.default_rng(7).standard_normal(3)
    noisy = w[:, :3] @ (s + eps) + w[:, 3]
    assert np.allclose(rest(2.0, 0.3, seed=7), [1.0, 2.0] * (1 + 2.0 * noisy), rtol=0, atol=1e-14)
