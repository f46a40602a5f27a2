"""The lockstep speed work without DDS: the per-step phase split behind ``bptsb bench --live`` (planted timings on a
fake clock), the pre-serialized body outputs (their bytes deserialize to the message objects they replace, bit for
bit; the recorder reads their stamps), the recorder's batched rounds, and the bench's table and parameter filter."""

from __future__ import annotations

import numpy as np
import pytest
from live_fakes import BASE, FakePort, agent, core

from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.phases import PHASES, StepPhases, row_from_summary, split

DT_NS = 10_000_000


# -- the split ---------------------------------------------------------------------------------------------------
def test_split_of_planted_totals():
    row = split(4, 0.02, {"recorder": 0.004, "publish": 0.002, "commands": 0.008, "compute": 0.004})
    assert row["steps_per_s"] == pytest.approx(200.0)
    assert row["recorder_ms"] == pytest.approx(1.0) and row["publish_ms"] == pytest.approx(0.5)
    assert row["commands_ms"] == pytest.approx(2.0) and row["compute_ms"] == pytest.approx(1.0)
    assert row["other_ms"] == pytest.approx(0.5)  # (20 ms - 18 ms) / 4 steps
    for steps, wall in ((0, 1.0), (3, 0.0)):
        with pytest.raises(ValueError, match="steps > 0 and a positive wall time"):
            split(steps, wall, {})


def test_phases_summary_and_bench_row():
    ph = StepPhases()
    assert ph.summary() == {} and ph.wall == 0.0
    ph.add("commands", 0.003)
    ph.add("publish", 0.001)
    ph.step_done(10.0, 10.005)
    ph.step_done(10.005, 10.010)
    s = ph.summary()
    assert s["loop_steps"] == 2 and s["loop_wall_s"] == pytest.approx(0.010) and s["loop_steps_per_s"] == pytest.approx(
        200.0)
    assert s["phase_ms_commands"] == pytest.approx(1.5) and s["phase_ms_publish"] == pytest.approx(0.5)
    assert s["phase_ms_other"] == pytest.approx(3.0)  # 10 ms - 4 ms over 2 steps
    row = row_from_summary(s)
    assert row["steps"] == 2 and row["commands_ms"] == pytest.approx(1.5) and row["steps_per_s"] == pytest.approx(200)
    with pytest.raises(KeyError, match="no phase timing.*loop_steps"):
        row_from_summary({"steps": 3})


def test_lockstep_loop_splits_each_step_into_its_phases():
    """Planted: the brain answers 3 ms after /clock, publishing /clock takes 0.5 ms and the step's state 2 ms,
    the recorder acknowledges step k 6 ms after /clock t_k and the body may run 1 step ahead; integrating takes no
    time on the fake clock. Step k ≥ 1 then waits 6 - 5 = 1 ms for the acknowledgement of step k - 1."""
    c = core(wait_for=["rest_length"], max_steps=9, command_timeout=1.0, wait_for_recorder=True, recorder_window=1,
             qos_depth=10)

    def brain(port, k):
        port.send(0.003, lambda: c.offer_command("rest_length", k, BASE, port.now()))
        port.send(0.006, lambda: c.recorder_ack(k, []))

    class SlowClock(FakePort):  # publishing /clock takes 0.5 ms (after the brain got it): publish, not commands
        def announce(self, step):
            super().announce(step)
            self.t += 0.0005

    port = SlowClock(c, brain, cost=0.002)
    assert BodyLoop(c, port).run() is False
    s = c.summary()
    assert s["loop_steps"] == 10 and s["loop_wall_s"] == pytest.approx(10 * 0.005 + 9 * 0.001)
    assert s["loop_steps_per_s"] == pytest.approx(10 / 0.059)
    assert s["phase_ms_commands"] == pytest.approx(2.5) and s["phase_ms_publish"] == pytest.approx(2.5)
    assert s["phase_ms_recorder"] == pytest.approx(0.9) and s["phase_ms_compute"] == pytest.approx(0.0)
    assert s["phase_ms_other"] == pytest.approx(0.0, abs=1e-9)
    assert set(PHASES) == {"recorder", "publish", "commands", "compute"}


