"""The step loop of the live body, ROS-free: when to announce a step, how long to wait for its commands (and for
the recorder), when a source counts as silent, and the realtime schedule. It drives a
:class:`~bptsb_ros.live.body_core.BodyCore` through a :class:`BodyPort` — the node's publishers, executor and
graph in ``body_sim``; plain Python objects and a fake clock in the tests.

* ``lockstep``: before step k the body waits until the recorder acknowledged step k − ``recorder_window``
  (``wait_for_recorder``; given up after ``recorder_timeout`` without progress), announces ``/clock`` t_k, then
  waits for the step-k command of every awaited source; a source whose publisher is gone, or that sent nothing
  for ``command_timeout``, is silent (the safe command stands in) until it sends again. While one is silent the
  steps are paced at ``rate_scale``.
* ``realtime``: step k is due at start + k·dt/``rate_scale`` wall seconds (a live change of ``rate_scale`` keeps
  the due time of the current step); the newest command is used; jitter (start − due), compute time and deadline
  misses (finished after the next step's due time) are counted, and with ``timing_path`` every step's wall times
  are kept (:class:`~bptsb_ros.live.step_times.StepTimes`); ``wall_duration`` > 0 ends the run. A step is done
  when the outputs the loop's nodes read and the next ``/clock`` are out; the viewers' topics (markers, the thinned
  state) follow it. Under ``rt_priority`` the body spends the last ``busy_wait`` before a step polling and rehearsing
  it (:meth:`BodyLoop.wait_due`).

In both modes the loop holds at a step boundary while ``core.control`` is paused (:mod:`~bptsb_ros.live.sim_control`:
pause, resume, step N, reset), handling messages and service calls; realtime shifts its schedule (and the end of
``wall_duration``) by the time held. A paused body says so in its log when the pause begins and every
``pause_notice_period`` wall seconds after, and ends the run once it has been paused for ``pause_timeout`` (0: never):
a forgotten pause cannot hold a launch forever.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.live.body_core import BodyCore, StepOutput

#: longest single wait [s] between two looks at the stop flag
POLL_S = 0.05


class PausedTooLong(RuntimeError):
    """The body stayed paused for ``pause_timeout`` wall seconds: the run ends (a failure)."""


class BodyPort(Protocol):
    """What the loop needs from its surroundings (``body_sim``: rclpy)."""

    def stopped(self) -> bool:
        """The run was asked to stop."""

    def now(self) -> float:
        """Monotonic time [s]."""

    def spin_once(self, timeout: float) -> None:
        """Handle at most one incoming message, waiting up to ``timeout`` [s] for it."""

    def drain(self) -> None:
        """Handle every incoming message that is ready now."""

    def publisher_gone(self, source: str) -> bool:
        """No node publishes on ``source``'s topic any more."""

    def topic(self, source: str) -> str:
        """The topic name of ``source`` (for log lines)."""

    def announce(self, step: int) -> None:
        """Publish ``/clock`` t_``step``."""

    def publish(self, out: StepOutput, views: bool = True) -> None:
        """Publish the outputs of one step; ``views`` False: only those the loop's nodes read."""

    def publish_views(self, out: StepOutput) -> None:
        """Publish the outputs of one step that :meth:`publish` with ``views`` False left out (viewers' topics)."""

    def rehearse(self, state: BodyState | None) -> None:
        """Go through the work of a step after ``state`` without any effect (nothing published on the loop's topics,
        nothing counted): called while a realtime body under ``rt_priority`` waits for its next step."""

    def diagnostics(self, slack: float = math.inf) -> None:
        """Publish the loop status if it is due; ``slack``: seconds until the next step is due (realtime), the work
        may be left for a later turn with more time to spare."""

    def log(self, level: str, text: str) -> None:
        """One log line (info, warning or error)."""


