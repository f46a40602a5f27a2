"""The live body's rules without DDS (:mod:`bptsb_ros.live`): a :class:`BodyCore` fed plain values, driven by
:class:`BodyLoop` through a fake port with a fake clock, in both timing modes.

Each rule is checked on both sides of its boundary, with expected values from the rule's statement or from an
independent few lines: the applied states are compared with ``MSDN.initial_state``/``MSDN.step`` called directly
with the commands the test sent; a reset state with layout + displacement; a perturbed state with r + d and
``MSDN.acceleration`` at the commanded rest lengths."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from live_fakes import BASE, RESTS, E, FakePort, agent, core, offline

from bptsb_ros.body.msdn import SimulationDiverged
from bptsb_ros.interface.params import ParameterError
from bptsb_ros.live.body_core import BodyCore
from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.body_params import MAX_PENDING_PERTURBATIONS
from bptsb_ros.live.summary import write_summary


def reasons(c: BodyCore, source: str) -> dict[str, int]:
    counts = c.channels[source].counts() if source != "perturbation" else c.perturbations.counts()
    return {k[len("rejected_"):]: v for k, v in counts.items() if k.startswith("rejected_") and v}


M2 = 2 * agent().body.n_movable


def test_planted_sizes():
    assert (E, M2) == (48, 26)  # 4 x 4 grid body of the lissajous task: its springs, its movable coordinates


# -- commands: the channel rules, both sides --------------------------------------------------------------------
def test_length_names_and_finiteness():
    c = core(wait_for=["rest_length"])
    assert c.offer_command("rest_length", 0, BASE[:-1], 0.0).reason == "wrong_length"
    assert c.offer_command("rest_length", 0, np.append(BASE, 1.0), 0.0).reason == "wrong_length"
    assert c.offer_command("rest_length", 0, BASE, 0.0, names=["x"] * E).reason == "wrong_names"
    for bad in (np.nan, np.inf, -np.inf):
        v = BASE.copy()
        v[3] = bad
        rej = c.offer_command("rest_length", 0, v, 0.0)
        assert rej.reason == "non_finite" and "index 3" in rej.message
    assert c.offer_command("force", 0, np.zeros(M2 + 2), 0.0).reason == "wrong_length"
    assert c.offer_command("rest_length", 0, BASE, 0.0, names=c.spring_names) is None  # the good one after all
    assert reasons(c, "rest_length") == {"wrong_length": 2, "wrong_names": 1, "non_finite": 3}
    assert c.channels["rest_length"].accepted == 1
    warnings = [e.text for e in c.events if e.level == "warning"]
    assert "rejected rest_length command for step 0: 47 values, expected 48; not integrated" in warnings


def test_every_stamped_source_checks_length_finiteness_and_names():
    c = core(reset_every=1)
    for source, size in (("force", M2), ("wind", 2), ("reset", M2)):
        good = np.zeros(size)
        assert c.offer_command(source, 0, good[:-1], 0.0).reason == "wrong_length"
        assert c.offer_command(source, 0, np.full(size, np.nan), 0.0).reason == "non_finite"
        assert c.offer_command(source, 0, good, 0.0, names=[f"q{i}" for i in range(size)]).reason == "wrong_names"
        assert c.offer_command(source, 0, good, 0.0) is None, source
        assert reasons(c, source) == {"wrong_length": 1, "non_finite": 1, "wrong_names": 1}, source
    assert c.summary()["rejected_total"] == 9


def test_rest_length_and_force_bounds_both_sides():
    c = core(max_rest_length=2.0, max_force=5.0)
    cases = [("rest_length", np.full(E, 2.0), None), ("rest_length", np.full(E, 2.0 + 1e-12), "out_of_bounds"),
             ("rest_length", np.full(E, 1e-12), None), ("rest_length", np.zeros(E), "out_of_bounds"),
             ("rest_length", -BASE, "out_of_bounds"),
             ("force", np.full(M2, 5.0), None), ("force", np.full(M2, -5.0), None),
             ("force", np.full(M2, 5.0 + 1e-9), "out_of_bounds"), ("force", np.full(M2, -5.0 - 1e-9), "out_of_bounds")]
    for step, (source, values, expected) in enumerate(cases):
        c.next_step = step
        rej = c.offer_command(source, step, values, 0.0)
        assert (rej and rej.reason) == expected, (source, values[0])


def test_default_max_rest_length_is_ten_times_the_layout_diagonal():
    c = core()  # the 4 m x 4 m layout: 10 * 4 * sqrt(2) m
    limit = 40.0 * np.sqrt(2.0)
    assert c.offer_command("rest_length", 0, np.full(E, limit * (1 - 1e-12)), 0.0) is None
    assert c.offer_command("rest_length", 1, np.full(E, limit * (1 + 1e-12)), 0.0).reason == "out_of_bounds"


def test_lockstep_stale_duplicate_and_ahead_both_sides():
    c = core()
    c.announce(5, 0.0)
    assert c.offer_command("rest_length", 4, BASE, 0.0).reason == "stale"  # step 4 was integrated
    assert c.offer_command("rest_length", 5, BASE, 0.0) is None
    assert c.offer_command("rest_length", 5, BASE, 0.0).reason == "duplicate"
    assert c.offer_command("rest_length", 6, BASE, 0.0) is None  # one step ahead of the next: allowed
    assert c.offer_command("rest_length", 7, BASE, 0.0).reason == "too_far_ahead"
    assert reasons(c, "rest_length") == {"stale": 1, "duplicate": 1, "too_far_ahead": 1}


def test_realtime_newest_and_age_both_sides():
    c = core(mode="realtime", max_command_age=0.05)  # 5 steps of 10 ms
    c.announce(10, 0.0)
    assert c.offer_command("rest_length", 4, BASE, 0.0).reason == "stale"  # 6 steps old
    assert c.offer_command("rest_length", 5, BASE, 0.0) is None  # 5 steps old: the oldest usable
    assert c.offer_command("rest_length", 5, BASE, 0.0).reason == "stale"  # not newer than the newest
    assert c.offer_command("rest_length", 6, 2 * BASE, 0.0) is None
    assert c.channels["rest_length"].take(11).values.tolist() == (2 * BASE).tolist()  # the newest, 5 steps old
    assert c.channels["rest_length"].take(12) is None  # 6 steps old when used


def test_untrusted_publisher_rejects_everything_on_the_topic():
    c = core()
    rej = c.offer_command("rest_length", 0, BASE, 0.0, untrusted=["/intruder"], topic="/brain/rest_length")
    assert rej.reason == "untrusted_publisher"
    assert "/brain/rest_length also has publisher(s) not in command_publishers (/intruder)" in rej.message
    assert c.offer_command("rest_length", 0, BASE, 0.0, untrusted=[]) is None  # the same command once it left
    assert c.offer_perturbation(3, np.zeros(M2), 0.0, untrusted=["/x"]).reason == "untrusted_publisher"
    assert c.publisher_rules["rest_length"].allowed == ("swg_brain", "feedback_brain")
    assert c.publisher_rules["force"].untrusted([("/", "mlp_brain"), ("/", "evil")]) == ["/evil"]


def test_wind_messages_are_checked_and_hold_from_the_next_step():
    c = core(max_wind=10.0)
    assert "NaN/inf" in c.offer_wind([np.nan, 0.0])
    assert "outside [-10, 10] N" in c.offer_wind([10.0 + 1e-9, 0.0])
    assert c.offer_wind([10.0, -10.0]) is None
    assert c.summary()["wind_rejected_non_finite"] == 1 and c.summary()["wind_rejected_out_of_bounds"] == 1
    # an unsynchronised wind follows the wind topic's publisher rule too (command_publishers: wind_source only)
    assert "env/wind has publisher(s) not in command_publishers (/intruder)" in c.offer_wind([1.0, 0.0], ["/intruder"])
    assert c.summary()["wind_rejected_untrusted_publisher"] == 1
    out = c.integrate(None, 0)
    np.testing.assert_array_equal(out.force.numpy(), np.tile([10.0, -10.0], (M2 // 2, 1)))
    with pytest.raises(ParameterError, match="parameter 'wind'"):
        c.on_parameter("wind", [11.0, 0.0])
    c.on_parameter("wind", [0.0, 0.0])
    assert c.integrate(out.state, 1).force is None
    with pytest.raises(ParameterError, match="parameter 'wind': value 20"):
        core(max_wind=10.0, wind=[20.0, 0.0])


# -- perturbations ----------------------------------------------------------------------------------------------
def test_perturbation_queue_schedule_and_staleness_both_sides():
    c = core(max_steps=50)
    d = np.zeros(M2)
    assert c.offer_perturbation(50, d, 0.0) is None  # the run's last step
    assert c.offer_perturbation(51, d, 0.0).reason == "too_far_ahead"
    assert c.offer_perturbation(4, d[:-1], 0.0).reason == "wrong_length"
    assert c.offer_perturbation(4, np.full(M2, np.nan), 0.0).reason == "non_finite"
    assert c.offer_perturbation(4, np.full(M2, 4 * np.sqrt(2) + 1e-9), 0.0).reason == "out_of_bounds"
    c.announce(3, 0.0)
    assert c.offer_perturbation(2, d, 0.0).reason == "stale"
    assert c.offer_perturbation(3, d, 0.0) is None
    free = core()  # no end: the queue is the limit
    for k in range(MAX_PENDING_PERTURBATIONS):
        assert free.offer_perturbation(k + 1, d, 0.0) is None
    assert free.offer_perturbation(MAX_PENDING_PERTURBATIONS + 1, d, 0.0).reason == "queue_full"
    assert free.summary()["perturbation_pending"] == MAX_PENDING_PERTURBATIONS


def test_perturbation_displaces_its_step_only_with_the_commanded_rest_lengths():
    c = core(wait_for=["rest_length"])
    body = agent().body
    disp = 0.01 * np.arange(M2) / M2
    rest = [BASE * (1 + 0.01 * k) for k in range(3)]
    c.offer_perturbation(1, disp, 0.0)
    state = None
    for k in range(3):
        c.announce(k, 0.0)
        assert c.offer_command("rest_length", k, rest[k], 0.0) is None
        out = c.integrate(state, k)
        assert (out.perturbation is not None) == (k == 1)
        if k == 1:  # expected: r + d, v kept, a from the commanded rest lengths (not the trained ones)
            with torch.no_grad():
                plain = body.step(state, rest_length=torch.from_numpy(rest[1]))
                r = plain.r + torch.from_numpy(disp).view(1, -1, 2)
                a, length = body.acceleration(r, plain.v, torch.from_numpy(rest[1]).view(1, -1), None)
            np.testing.assert_array_equal(out.state.r.numpy(), r.numpy())
            np.testing.assert_array_equal(out.state.v.numpy(), plain.v.numpy())
            np.testing.assert_allclose(out.state.a.numpy(), a.numpy(), rtol=1e-12, atol=1e-12)
        state = out.state
    s = c.summary()
    assert s["perturbation_applied"] == 1 and s["perturbation_steps"] == [1] and s["perturbation_pending"] == 0


# -- resets ------------------------------------------------------------------------------------------------------
def test_reset_schedule_bounds_and_state_at_step_k():
    c = core(reset_every=10, wait_for=["reset"], max_steps=20)
    body = agent().body
    good = np.linspace(-0.2, 0.2, M2)
    assert c.offer_command("reset", 1, good, 0.0).reason == "off_schedule"
    assert c.offer_command("reset", 0, np.full(M2, 100.0), 0.0).reason == "out_of_bounds"  # 141 m from rest
    assert c.offer_command("reset", 0, good, 0.0) is None
    state = c.integrate(None, 0).state
    layout = body.positions0[body.movable_index].numpy()
    np.testing.assert_array_equal(state.r[0].numpy(), layout + good.reshape(-1, 2))
    np.testing.assert_array_equal(state.v.numpy(), 0.0)
    for k in range(1, 10):
        assert c.missing(k) == []  # no reset is awaited between reset steps
        c.announce(k, 0.0)
        state = c.integrate(state, k).state
    c.announce(10, 0.0)
    assert c.missing(10) == ["reset"]
    later = np.linspace(0.15, -0.1, M2)
    assert c.offer_command("reset", 10, later, 0.0) is None and c.missing(10) == []
    np.testing.assert_array_equal(c.integrate(state, 10).state.r[0].numpy(), layout + later.reshape(-1, 2))
    assert c.summary()["safe_command_steps"] == 0 and c.summary()["reset_accepted"] == 2


def test_an_awaited_reset_that_never_came_is_a_safe_step_and_reset_needs_lockstep():
    c = core(reset_every=5, wait_for=["reset"])
    state = c.integrate(None, 0).state
    assert c.summary()["safe_command_steps"] == 1
    c.integrate(state, 1)
    assert c.summary()["safe_command_steps"] == 1  # step 1 is no reset step
    with pytest.raises(ParameterError, match="needs mode lockstep"):
        core(reset_every=5, mode="realtime")
    with pytest.raises(ParameterError, match="'reset_every' is 0"):
        core(wait_for=["reset"])


# -- divergence --------------------------------------------------------------------------------------------------
def _diverging_core(**params) -> tuple[BodyCore, list]:
    c = core(wait_for=["rest_length", "force"], max_force=1e12, **params)
    states = []
    state = None
    for k in range(2):
        c.announce(k, 0.0)
        c.offer_command("rest_length", k, BASE, 0.0)
        c.offer_command("force", k, np.zeros(M2), 0.0)
        state = c.integrate(state, k).state
        states.append(state)
    c.announce(2, 0.0)
    c.offer_command("rest_length", 2, BASE * 1.01, 0.0)
    c.offer_command("force", 2, np.full(M2, 1e11), 0.0)  # within the loosened bound, but the step diverges
    return c, states


def test_divergence_restores_the_last_good_state_with_the_safe_command():
    c, states = _diverging_core()
    out = c.integrate(states[-1], 2)
    with torch.no_grad():
        expected = agent().body.step(states[-1], rest_length=agent().body.l)
    np.testing.assert_array_equal(out.state.r.numpy(), expected.r.numpy())
    np.testing.assert_array_equal(out.rest.numpy(), BASE)
    assert out.force is None
    s = c.summary()
    assert s["divergences"] == 1 and s["safe_command_steps"] == 1 and s["force_accepted"] == 3
    errors = [e for e in c.events if e.level == "error"]
    assert len(errors) == 1 and errors[0].diagnostic
    assert errors[0].text.startswith("step 2 diverged (")
    assert "restored the last good state (step 1) and integrated step 2 with the safe command" in errors[0].text
    assert c.divergence_of(states[-1]) is None  # the planted good state is good


def test_divergence_with_stop_ends_the_run():
    c, states = _diverging_core(on_divergence="stop")
    with pytest.raises(SimulationDiverged, match="stopping the run"):
        c.integrate(states[-1], 2)
    assert c.diverged_stop and c.summary()["divergences"] == 1 and c.stats.steps == 1


def test_a_perturbation_that_would_diverge_is_dropped_not_the_step():
    c = core()
    c.offer_perturbation(0, np.full(M2, 4.0), 0.0)  # within the 5.66 m bound
    c.limits = type(c.limits)(c.limits.max_rest_length, max_displacement=1e9)
    big = c.perturbations.pending[0]
    big.values[:] = 1e8  # planted beyond the runaway box after the check
    out = c.integrate(None, 0)
    assert out.perturbation is None and c.summary()["perturbation_applied"] == 0
    assert any("would diverge" in e.text and e.diagnostic for e in c.events)


# -- the loop, with a fake port ----------------------------------------------------------------------------------


def test_lockstep_loop_equals_the_offline_steps_and_rejects_a_stale_command():
    c = core(wait_for=["rest_length"], max_steps=20, command_timeout=1.0)

    def brain(port, k):
        port.send(0.003, lambda: c.offer_command("rest_length", k, RESTS[k], port.now()))
        if k == 4:  # a late duplicate for step 3, after step 3 was integrated
            port.send(0.001, lambda: c.offer_command("rest_length", 3, 2 * BASE, port.now()))

    port = FakePort(c, brain)
    assert BodyLoop(c, port).run() is False
    assert port.clocks == list(range(21)) and [o.state.step for o in port.outputs] == list(range(21))
    assert port.viewed == list(range(21))
    for got, want in zip(port.outputs, offline(RESTS), strict=True):
        np.testing.assert_array_equal(got.state.r[0].numpy(), want)
    s = c.summary()
    assert s["steps"] == 20 and s["rest_length_accepted"] == 21 and s["rest_length_rejected_stale"] == 1
    assert s["safe_command_steps"] == 0 and s["command_latency_ms_max"] == pytest.approx(3.0)


def test_lockstep_silent_brain_gets_the_safe_command_until_it_resumes():
    c = core(wait_for=["rest_length"], max_steps=9, command_timeout=0.5)
    quiet = {3, 4, 5}

    def brain(port, k):
        if k not in quiet:
            port.send(0.001, lambda: c.offer_command("rest_length", k, RESTS[k], port.now()))

    port = FakePort(c, brain)
    BodyLoop(c, port).run()
    applied = [o.rest.numpy() for o in port.outputs]
    for k in range(10):
        np.testing.assert_array_equal(applied[k], BASE if k in quiet else RESTS[k])
    assert c.summary()["safe_command_steps"] == 3 and c.summary()["silent_brain_steps"] == {"rest_length": 3}
    silent = [t for lvl, t in [(e.level, e.text) for e in c.events] if lvl == "error"]
    assert silent == ["brain silent: no rest_length command for step 3 within 0.5 s; the body keeps running with "
                      "the safe command (trained rest lengths, zero force) until commands resume"]
    assert any(e.text == "rest_length commands resumed at step 6" for e in c.events)
    # waited the timeout once (step 3), then paced at dt / rate_scale while silent, not the timeout again
    assert 0.5 <= port.t < 0.5 + 10 * 0.011


def test_lockstep_gone_publisher_is_silent_at_once():
    c = core(wait_for=["rest_length"], max_steps=2, command_timeout=100.0)
    port = FakePort(c)
    port.gone.add("rest_length")
    BodyLoop(c, port).run()
    assert port.t < 1.0 and c.summary()["safe_command_steps"] == 3
    assert any("no publisher left on /rest_length" in e.text for e in c.events)


def test_a_run_without_its_brain_does_not_count():
    """A brain that never publishes: every step on the safe command, counted as silent, and brain_problem names it
    (the launchers fail such a run); a run whose brain answered every step has no problem."""
    from bptsb_ros.live.summary import brain_problem

    c = core(wait_for=["rest_length"], max_steps=4, command_timeout=0.05)
    BodyLoop(c, FakePort(c)).run()
    s = c.summary()
    assert s["silent_brain_steps"] == {"rest_length": 5}
    assert brain_problem(s) == ("body_sim ran on the safe command for lack of its brain (rest_length silent on 5 of "
                                "steps 0..4): the loop did not run as launched")
    ok = core(wait_for=["rest_length"], max_steps=4)
    BodyLoop(ok, FakePort(ok, lambda port, k: port.send(0.001, lambda: ok.offer_command(
        "rest_length", k, RESTS[k], port.now())))).run()
    assert ok.summary()["silent_brain_steps"] == {"rest_length": 0} and brain_problem(ok.summary()) == ""


def test_realtime_loop_schedule_jitter_misses_and_newest_command():
    c = core(mode="realtime", wait_for=["rest_length"], max_steps=9, max_command_age=0.05)

    def brain(port, k):  # answers every second /clock only: the body uses the newest, one step old
        if k % 2 == 0:
            port.send(0.002, lambda: c.offer_command("rest_length", k, RESTS[k], port.now()))

    port = FakePort(c, brain, cost=0.004)
    BodyLoop(c, port).run()
    applied = [o.rest.numpy() for o in port.outputs]
    assert len(applied) == 10 and port.viewed == list(range(10))  # each step's viewers' topics once, after it
    for k in range(10):  # clock t_{k+1} goes out after step k; the answer arrives 2 ms later, before step k+1
        np.testing.assert_array_equal(applied[k], RESTS[k - k % 2])
    s = c.summary()
    assert s["deadline_misses"] == 0 and s["jitter_ms_max"] == pytest.approx(0.0, abs=1e-9)
    assert s["command_age_steps_max"] == 1.0 and s["command_age_steps_mean"] == pytest.approx(0.5)

    slow = core(mode="realtime", max_steps=4)
    port = FakePort(slow, cost=0.015)  # 15 ms per 10 ms step: every step is late
    BodyLoop(slow, port).run()
    assert slow.stats.deadline_misses == 5
    assert slow.stats.jitter.max == pytest.approx(4 * 0.005)  # step k starts 5 ms later than the one before


class PollingPort(FakePort):
    """A fake port whose ``drain`` takes ``poll`` seconds and ``rehearse`` 2.5 times that; records (time, timeout)
    of every sleep (``spin_once``), the time of every poll (``drain``) and (time, step) of every rehearsal."""

    def __init__(self, core: BodyCore, poll: float = 0.0001) -> None:
        super().__init__(core)
        self.poll, self.sleeps, self.polls, self.rehearsals = poll, [], [], []

    def spin_once(self, timeout: float) -> None:
        self.sleeps.append((self.t, timeout))
        super().spin_once(timeout)

    def drain(self) -> None:
        self.polls.append(self.t)
        super().drain()
        self.t += self.poll

    def rehearse(self, state) -> None:
        self.rehearsals.append((self.t, None if state is None else state.step))
        self.t += 2.5 * self.poll


@pytest.mark.parametrize("rt", [0, 10])
def test_realtime_under_rt_priority_polls_the_last_busy_wait_before_each_step(rt):
    """Steps due at 10 ms intervals; under rt_priority the body sleeps until 2 ms (busy_wait) before each is due and
    polls and rehearses the step after its last state from then on, the last rehearsal ending before the step is due;
    on the normal scheduler it sleeps until the step is due; the schedule is the same."""
    c = core(mode="realtime", max_steps=3, busy_wait=0.002)
    c.rt_priority = rt
    port = PollingPort(c)
    BodyLoop(c, port).run()
    due = [0.01 * (k + 1) for k in range(4)]  # /clock t_0 at 0, step k due one period after
    assert c.stats.jitter.max < 0.0002 and len(port.outputs) == 4
    sleep_ends = [t + timeout for t, timeout in port.sleeps]
    for d in due:
        woke = max(e for e in sleep_ends if e <= d + 1e-12)
        assert woke == pytest.approx(d - 0.002 if rt else d, abs=1e-9)
        polling = [t for t in port.polls if d - 0.002 - 1e-9 <= t < d]
        assert (len(polling) >= 4) if rt else (len(polling) <= 2)
        rehearsed = [(t, k) for t, k in port.rehearsals if d - 0.002 - 1e-9 <= t < d]
        # a poll (0.1 ms) and a rehearsal (0.25 ms) while twice that fits before the step: polls at 2, 1.65, 1.3, 0.95
        # ms before it, the last rehearsal over 0.6 ms before it
        assert len(rehearsed) == (4 if rt else 0) and all(t + 0.00025 <= d - 0.0006 + 1e-9 for t, _ in rehearsed)
        assert {k for _, k in rehearsed} <= ({None} if d == due[0] else {round(d / 0.01) - 2})
    half = core(mode="realtime", max_steps=1, busy_wait=1.0)  # at most half a period
    half.rt_priority = rt
    port = PollingPort(half)
    BodyLoop(half, port).run()
    assert max(t + timeout for t, timeout in port.sleeps if t < 0.01) == pytest.approx(0.005 if rt else 0.01)


def test_realtime_perturbation_lands_on_its_step_and_a_stale_one_is_rejected():
    c = core(mode="realtime", max_steps=12)
    disp = 0.02 * np.arange(M2) / M2

    def brain(port, k):
        if k == 2:
            port.send(0.001, lambda: c.offer_perturbation(9, disp, port.now()))
            port.send(0.001, lambda: c.offer_perturbation(1, disp, port.now()))  # step 1 is done

    port = FakePort(c, brain)
    BodyLoop(c, port).run()
    kicked = [o.state.step for o in port.outputs if o.perturbation is not None]
    assert kicked == [9]
    plain = offline([BASE] * 13)
    np.testing.assert_array_equal(port.outputs[9].state.r[0].numpy(), plain[9] + disp.reshape(-1, 2))
    np.testing.assert_array_equal(port.outputs[8].state.r[0].numpy(), plain[8])
    s = c.summary()
    assert (s["perturbation_accepted"], s["perturbation_rejected_stale"], s["perturbation_steps"]) == (1, 1, [9])


def test_realtime_wall_duration_and_quiet_source():
    c = core(mode="realtime", wait_for=["rest_length"], wall_duration=0.1, command_timeout=0.055)
    port = FakePort(c)
    BodyLoop(c, port).run()
    assert [o.state.step for o in port.outputs] == list(range(11))  # due at 0.01 .. 0.11 s, the last within 0.1 s
    assert port.clocks == list(range(11))
    silent = [e.text for e in c.events if e.level == "error"]
    assert silent == ["brain silent: no rest_length command for 0.055 s; the body keeps running with the safe "
                      "command (trained rest lengths, zero force) until commands resume"]
    # silent from step 5 (due at 0.06 s, past the timeout counted from the start); steps 0..4 warn instead
    assert [e.text for e in c.events if e.key == "stale:rest_length"] == [
        f"no usable rest_length command at step {k}: using the safe command" for k in range(5)]


def test_recorder_gate_waits_and_gives_up_without_progress():
    c = core(wait_for_recorder=True, recorder_window=2, qos_depth=10, max_steps=6, recorder_timeout=0.3)
    acks = {0: 0, 1: 1, 2: 2}  # the recorder acknowledges steps 0..2, then freezes

    def brain(port, k):
        if k in acks:
            port.send(0.01, lambda: c.recorder_ack(acks[k], []))

    port = FakePort(c, brain)
    BodyLoop(c, port).run()
    gate = c.recorder
    assert gate.acked == 2 and gate.silent  # step 5 needed step 3
    # steps 2 and 4 waited 0.01 s for a late ack; step 3's ack had arrived but was handled only when step 3 asked for
    # it (no source is awaited, so nothing is handled between steps): a wait of 0 s; step 5 gave up once 0.3 s
    # passed without progress, at the first 0.05 s poll beyond: 0.35 s
    assert gate.waits == 4 and gate.wait_s == pytest.approx(0.01 + 0.0 + 0.01 + 0.35)
    assert any("recorder silent" in t for _, t in port.logs)
    c.recorder_ack(6, ["/forger"])
    assert gate.acked == 2 and gate.rejected == 1


def test_stop_request_and_summary_file(tmp_path):
    c = core(wait_for=["rest_length"], command_timeout=10.0)
    port = FakePort(c, stop_at=0.5)  # no brain: the body waits until stopped
    assert BodyLoop(c, port).run() is False and port.outputs == []
    write_summary(tmp_path / "a" / "s.json", c.summary())
    s = json.loads((tmp_path / "a" / "s.json").read_text())
    assert s["steps"] == 0 and s["mode"] == "lockstep" and s["rejected_total"] == 0


def test_startup_waits_for_what_is_missing_then_gives_up_at_the_timeout():
    c = core(startup_timeout=1.0)
    port = FakePort(c)
    BodyLoop(c, port).wait_startup(lambda: ["a brain"] if port.t < 0.3 else [])
    assert 0.3 <= port.t < 0.4 and port.logs[-1] == ("info", "startup complete: brains and subscribers present; "
                                                     "running")
    port = FakePort(c)
    BodyLoop(c, port).wait_startup(lambda: ["a publisher on /brain/rest_length"])
    assert 1.0 < port.t < 1.1
    assert port.logs[-1] == ("warning", "startup: still missing a publisher on /brain/rest_length after 1 s; "
                                        "starting anyway")


def test_diagnostic_level_and_end_text():
    c = core(wait_for=["rest_length"])
    assert c.status(c.summary())[0] == "OK"
    c.offer_command("rest_length", 0, BASE[:-1], 0.0)  # one rejection
    level, message, values = c.status(c.summary())
    assert level == "WARN" and "1 rejected commands" in message and ("rest_length_rejected_wrong_length", "1") in values
    assert c.status(c.summary(), error="step 3 diverged")[:2] == ("ERROR", "step 3 diverged")
    quiet = core()
    quiet.integrate(None, 0)  # nothing awaited: not a safe-command step
    assert quiet.status(quiet.summary())[0] == "OK"
    c.integrate(None, 0)  # awaited rest length missing: the safe command
    assert c.summary()["safe_command_steps"] == 1
    assert c.end_text(c.summary(), False, None).startswith("finished after 0 steps (0.000 s sim time)\n")
    assert c.end_text(c.summary(), True, None).startswith("stopped: the simulation diverged after")
    assert c.end_text(c.summary(), False, "SIGINT").startswith("stopped by SIGINT after")


# -- the feedback brain's commands -----------------------------------------------------------------------------
def fitted_agent(state: str):
    """A lissajous agent whose feedback layer (state ``state``) carries planted weights W (E, F + 1)."""
    from bptsb_ros.agent import build_agent
    from bptsb_ros.config import validate

    a = build_agent(validate({"task": "lissajous", "seed": 0, "dtype": "float64", "feedback": {"state": state}}))
    layer = a.feedback
    w = 0.01 * np.random.default_rng(3).standard_normal(tuple(layer.weight.shape))
    layer.load_fit(w)
    for module in a.modules().values():  # frozen, as the nodes hold it
        module.requires_grad_(False)
    return a, layer.weight.detach().numpy().copy()  # undriven rows zeroed by load_fit


def test_feedback_commands_route_clock_and_state_and_compute_the_layer_by_hand():
    from bptsb_ros.live.feedback_loop import FeedbackCommands

    a, w = fitted_agent("spring_length")
    base = a.body.l.numpy()
    closed = FeedbackCommands(a, open_loop=0)
    assert closed.on_clock(0) is not None and np.array_equal(closed.on_clock(0), base)
    assert closed.on_clock(1) is None  # answered by the state of step 0
    topo = a.body.topology
    positions = np.asarray(topo.positions) * 1.1 + 0.01 * np.arange(2 * topo.n_masses).reshape(-1, 2)
    s = np.array([np.hypot(*(positions[i] - positions[j])) for i, j in np.asarray(topo.springs)])  # by hand
    rest = closed.on_state(4, positions)
    np.testing.assert_allclose(rest, base * (1 + w[:, :-1] @ s + w[:, -1]), rtol=0, atol=1e-13)
    assert closed.on_state(4, positions.reshape(-1)[:-1]) == ("ignored mass positions of step 4: 49 values, "
                                                              "expected 50")

    swg = a.brain
    opened = FeedbackCommands(a, open_loop=3)
    with torch.no_grad():
        amp, phase, drv = swg.amplitude.numpy(), swg.phase.numpy(), swg.driven.numpy()
    for k in (0, 3):  # the SWG's l·(1 + A sin(ω k dt + φ)) on driven springs
        expected = base * (1 + drv * amp * np.sin(swg.omega * k * a.body.dt + phase))
        np.testing.assert_allclose(opened.on_clock(k), expected, rtol=0, atol=1e-12)
    assert opened.on_clock(4) is None
    assert opened.on_state(2, positions) is None and opened.on_state(3, positions) is not None  # the layer: step 4 on


def test_feedback_acceleration_features_are_effort_over_mass():
    from bptsb_ros.live.feedback_loop import FeedbackCommands

    a, w = fitted_agent("acceleration")
    with torch.no_grad():  # planted unequal masses (the paper's are all 1, where a = F / m = F · m)
        a.body.mass.copy_(torch.linspace(0.5, 2.0, a.body.mass.numel(), dtype=a.body.mass.dtype))
    mass = a.body.mass.numpy()
    assert mass.shape == (M2 // 2,)
    effort = np.linspace(-1.0, 1.0, M2)
    feats = FeedbackCommands(a).features(effort)
    np.testing.assert_array_equal(feats, (effort.reshape(-1, 2) / mass[:, None]).reshape(-1))
    assert FeedbackCommands(a).on_state(0, effort[:-2]) == ("ignored mass states (acceleration) of step 0: 24 values, "
                                                            "expected 26")


def test_the_body_steps_once_at_construction_and_rehearsing_changes_nothing(monkeypatch):
    """The live step is called once while the core is built (numba compiles or loads it then, not at the first step
    of a realtime run); ``rehearse`` computes a step and throws it away: the next real step is as without it."""
    from bptsb_ros.body.live_step import LiveStep

    calls = []
    real = LiveStep.__call__
    monkeypatch.setattr(LiveStep, "__call__", lambda self, *a: calls.append(1) or real(self, *a))
    c, plain = core(), core()
    assert len(calls) == 2
    s0, p0 = c.integrate(None, 0).state, plain.integrate(None, 0).state
    c.rehearse(s0)
    assert len(calls) == 3
    np.testing.assert_array_equal(c.integrate(s0, 1).state.r[0].numpy(), plain.integrate(p0, 1).state.r[0].numpy())
    assert c.summary()["steps"] == plain.summary()["steps"] == 1