# -- pre-serialized outputs ----------------------------------------------------------------------------------------
rclpy_serialization = pytest.importorskip("rclpy.serialization")


def _template(build, shapes):
    from bptsb_ros.ros.raw_out import RawTemplate

    return RawTemplate(build, shapes, rclpy_serialization.deserialize_message, DT_NS)


def _outputs():
    """The builders body_sim templates, for the lissajous body (25 masses, 48 springs, 13 movable)."""
    from bptsb_ros.interface.topics import mass_dof_names, spring_names
    from bptsb_ros.ros import messages as m

    body = agent().body
    n, e = body.topology.n_masses, body.topology.n_springs
    dof, springs = mass_dof_names(body.movable_index.tolist()), spring_names(e)
    colors = m.mass_colors(np.asarray(body.topology.fixed), body.topology.cmp_index)
    return {
        "clock": (lambda k: m.clock_msg(k, DT_NS), []),
        "positions": (lambda k, r: m.pose_array(k, DT_NS, r, "msdn"), [(n, 2)]),
        "mass_states": (lambda k, r, v, f: m.joint_state(k, DT_NS, dof, position=r, velocity=v, effort=f,
                                                         frame_id="msdn"), [(len(dof),)] * 3),
        "spring_lengths": (lambda k, x: m.joint_state(k, DT_NS, springs, position=x), [(e,)]),
        "external_force": (lambda k, f: m.joint_state(k, DT_NS, dof, effort=f, frame_id="msdn"), [(len(dof),)]),
        "force_cmd": (lambda k, f: m.joint_state(k, DT_NS, dof, effort=f), [(len(dof),)]),  # mlp_brain
        "task_input": (lambda k, u: m.joint_state(k, DT_NS, ["u0"], position=u), [(1,)]),  # task_input
        "markers": (lambda k, r, ends, rgba: m.markers_of(k, DT_NS, r, ends, rgba, colors, "msdn", 0.04),
                    [(n, 2), (2 * e, 2), ((2 * e, 4), "float32")]),
    }


@pytest.mark.ros
@pytest.mark.parametrize("key", ["clock", "positions", "mass_states", "spring_lengths", "external_force", "force_cmd",
                                 "task_input", "markers"])
def test_template_bytes_are_the_message_objects(key):
    """Both sides: what body_sim publishes from a template deserializes to the message it replaces (float64 values
    bit for bit), and the recorder's acknowledgement reads the step's stamp from those bytes."""
    from bptsb_ros.bags.recording import cdr_stamp_ns

    build, shapes = _outputs()[key]
    raw = _template(build, shapes)
    rng = np.random.default_rng(3)
    for step in (0, 1, 417, 123_456):
        arrays = [rng.uniform(-2, 2, s if isinstance(s[0], int) else s[0]) for s in shapes]
        data = raw.render(step, *arrays)
        want = build(step, *[a.astype(np.float32) if not isinstance(s[0], int) else a
                             for a, s in zip(arrays, shapes, strict=True)])
        got = rclpy_serialization.deserialize_message(data, type(want))
        assert got == rclpy_serialization.deserialize_message(rclpy_serialization.serialize_message(want), type(want))
        if key != "markers":  # no float32 field: the message objects themselves
            assert got == want
        if key == "markers":  # not acknowledged (not every step); each marker carries the stamp
            assert [(mk.header.stamp.sec, mk.header.stamp.nanosec) for mk in got.markers] == [
                divmod(step * DT_NS, 1_000_000_000)] * 2
        else:
            assert cdr_stamp_ns(data) == step * DT_NS
        if key == "mass_states":
            np.testing.assert_array_equal(np.frombuffer(got.velocity, dtype=np.float64), arrays[1])
        if key == "positions":
            xy = np.array([(p.position.x, p.position.y) for p in got.poses])
            np.testing.assert_array_equal(xy, arrays[0])