class BodyLoop:
    """Runs a :class:`BodyCore` in its timing mode (``core.p['mode']``) through a :class:`BodyPort`."""

    def __init__(self, core: BodyCore, port: BodyPort) -> None:
        self.core, self.port = core, port
        self.started = 0.0

    def run(self) -> bool:
        """Step until the last step, ``wall_duration`` or a stop request; True if the run failed: the simulation
        diverged, or the body stayed paused for ``pause_timeout`` (``core.pause_expired``)."""
        core, port = self.core, self.port
        self.started = port.now()  # start of stepping: realtime silence is counted from here
        core.counting = not port.stopped()  # a run stopped during startup published nothing a recorder had to get
        try:
            self._lockstep() if core.p["mode"] == "lockstep" else self._realtime()
        except SimulationDiverged as err:
            if not core.diverged_stop:
                port.log("error", str(err))
            return True
        except PausedTooLong as err:
            core.pause_expired = True
            port.log("error", str(err))
            return True
        return False

    def wait_startup(self, missing: Callable[[], list[str]]) -> None:
        """Before the first step: handle messages until ``missing()`` (what the run still lacks: brains,
        subscribers, the recorder) is empty, or ``startup_timeout`` passed (then start anyway, the silent sources
        on the safe command)."""
        port, timeout = self.port, self.core.p["startup_timeout"]
        deadline = port.now() + timeout
        while not port.stopped():
            lacking = missing()
            if not lacking:
                port.log("info", "startup complete: brains and subscribers present; running")
                return
            if port.now() > deadline:
                port.log("warning", f"startup: still missing {'; '.join(lacking)} after {timeout:g} s; starting anyway")
                return
            self.spin_for(POLL_S)

    def hold(self) -> float:
        """While paused (and no ``step`` left): handle messages and calls, publish diagnostics, say so in the log;
        returns the wall seconds held (0.0: not paused). Raises PausedTooLong after ``pause_timeout``."""
        control, port, p = self.core.control, self.port, self.core.p
        if not control.holding():
            return 0.0
        began = port.now()
        timeout, period = p["pause_timeout"], p["pause_notice_period"]
        at = f"after step {control.last_step}" if control.last_step >= 0 else "before the first step"
        bound = (f"; the run ends if it stays paused for {timeout:g} s (pause_timeout)" if timeout else
                 " (no pause_timeout: it waits as long as it takes)")
        port.log("warning", f"paused {at}: no step is taken until ~/resume or ~/step is called{bound}")
        notice = began + period
        while control.holding() and not port.stopped():
            port.spin_once(POLL_S)
            port.diagnostics()
            if not control.holding():
                break
            now = port.now()
            if timeout and now - began >= timeout:
                raise PausedTooLong(f"paused {at} for {timeout:g} s without ~/resume or ~/step (pause_timeout): "
                                    "ending the run")
            if now >= notice:
                port.log("warning", f"still paused {at}, for {now - began:.0f} s: call ~/resume or ~/step{bound}")
                notice += period
        return port.now() - began

    def _more(self, step: int) -> bool:
        return not self.port.stopped() and (self.core.max_steps == 0 or step <= self.core.max_steps)

    def spin_for(self, seconds: float) -> None:
        """Handle messages for ``seconds`` (at least the ready ones), polling the stop flag."""
        port = self.port
        end = port.now() + seconds
        port.drain()
        while not port.stopped():
            remaining = end - port.now()
            if remaining <= 0:
                return
            port.spin_once(min(remaining, POLL_S))

    def wait_due(self, due: float, period: float, state: BodyState | None) -> None:
        """Realtime: handle messages until ``due`` (monotonic seconds). Under ``rt_priority`` the last ``busy_wait``
        seconds (at most half of ``period``) are not slept: the body polls for messages and rehearses the step after
        ``state`` (``port.rehearse``) as long as one more rehearsal ends before ``due``. A step that starts after
        milliseconds of sleep, or of other processes on its core, finds the CPU's caches cold and costs several
        times what the same step costs right after another."""
        port = self.port
        busy = min(self.core.p["busy_wait"], period / 2) if self.core.rt_priority else 0.0
        self.spin_for(due - busy - port.now())
        cost = 0.0  # the last rehearsal's wall time
        while busy and not port.stopped() and (now := port.now()) < due:
            port.drain()
            if now + 2 * cost < due:
                port.rehearse(state)
                cost = port.now() - now

    def _lockstep(self) -> None:
        core, port = self.core, self.port
        state: BodyState | None = None
        step = 0
        last = port.now()
        phases = core.phases
        while self._more(step):
            began = port.now()
            self.hold()
            if port.stopped():
                break
            t0 = port.now()
            self.await_recorder(step)
            if port.stopped():
                break
            t1 = port.now()
            core.announce(step, t1)
            port.announce(step)
            t2 = port.now()
            self.await_commands(step)
            if port.stopped():
                break
            t3 = port.now()
            if any(core.silent[s] for s in core.wait_sources):  # pace silent running at rate_scale
                self.spin_for(max(0.0, last + core.period() - port.now()))
            last = port.now()
            out = core.integrate(state, step)
            t4 = port.now()
            port.publish(out)
            state = out.state
            t5 = port.now()
            core.stats.compute.append(t5 - last)
            port.diagnostics()
            ended = port.now()
            phases.add("recorder", t1 - t0)
            phases.add("commands", t3 - t2)
            phases.add("compute", t4 - last)
            phases.add("publish", (t2 - t1) + (t5 - t4) + (ended - t5))
            phases.step_done(began, ended)
            step += 1

    def _realtime(self) -> None:
        core, port = self.core, self.port
        period = core.period()
        state: BodyState | None = None
        core.announce(0, port.now())
        port.announce(0)
        start = port.now() + period
        wall_end = start + core.p["wall_duration"] if core.p["wall_duration"] > 0 else math.inf
        step = 0
        while self._more(step):
            held = self.hold()
            if held:  # the paused time is not schedule: step k is due as long after now as it was at the pause
                start, wall_end, core.resumed_at = start + held, wall_end + held, port.now()
            if core.period() != period:  # rate_scale changed live: keep this step's due time, new pace after it
                start, period = start + step * (period - core.period()), core.period()
            due = start + step * period
            if due > wall_end:
                break
            self.wait_due(due, period, state)
            if port.stopped():
                break
            began = port.now()
            core.stats.jitter.append(began - due)
            for s in core.wait_sources:
                core.watch_realtime(s, step, began, self.started, port.publisher_gone(s), port.topic(s))
            out = core.integrate(state, step)
            integrated = port.now()
            port.publish(out, views=False)  # what the brains read now; the viewers' topics once the step is done
            state = out.state
            if (core.max_steps == 0 or step < core.max_steps) and start + (step + 1) * period <= wall_end:
                core.announce(step + 1, port.now())
                port.announce(step + 1)
            done = port.now()
            core.stats.compute.append(done - began)
            if done > due + period:
                core.stats.deadline_misses += 1
            if core.step_times is not None:
                core.step_times.append(step, due, began, integrated, done)
            port.publish_views(out)
            port.diagnostics(slack=due + period - port.now())  # the time left before the next step is due
            step += 1

    def await_commands(self, step: int) -> None:
        """Lockstep: handle messages until every awaited source that is not silent has its command for ``step``;
        a source whose publisher is gone, or still without it after ``command_timeout``, becomes silent.

        Messages are handled one at a time in the order they arrived (``spin_once``; the EventsExecutor's order), and
        only while a command is missing: every message that arrived before the step's last command (a perturbation
        for the step, say) is handled before the step is integrated, without an idle spin to find out that nothing
        else is waiting."""
        core, port = self.core, self.port
        timeout = core.p["command_timeout"]
        deadline = port.now() + timeout
        while not port.stopped():
            missing = core.missing(step)
            if not missing:
                return
            now = port.now()
            for s in missing:
                gone = port.publisher_gone(s)
                if gone or now >= deadline:
                    core.silence(s, f"no publisher left on {port.topic(s)}" if gone else
                                 f"no {s} command for step {step} within {timeout:g} s")
            if now >= deadline or all(core.silent[s] for s in missing):
                return
            port.spin_once(min(POLL_S, deadline - now))

    def await_recorder(self, step: int) -> None:
        """``wait_for_recorder``: handle messages until the recorder acknowledged step − ``recorder_window``; go on
        without it once its acknowledgement made no progress for ``recorder_timeout`` (it is then silent until it
        acknowledges again)."""
        gate, port = self.core.recorder, self.port
        if gate is None:
            return
        need = gate.need(step)
        if gate.acked >= need:
            if gate.silent:
                gate.silent = False
                port.log("info", f"the recorder caught up (acknowledged step {gate.acked}); waiting for it again")
            return
        if gate.silent:
            port.drain()
            return
        gate.waits += 1
        timeout = self.core.p["recorder_timeout"]
        started = progress = port.now()
        seen = gate.acked
        while not port.stopped() and gate.acked < need:
            port.spin_once(POLL_S)
            now = port.now()
            if gate.acked > seen:
                seen, progress = gate.acked, now
            elif now - progress > timeout:
                gate.silent = True
                port.log("error", f"recorder silent: no acknowledgement progress for {timeout:g} s (it has step "
                         f"{gate.acked}, step {step} needs {need}); the body goes on without waiting, and the "
                         "recording counts the messages it loses")
                break
        gate.wait_s += port.now() - started
