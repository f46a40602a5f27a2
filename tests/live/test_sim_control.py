"""The simulator services' semantics without DDS (:mod:`bptsb_ros.live.sim_control`): pause, resume, step N and
reset of a :class:`BodyCore` driven by :class:`BodyLoop` through the fake port of ``live_fakes.py``, in both
timing modes. Expected states come from ``MSDN.initial_state``/``MSDN.step`` called directly, expected times from
the schedule written out by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from live_fakes import RESTS, FakePort, agent, core, offline

from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.sim_control import SimControl


def test_calls_answer_and_refuse_with_one_clear_line():
    c = SimControl(clock=lambda: 12.5)
    assert c.call("step", 3) == (False, "refused: step needs a paused body (call pause first); running before the "
                                        "first step")
    assert c.call("pause") == (True, "paused before the first step") and c.holding()
    c.stepped(4)
    assert c.call("pause") == (True, "already paused after step 4")
    assert c.call("step", 0) == (False, "refused: step_count must be >= 1, got 0") and c.holding()
    assert c.call("step", 2) == (True, "stepping 2 step(s) after step 4, then paused again") and not c.holding()
    c.stepped(5)
    assert not c.holding()
    c.stepped(6)
    assert c.holding() and c.steps_left == 0
    assert c.call("resume") == (True, "resumed after step 6") and not c.holding()
    assert c.call("resume") == (True, "not paused (after step 6); running")
    assert not c.take_reset() and c.call("reset")[0] and c.take_reset() and not c.take_reset()
    assert [(k.name, k.step, k.ok) for k in c.calls] == [
        ("step", -1, False), ("pause", -1, True), ("pause", 4, True), ("step", 4, False), ("step", 4, True),
        ("resume", 6, True), ("resume", 6, True), ("reset", 6, True)]
    assert dict(c.calls[4].values()) == {"call": "step", "step": "4", "wall_time": "12.500000", "accepted": "True",
                                         "paused": "True", "steps_left": "2", "callers": "", "untrusted_callers": ""}
    # a call while a node not in control_callers has a client of the service: refused, counted, named in the record
    assert c.call("pause", callers=("/_ros2cli_requester_std_srvs_Trigger", "/evil/x"), untrusted=("/evil/x",)) == (
        False, "refused: ~/pause has client(s) not in control_callers (/evil/x); running after step 6")
    assert not c.paused and c.refused == 1 and not c.calls[-1].ok
    assert dict(c.calls[-1].values())["callers"] == "/_ros2cli_requester_std_srvs_Trigger, /evil/x"
    assert dict(c.calls[-1].values())["untrusted_callers"] == "/evil/x"
    assert c.call("pause", callers=("/_ros2cli_requester_std_srvs_Trigger",))[0] and c.paused
    with pytest.raises(ValueError, match="^unknown control call 'stop': expected one of pause, resume, step, reset$"):
        c.call("stop")


def test_lockstep_paused_body_takes_no_step_even_with_its_command_then_steps_n_and_equals_offline():
    c = core(wait_for=["rest_length"], max_steps=12, command_timeout=0.2, start_paused=True)
    seen = {}

    def brain(port, k):
        if k != 3:  # step 3's command arrives while paused, before /clock t_3 went out
            port.send(0.003, lambda: c.offer_command("rest_length", k, RESTS[k], port.now()))

    port = FakePort(c, brain)
    snap = lambda key: port.send(0, lambda: seen.__setitem__(key, (list(port.clocks), len(port.outputs))))  # noqa: E731
    port.send(0.4, lambda: snap("start"))
    port.send(0.5, lambda: c.control.call("step", 3))
    port.send(0.7, lambda: c.offer_command("rest_length", 3, RESTS[3], port.now()))
    port.send(0.9, lambda: snap("stepped"))
    port.send(1.0, lambda: c.control.call("resume"))
    assert BodyLoop(c, port).run() is False
    assert seen["start"] == ([], 0)  # paused at startup: no /clock, no state, and no brain counted silent
    assert seen["stepped"] == ([0, 1, 2], 3)  # step 3: three steps, then held although step 3's command is there
    assert port.clocks == list(range(13)) and [o.state.step for o in port.outputs] == list(range(13))
    for got, want in zip(port.outputs, offline(RESTS[:13]), strict=True):
        np.testing.assert_array_equal(got.state.r[0].numpy(), want)
    s = c.summary()
    assert s["safe_command_steps"] == 0 and s["rest_length_rejected_stale"] == 0 and s["rest_length_accepted"] == 13
    assert s["control_calls"] == 2 and s["paused"] is False
    calls = [e.control for e in c.events if e.control]
    assert [(k.name, k.step, k.paused, k.steps_left) for k in calls] == [("step", -1, True, 3),
                                                                          ("resume", 2, False, 0)]
    assert not any(e.level == "error" for e in c.events)


def test_status_says_paused():
    c = core(start_paused=True)
    level, message, values = c.status(c.summary())
    assert message.startswith("paused: lockstep: step 0") and ("paused", "True") in values
    c.control.call("resume")
    assert not c.status(c.summary())[1].startswith("paused")


def test_reset_call_puts_the_body_at_rest_at_its_layout_and_time_goes_on():
    c = core(max_steps=8)
    body = agent().body
    state, outs = None, []
    for k in range(7):
        if k == 3:
            c.control.call("reset")
        c.announce(k, 0.0)
        assert c.offer_command("rest_length", k, RESTS[k], 0.0) is None
        outs.append(c.integrate(state, k))
        state = outs[-1].state
    with torch.no_grad():  # released from rest with the rest lengths of step 3, then stepped with the commands
        expect = [body.initial_state(1, rest_length=torch.from_numpy(RESTS[3]))]
        for k in range(4, 7):
            expect.append(body.step(expect[-1], rest_length=torch.from_numpy(RESTS[k])))
    movable = np.asarray(body.topology.positions)[body.movable_index.numpy()]
    np.testing.assert_array_equal(outs[3].state.r[0].numpy(), movable)  # the hand value: the layout, at rest
    np.testing.assert_array_equal(outs[3].state.v[0].numpy(), 0.0)
    assert [o.state.step for o in outs] == list(range(7))  # sim time goes on
    for got, want in zip(outs[3:], expect, strict=True):
        np.testing.assert_array_equal(got.state.r[0].numpy(), want.r[0].numpy())
    assert np.abs(outs[2].state.r[0].numpy() - movable).max() > 0  # it moved before (the reset is visible)
    assert c.summary()["control_calls"] == 1 and not c.control.reset_pending


def test_realtime_pause_shifts_the_schedule_steps_n_at_the_pace_and_is_no_silence():
    c = core(mode="realtime", wait_for=["rest_length"], max_steps=9, command_timeout=0.2)

    def brain(port, k):
        port.send(0.002, lambda: c.offer_command("rest_length", k, RESTS[k], port.now()))

    port = FakePort(c, brain)
    times: list[float] = []
    publish = port.publish
    port.publish = lambda out, views=True: (times.append(port.t), publish(out, views))  # type: ignore[method-assign]
    port.send(0.035, lambda: c.control.call("pause"))  # during the wait for step 3 (due 0.04): held after it
    port.send(0.3, lambda: c.control.call("step", 2))  # held 0.26 s: steps 4, 5 at the pace, then held again
    port.send(0.6, lambda: c.control.call("resume"))  # held 0.28 s more
    BodyLoop(c, port).run()
    shift = [0.0] * 4 + [0.26] * 2 + [0.54] * 4
    assert times == pytest.approx([0.01 + 0.01 * k + shift[k] for k in range(10)], abs=1e-9)
    s = c.summary()
    assert s["deadline_misses"] == 0 and s["jitter_ms_max"] == pytest.approx(0.0, abs=1e-6)
    assert s["safe_command_steps"] == 0 and not any(e.level == "error" for e in c.events)  # 0.5 s held > timeout
    for k, out in enumerate(port.outputs):
        np.testing.assert_array_equal(out.rest.numpy(), RESTS[k])


def test_a_pause_is_announced_repeated_and_bounded_by_pause_timeout():
    c = core(max_steps=5, start_paused=True, pause_timeout=1.0, pause_notice_period=0.3)
    port = FakePort(c)
    assert BodyLoop(c, port).run() is True and c.pause_expired
    warnings = [t for level, t in port.logs if level == "warning"]
    assert warnings[0] == ("paused before the first step: no step is taken until ~/resume or ~/step is called; the "
                           "run ends if it stays paused for 1 s (pause_timeout)")
    assert sum(t.startswith("still paused before the first step, for ") for t in warnings) == 3  # at 0.3, 0.6, 0.9 s
    assert ("error", "paused before the first step for 1 s without ~/resume or ~/step (pause_timeout): ending the "
            "run") in port.logs
    assert port.outputs == [] and c.summary()["pause_expired"] is True
    assert c.end_text(c.summary(), True, None).startswith("stopped: paused for pause_timeout after 0 steps")
    # the other side: without a bound the body waits as long as it takes, and a resume lets it run
    free = core(max_steps=5, start_paused=True, pause_timeout=0.0, pause_notice_period=10.0)
    port = FakePort(free)
    port.send(30.0, lambda: free.control.call("resume"))
    assert BodyLoop(free, port).run() is False and not free.pause_expired and len(port.outputs) == 6
    assert port.logs[0][1].endswith("(no pause_timeout: it waits as long as it takes)")
    assert sum("still paused" in t for _, t in port.logs) == 2  # at 10 and 20 s