@pytest.mark.ros
def test_a_builder_that_changes_its_values_cannot_be_templated():
    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.raw_out import TemplateError

    with pytest.raises(TemplateError, match="not found in the bytes"):
        _template(lambda k, x: m.joint_state(k, DT_NS, ["a", "b"], position=2.0 * x), [(2,)])
    with pytest.raises(TemplateError, match="no stamp"):
        _template(lambda k, x: m.joint_state(0, DT_NS, ["a", "b"], position=x), [(2,)])


@pytest.mark.ros
def test_template_bytes_are_exact_cdr_that_a_strict_reader_accepts():
    """Every render is the whole message and nothing more: ``rosbags``' strict deserializer (which refuses more than
    3 bytes after the content) reads it with the values, and it has the length of rosbags' own serialization. rclpy's
    ``serialize_message`` leaves bytes after a ``JointState`` with empty arrays, which that reader refuses."""
    from rosbags.typesys import Stores, get_typestore

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.raw_out import ros_type_name

    store = get_typestore(Stores.ROS2_JAZZY)
    probe = m.joint_state(5, DT_NS, ["a", "b", "c"], position=np.arange(3.0))
    with pytest.raises(Exception, match="size mismatch"):  # the bytes the templates were made of before
        store.deserialize_cdr(rclpy_serialization.serialize_message(probe), "sensor_msgs/msg/JointState")
    rng = np.random.default_rng(11)
    for key, (build, shapes) in _outputs().items():
        raw = _template(build, shapes)
        arrays = [rng.uniform(-2, 2, s if isinstance(s[0], int) else s[0]) for s in shapes]
        data = raw.render(417, *arrays)
        want = build(417, *[a.astype(np.float32) if not isinstance(s[0], int) else a
                            for a, s in zip(arrays, shapes, strict=True)])
        got = store.deserialize_cdr(data, ros_type_name(want))
        assert len(store.serialize_cdr(got, ros_type_name(want))) == len(data), key
        if key in ("spring_lengths", "external_force", "force_cmd", "task_input"):
            field = "effort" if key in ("external_force", "force_cmd") else "position"
            np.testing.assert_array_equal(getattr(got, field), arrays[0])
            assert len(got.velocity) == 0 and (got.header.stamp.sec, got.header.stamp.nanosec) == (4, 170_000_000)


@pytest.mark.ros
def test_command_messages_of_every_size_are_templated():
    """Every ``JointState`` of 1–120 values templates, one after another in one process (while a sentinel had to
    occur once, a stale copy in the buffer's unfilled tail refused 17 of these sizes in one run, which ones varying
    with the process's memory; a lissajous launch once lost its 48-spring ``rest_length`` template to it)."""
    from bptsb_ros.ros import messages as m

    rng = np.random.default_rng(0)
    for n in range(1, 121):
        names = [f"spring_{e}" for e in range(n)]
        raw = _template(lambda k, x, names=names: m.joint_state(k, DT_NS, names, position=x), [(n,)])
        values = rng.standard_normal(n)
        got = rclpy_serialization.deserialize_message(raw.render(n, values), type(m.joint_state(0, DT_NS, [])))
        np.testing.assert_array_equal(np.asarray(got.position), values)


@pytest.mark.ros
def test_markers_by_hand():
    """``body_markers`` (now from arrays): mass points at the positions, line points at both ends of every spring,
    line colours the scalar strain colour of their spring, twice."""
    from bptsb_ros.ros import messages as m

    pos = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    springs = np.array([[0, 1], [1, 2]])
    strain = np.array([0.3, -0.05])
    msg = m.body_markers(7, DT_NS, pos, springs, np.array([True, False, False]), 2, strain, "msdn", 0.1)
    masses, lines = msg.markers
    assert [(p.x, p.y) for p in masses.points] == [(0.0, 0.0), (1.0, 0.0), (0.0, 2.0)]
    assert [(p.x, p.y) for p in lines.points] == [(0.0, 0.0), (1.0, 0.0), (1.0, 0.0), (0.0, 2.0)]
    assert masses.colors == [m._FIXED, m._MOVABLE, m._CMP]
    assert lines.colors == [m._strain_color(0.3)] * 2 + [m._strain_color(-0.05)] * 2
    s = np.linspace(-0.4, 0.4, 41)
    want = [m._strain_color(float(v)) for v in s]
    got = m.strain_colors(s)
    assert [(c.r, c.g, c.b, c.a) for c in want] == [tuple(row) for row in got.tolist()]


# -- the recorder's rounds -----------------------------------------------------------------------------------------
class FakeSpin:
    """Messages arriving at planted times; ``spin_once`` handles at most one ready message (waiting up to its
    timeout for the next), and each handled message costs ``cost`` seconds."""

    def __init__(self, arrivals, cost=0.0):
        self.arrivals, self.cost, self.t, self.taken, self.sleeps = sorted(arrivals), cost, 0.0, 0, []

    def spin_once(self, timeout):
        if self.arrivals and self.arrivals[0] <= self.t + timeout:
            self.t = max(self.t, self.arrivals.pop(0)) + self.cost
            self.taken += 1
        else:
            self.t += timeout

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.t += seconds


def _round(spin, batch_wait, timeout=0.05):
    from bptsb_ros.bags.recording import take_round

    return take_round(spin.spin_once, lambda: spin.taken, lambda: spin.t, spin.sleep, batch_wait, timeout)


def test_a_round_takes_everything_ready_then_sleeps_out_batch_wait():
    spin = FakeSpin([0.0, 0.0, 0.0, 0.0005, 0.0015], cost=0.0001)
    # round 1 from t = 0: the three messages ready at 0 (handled by 0.3 ms); the fourth, due at 0.5 ms, is not ready
    # for a zero-timeout spin then; sleeps out the rest of 2 ms
    assert _round(spin, 0.002) == 3 and spin.sleeps == [pytest.approx(0.0017)]
    # round 2 from t = 2 ms: both waiting messages (due at 0.5 and 1.5 ms), done at 2.2 ms, sleeps 1.8 ms
    assert _round(spin, 0.002) == 2 and spin.sleeps[1] == pytest.approx(0.0018) and spin.taken == 5


def test_rounds_lose_nothing_and_wake_once_per_batch():
    arrivals = [k * 0.0002 for k in range(50)]  # 5,000 messages/s for 10 ms
    spin = FakeSpin(arrivals, cost=0.00001)
    rounds = []
    while spin.arrivals:
        rounds.append(_round(spin, 0.002))
    assert sum(rounds) == 50 and spin.taken == 50
    assert len(rounds) <= 7  # about one round per 2 ms, not one per message
    unbatched = FakeSpin(arrivals, cost=0.00001)
    n = 0
    while unbatched.arrivals:
        _round(unbatched, 0.0)
        n += 1
    assert unbatched.taken == 50 and unbatched.sleeps == [] and n > 20


def test_a_round_takes_the_recorded_topics_at_once_after_its_wait():
    """``take_ready`` (the recorder's direct takes) runs once per round, after a wait that brought something, and
    what it takes counts; a wait that timed out with nothing runs no takes."""
    from bptsb_ros.bags.recording import take_round

    spin = FakeSpin([0.001], cost=0.0)
    calls = []

    def take_ready():
        calls.append(spin.t)
        spin.taken += 3  # three messages waiting on other topics, taken without a spin each

    assert take_round(spin.spin_once, lambda: spin.taken, lambda: spin.t, spin.sleep, 0.02, 0.05, take_ready) == 4
    assert calls == [0.001] and spin.sleeps == [pytest.approx(0.019)]
    assert take_round(spin.spin_once, lambda: spin.taken, lambda: spin.t, spin.sleep, 0.02, 0.05, take_ready) == 0
    assert len(calls) == 1


def test_a_wait_ended_by_something_else_still_makes_a_round():
    """The sim-time /clock subscription (not a recorded message) ends the wait early: the round still sleeps out
    batch_wait, so such wake-ups cannot make one round per step."""
    spin = FakeSpin([])

    def clock_tick(timeout):  # handles a callback that is no recorded message, 1 ms into the wait
        spin.t += 0.001

    from bptsb_ros.bags.recording import take_round

    assert take_round(clock_tick, lambda: 0, lambda: spin.t, spin.sleep, 0.02, 0.05) == 0
    assert spin.sleeps == [pytest.approx(0.018)]  # the wait and one zero-timeout spin took 1 ms each


def test_no_sleep_after_an_empty_round_or_a_long_one():
    idle = FakeSpin([])
    assert _round(idle, 0.002, timeout=0.05) == 0 and idle.sleeps == [] and idle.t == pytest.approx(0.05)
    slow = FakeSpin([0.0, 0.0, 0.0], cost=0.001)  # 3 ms of work > batch_wait
    assert _round(slow, 0.002) == 3 and slow.sleeps == []


# -- the bench's plumbing ------------------------------------------------------------------------------------------
def test_bench_params_go_to_the_loops_that_have_the_node_and_the_table():
    from bptsb_ros.bench.live import launch_argv, live_table, loop_params

    params = ("body_sim:executor:=single", "feedback_brain:gain:=0.5", "mlp_brain:executor:=single")
    assert loop_params("narma", params) == ("body_sim:executor:=single", "mlp_brain:executor:=single")
    assert loop_params("lissajous_closed", params) == ("body_sim:executor:=single", "feedback_brain:gain:=0.5")
    argv = launch_argv("narma", "b", 2.0, params=params)
    assert argv[argv.index("launch") + 1] == "narma" and "feedback_brain:gain:=0.5" not in argv
    assert argv.count("--param") == 2 and "--agent" not in argv and argv[argv.index("--duration") + 1] == "2"
    assert "--composed" not in argv and "--composed" in launch_argv("narma", "b", 2.0, composed=True)
    assert "--recorder-in-body" not in argv
    assert "--recorder-in-body" in launch_argv("narma", "b", 2.0, recorder_in_body=True)
    run = {"loop": "narma", "steps": 1001, "steps_per_s": 250.4, "recorder_ms": 0.0, "publish_ms": 1.25,
           "commands_ms": 2.5, "compute_ms": 0.25, "other_ms": 0.0, "dropped_messages": 0, "launch_exit_code": 0,
           "ratio_to_anchor": 0.5, "cpu_us_per_step": {"body_sim": 120.4, "recorder": 80.0}}
    anchor = {"shape": "split", "round_trips_per_s": 500.8, "rtt_p50_ms": 0.25}
    table = live_table({"runs": [run, {"loop": "lissajous_closed", "error": "no summary"}],
                        "anchors": [anchor, {"shape": "split", "error": "no match"}]}).splitlines()
    assert table[0].startswith("| loop | steps | steps/s | × anchor | recorder ms | publish ms | commands ms |")
    assert table[2] == ("| narma | 1001 | 250 | 0.50 | 0.000 | 1.250 | 2.500 | 0.250 | 0.000 | "
                        "body_sim 120, recorder 80 | 0 | 0 |")
    assert table[3].startswith("| lissajous_closed | no summary |")
    hosted = live_table({"runs": [{**run, "composed": False, "recorder_in_body": True}], "anchors": []})
    assert hosted.splitlines()[2].startswith("| narma (split, recorder in body) | 1001 |")
    assert table[-2:] == ["anchor (split): 501 round trips/s, p50 0.250 ms", "anchor (split): no match"]


def test_each_loop_run_is_compared_with_the_anchor_runs_of_its_shape_around_it():
    from bptsb_ros.bench.live import with_ratios

    seq = [{"kind": "anchor", "shape": "split", "round_trips_per_s": 1000.0},
           {"kind": "loop", "loop": "a", "steps_per_s": 300.0},
           {"kind": "anchor", "shape": "split", "round_trips_per_s": 2000.0},
           {"kind": "anchor", "shape": "composed", "round_trips_per_s": 4000.0},
           {"kind": "loop", "loop": "a", "composed": True, "steps_per_s": 1000.0},
           {"kind": "loop", "loop": "b", "steps_per_s": 100.0},
           {"kind": "loop", "loop": "b", "recorder_in_body": True, "steps_per_s": 150.0},
           {"kind": "anchor", "shape": "split", "error": "failed"},
           {"kind": "loop", "loop": "c", "error": "no summary"}]
    report = with_ratios({"sequence": seq})
    assert seq[1]["ratio_to_anchor"] == 0.2 and seq[1]["anchor_round_trips_per_s"] == 1500.0  # 300 / mean(1000, 2000)
    assert seq[4]["ratio_to_anchor"] == 0.25  # only the composed anchor before it
    assert seq[5]["ratio_to_anchor"] == 0.05  # the split one before it; the failed one after it does not count
    assert seq[6]["ratio_to_anchor"] == 0.075  # the recorder in the body's process: still beside the split anchor
    assert "ratio_to_anchor" not in seq[8]
    assert report["ratios"] == {"a (split)": [0.2], "a (composed)": [0.25], "b (split)": [0.05],
                                "b (split, recorder in body)": [0.075]}


def test_composed_runs_sit_between_composed_anchors(tmp_path, monkeypatch):
    from bptsb_ros.bench import live

    monkeypatch.setattr(live, "anchor_run", lambda shape, seconds, progress: {"shape": shape,
                                                                             "round_trips_per_s": 1000.0})
    monkeypatch.setattr(live, "live_run", lambda loop, *a, composed=False, recorder_in_body=False, **k: {
        "loop": loop, "composed": composed, "recorder_in_body": recorder_in_body, "steps_per_s": 100.0})
    report = live.run_live(("narma",), 1.0, 1, tmp_path, progress=lambda m: None, composed=True,
                           recorder_in_body=True)
    order = [(i["kind"], i.get("shape") or live.shape_label(i["composed"], i["recorder_in_body"]))
             for i in report["sequence"]]
    assert order == [("anchor", "split"), ("loop", "split"), ("anchor", "split"),
                     ("loop", "split, recorder in body"), ("anchor", "split"), ("anchor", "composed"),
                     ("loop", "composed"), ("anchor", "composed"), ("anchor", "composed"),
                     ("loop", "composed, recorder in body"), ("anchor", "composed")]
    assert report["ratios"] == {"narma (split)": [0.1], "narma (split, recorder in body)": [0.1],
                                "narma (composed)": [0.1], "narma (composed, recorder in body)": [0.1]}
    plain = live.run_live(("narma",), 1.0, 1, tmp_path, progress=lambda m: None)
    assert [i["kind"] for i in plain["sequence"]] == ["anchor", "loop", "anchor"]


def test_the_cpu_sampler_reads_each_node_inside_the_window():
    from bptsb_ros.bench.live import CpuSampler

    sampler = CpuSampler.__new__(CpuSampler)  # no thread: planted samples (monotonic s, CPU s)
    sampler.samples = {"body_sim": [(10.0, 1.0), (11.0, 1.5), (12.0, 2.5)], "late": [(11.5, 0.0), (13.0, 1.0)]}
    cpu = sampler.cpu_in(10.5, 11.5)
    assert cpu == {"body_sim": pytest.approx(0.75)}  # 1.25 → 2.0 by linear interpolation; "late" began inside


@pytest.mark.parametrize("args, message", [
    (["--live-loops", "narma,bogus"], "unknown loop(s) bogus"),
    (["--live-loops", "mnist_drawing"], "mnist_drawing needs an MNIST system"),
    (["--live-seconds", "0"], "--live-seconds must be > 0"),
    (["--live-repeats", "0"], "--live-repeats must be >= 1"),
])
def test_bench_live_refuses_bad_arguments(tmp_path, capsys, args, message):
    from bptsb_ros.cli import main

    assert main(["bench", "--live", "--out", str(tmp_path / "b.json"), *args]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()
