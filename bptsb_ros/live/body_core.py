"""The live body, ROS-free: commands, wind, perturbations and resets stamped with steps in; one ``MSDN.step`` per
step out, under the body's safety rules. ``body_sim`` converts messages to calls of :class:`BodyCore` and its
outputs back to messages; :mod:`bptsb_ros.live.body_loop` drives the steps in either timing mode.

Every input names the step it is in force at (a stamp t_k = k·dt):

* commands (``rest_length`` (E,) [m], ``force`` (2M,) [N], the synchronised ``wind`` (2,) [N] of a wind_source, and
  ``reset`` displacements (2M,) [m]) go through a :class:`~bptsb_ros.live.channels.CommandChannel` each: wrong
  length or joint names, NaN/inf, out of physical bounds (:class:`~bptsb_ros.live.safety.CommandLimits`), stale,
  duplicate, stamped too far ahead, off the reset schedule, or sent while a node not allowed by
  :class:`~bptsb_ros.live.safety.PublisherRule` publishes on the topic (the node names those publishers) are
  rejected, counted by reason and never integrated;
* an unsynchronised wind (a message on ``env/wind`` or the ``wind`` parameter) holds from the next step on;
* a perturbation (2M,) [m] displaces the state of its step (velocities kept); at most
  :data:`MAX_PENDING_PERTURBATIONS` wait at once (``queue_full``), none beyond the run's last step.

:meth:`BodyCore.integrate` takes the commands of step k (the safe command — trained rest lengths, no brain force —
for an awaited source without one), applies a reset or integrates, checks the new state for divergence and
recovers (``on_divergence``, :class:`~bptsb_ros.live.safety.DivergenceRecovery`) or stops (raises
``SimulationDiverged``). Pause, resume, step and reset calls go to :attr:`BodyCore.control`
(:class:`~bptsb_ros.live.sim_control.SimControl`). What a node logs arrives as :class:`Event` records at ``sink``;
:meth:`BodyCore.summary` is the run summary as plain data.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from bptsb_ros.body.live_step import SOUND, LiveStep, state_arrays
from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.interface.params import ParameterError, ParamValue
from bptsb_ros.interface.topics import dt_to_ns, mass_dof_names, spring_names
from bptsb_ros.live.body_params import (
    LISTED_PERTURBATIONS,
    MAX_PENDING_PERTURBATIONS,
    MAX_PERTURB_AHEAD,
    perturb_step,
)
from bptsb_ros.live.channels import CommandChannel, Rejection, TimingStats
from bptsb_ros.live.phases import StepPhases
from bptsb_ros.live.safety import (
    CommandLimits,
    DivergenceRecovery,
    PublisherRule,
    WindIntake,
    rest_length_floor,
    runaway,
)
from bptsb_ros.live.sim_control import ControlCall, SimControl
from bptsb_ros.live.step_times import StepTimes
from bptsb_ros.live.summary import summary_text
from bptsb_ros.sim.perturbation import perturbation

#: the sources whose commands are stamped with the step they are in force at (``wait_for`` may name them)
SOURCES: tuple[str, ...] = ("rest_length", "force", "wind", "reset")


@dataclass(frozen=True)
class Event:
    """A line for the node's log. ``level``: info, warning or error; ``key``: throttle warnings of one kind
    (empty: always logged); ``diagnostic``: also publish it as an ERROR diagnostic (a divergence); ``control``: the
    pause/resume/step/reset call it reports (published as a control diagnostic, recorded in bags)."""

    level: str
    text: str
    key: str = ""
    diagnostic: bool = False
    control: ControlCall | None = None


@dataclass
class StepOutput:
    """What step ``state.step`` publishes: the state, the rest lengths (E,) [m] and total external force (M, 2) [N]
    (or None: none) in force, as numpy arrays of the body's dtype (``rest``, ``force``: the same as tensors), and the
    perturbation (2M,) [m] applied to the state (None: none)."""

    state: BodyState
    rest_np: np.ndarray
    force_np: np.ndarray | None
    perturbation: np.ndarray | None = None

    @property
    def rest(self) -> torch.Tensor:
        return torch.from_numpy(self.rest_np)

    @property
    def force(self) -> torch.Tensor | None:
        return None if self.force_np is None else torch.from_numpy(self.force_np)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The step's r, v, a (M, 2), spring lengths (E,), rest lengths (E,) and force (M, 2) (or None) as numpy
        arrays (views; no torch call where the compiled live step made the state)."""
        r, v, a, length = state_arrays(self.state)
        return r[0], v[0], a[0], length[0], self.rest_np.reshape(-1), self.force_np


@dataclass
class RecorderGate:
    """``wait_for_recorder``: the newest step the recorder acknowledged (only while every publisher of the
    acknowledgements is allowed by ``rule``), how far the body may run ahead (``window`` steps), and the counts."""

    rule: PublisherRule
    window: int
    acked: int = -1
    silent: bool = False
    waits: int = 0
    wait_s: float = 0.0
    rejected: int = 0

    def ack(self, step: int, untrusted: Sequence[str]) -> bool:
        """An acknowledgement of ``step``; ignored (False, counted) while ``untrusted`` publishers send them too."""
        if untrusted:
            self.rejected += 1
            return False
        self.acked = max(self.acked, step)
        return True

    def need(self, step: int) -> int:
        """The step the recorder must have acknowledged before the body announces ``step``."""
        return step - self.window


class BodyCore:
    """One live body: intake, the step, recovery and counters (see the module docstring).

    Args:
        agent: the agent whose body runs (``agent.body`` an MSDN, ``agent.brain`` its trained brain).
        p: the node's validated parameter values (:data:`~bptsb_ros.live.body_params.PARAMS`); read live where
            they are dynamic (``rate_scale``, ``wind``).
        sink: receives every :class:`Event` (default: kept in :attr:`events`).
        clock: monotonic time [s] (the scheduled perturbation's arrival time).
    """

    def __init__(self, agent: Any, p: Mapping[str, Any], sink: Callable[[Event], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.p = p
        self.events: list[Event] = []
        self.sink = sink or self.events.append
        self.agent = agent
        body = self.body = agent.body
        body.warm_up()  # load (or compile) the step kernel now, not in the first timed step
        try:
            self.dt_ns = dt_to_ns(body.dt)
        except ValueError as err:
            raise ParameterError(f"parameter 'dt' (or the agent's time step): {err}") from None
        self.max_steps = p["max_steps"] or (int(round(p["duration"] / body.dt)) if p["duration"] > 0 else 0)
        topo = body.topology
        self.spring_names = spring_names(topo.n_springs)
        self.dof_names = mass_dof_names(body.movable_index.tolist())
        self.base = body.l.detach().clone()
        self.base_np = self.base.numpy()
        self.np_dtype = self.base_np.dtype
        self.mass = body.mass.detach().numpy().copy()
        with torch.no_grad():  # the compiled one-body step where the body's steps run in the kernel
            self.live_step = LiveStep(body) if body.uses_kernel() else None
            if self.live_step is not None:  # compiled (or loaded from numba's cache) now, not at the first step
                first = body.initial_state(1, rest_length=self.base)
                self.rehearse(BodyState(first.r, first.v, first.a, first.length, 0))
        depth = p["qos_depth"]
        max_age = max(1, int(math.floor(p["max_command_age"] / body.dt + 1e-9)))
        amplitude = getattr(agent.brain, "amplitude", None)
        floor = p["min_rest_length"] or rest_length_floor(
            self.base.numpy(), None if amplitude is None else amplitude.detach().double().numpy())
        try:
            self.limits = CommandLimits.for_body(np.asarray(topo.positions), p["max_rest_length"], p["max_force"],
                                                 p["max_wind"], floor)
        except ValueError as err:
            raise ParameterError(f"parameters min_rest_length/max_rest_length/max_force/max_wind: {err}") from None
        sizes = {"rest_length": (topo.n_springs, self.spring_names), "force": (2 * body.n_movable, self.dof_names),
                 "wind": (2, ["x", "y"]), "reset": (2 * body.n_movable, self.dof_names)}
        self.channels = {s: CommandChannel(s, size, names, p["mode"], max_age_steps=max_age,
                                           bounds=lambda values, s=s: self.limits.check(s, values),
                                           surely_within=lambda values, s=s: self.limits.surely_within(s, values))
                         for s, (size, names) in sizes.items()}
        self.channels["reset"].every = p["reset_every"]  # 0: resets off
        allowed = tuple(p["command_publishers"])
        self.publisher_rules = {s: PublisherRule(s, allowed) for s in self.channels}
        # perturbations: stamped with the step whose state they displace, queued until the body reaches it
        self.perturbations = CommandChannel("perturbation", 2 * body.n_movable, self.dof_names, "lockstep",
                                            max_ahead=MAX_PERTURB_AHEAD,
                                            bounds=lambda values: self.limits.check("perturbation", values))
        self.publisher_rules["perturbation"] = PublisherRule("perturbation", tuple(p["perturb_publishers"]))
        self.perturbed: list[int] = []  # the first LISTED_PERTURBATIONS steps perturbed
        self.perturbation_count = 0
        if p["perturb_at"] >= 0:
            k = perturb_step(p["perturb_at"], body.dt, self.max_steps)
            disp = perturbation(body.n_movable, p["perturb_sigma"], p["perturb_seed"])
            rejection = self.perturbations.offer(k, disp.reshape(-1), 0, clock())
            if rejection is not None:
                raise ParameterError(f"parameters perturb_at/perturb_sigma: {rejection.message}")
        self.wind_intake = WindIntake(self.limits)
        self.divergence: DivergenceRecovery[BodyState] = DivergenceRecovery(p["on_divergence"])
        self.diverged_stop = False
        self.wait_sources: list[str] = list(dict.fromkeys(p["wait_for"]))
        if "reset" in self.wait_sources and not p["reset_every"]:
            raise ParameterError("parameter 'wait_for' contains reset but 'reset_every' is 0: set the episode length")
        if p["reset_every"] and p["mode"] != "lockstep":
            raise ParameterError("parameter 'reset_every': resets take effect at a stated step, which needs mode "
                                 "lockstep")
        self.silent: dict[str, bool] = {s: False for s in self.channels}
        self.silent_steps: dict[str, int] = {s: 0 for s in self.wait_sources}  # steps run while s was silent
        self.wind: np.ndarray | None = None
        if any(p["wind"]):
            problem = self.limits.check("wind", np.asarray(p["wind"]))
            if problem:
                raise ParameterError(f"parameter 'wind': {problem}")
            self.wind = np.asarray(p["wind"], dtype=np.float64)
        self.next_step = 0
        self.control = SimControl(p["start_paused"], sink=self._on_control)
        self.control_rule = PublisherRule("control", tuple(p["control_callers"]))
        self.pause_expired = False  # the run ended because the body stayed paused for pause_timeout
        self.resumed_at = -math.inf  # realtime: when a pause ended (silence is counted from then)
        self.stats = TimingStats()
        self.phases = StepPhases()  # lockstep: wall time per phase of a step (bptsb bench --live)
        if p["timing_path"] and p["mode"] != "realtime":
            raise ParameterError("parameter 'timing_path': per-step wall times are recorded in mode realtime only")
        self.step_times: StepTimes | None = StepTimes() if p["timing_path"] else None
        self.rt_priority = 0  # the SCHED_FIFO priority the node's stepping thread got (0: the normal scheduler)
        self.cpus = "any"  # the CPUs the node's threads were pinned to (its cpus parameter, once applied)
        self.clock_sent: dict[int, float] = {}
        self.published: dict[str, int] = {}  # topic name -> messages published since stepping began
        self.counting = False  # stepping began (startup complete or given up on): publications are counted
        if p["recorder_window"] >= depth:
            raise ParameterError(f"parameter 'recorder_window': {p['recorder_window']} must be below qos_depth "
                                 f"({depth}): the recorder must get every message before its publisher forgets it")
        if p["wait_for_recorder"] and p["mode"] != "lockstep":
            raise ParameterError("parameter 'wait_for_recorder': only a lockstep body can wait for the recorder")
        self.recorder: RecorderGate | None = None
        if p["wait_for_recorder"]:
            self.recorder = RecorderGate(PublisherRule("recorder_ack", tuple(p["recorder_publishers"])),
                                         p["recorder_window"] or max(1, depth // 2))

    def _emit(self, level: str, text: str, key: str = "", diagnostic: bool = False) -> None:
        self.sink(Event(level, text, key, diagnostic))

    def _on_control(self, call: ControlCall) -> None:
        self.sink(Event("info" if call.ok else "warning", f"{call.name}: {call.message}", control=call))

    # -- intake -----------------------------------------------------------------------------------------------
    @property
    def wind_synchronised(self) -> bool:
        """Whether wind arrives stamped per step from a wind_source (``wind`` in ``wait_for``), like a command."""
        return "wind" in self.wait_sources

    def offer_command(self, source: str, step: int, values: Sequence[float] | np.ndarray, now: float,
                      names: Sequence[str] | None = None, untrusted: Sequence[str] = (),
                      topic: str = "its topic") -> Rejection | None:
        """A command of ``source`` (rest_length, force, wind or reset) for ``step``, arrived at ``now`` [s,
        monotonic]; ``untrusted``: publishers on its ``topic`` that the publisher rule does not allow (then it is
        rejected). Returns None if accepted, else the rejection (counted and logged as a warning)."""
        channel = self.channels[source]
        if untrusted:
            what = "wind is" if source == "wind" else "commands are"
            rejection = channel.reject(step, "untrusted_publisher", f"{topic} also has publisher(s) not in "
                                       f"command_publishers ({', '.join(untrusted)}); its {what} ignored while they "
                                       "publish")
        else:
            rejection = channel.offer(step, values, self.next_step, now, list(names) if names else None)
        if rejection is not None:
            self._emit("warning", f"{rejection.message}; not {'applied' if source == 'wind' else 'integrated'}",
                       f"reject:{source}:{rejection.reason}")
            return rejection
        sent = self.clock_sent.get(step)
        if sent is not None:
            self.stats.latency.append(now - sent)
        if self.silent[source]:
            self.silent[source] = False
            self._emit("info", f"{source} commands resumed at step {step}")
        return None

    def offer_wind(self, wind: Sequence[float] | np.ndarray, untrusted: Sequence[str] = (),
                   topic: str = "env/wind") -> str | None:
        """An unsynchronised wind (x, y) [N] from the next step on; None if accepted, else why not (the previous
        wind stays). ``untrusted``: publishers on its ``topic`` that ``command_publishers`` does not allow."""
        wind = np.asarray(wind, dtype=np.float64)
        problem = self.wind_intake.offer(wind, untrusted, topic)
        if problem:
            self._emit("warning", f"{problem}; keeping the previous wind", "reject:wind")
            return problem
        self._set_wind(wind)
        return None

    def on_parameter(self, name: str, value: ParamValue) -> None:
        """A live parameter change; raises ParameterError to refuse it (``wind``: out of bounds or non-finite). The
        other live parameters are read where they are used."""
        if name == "wind":
            wind = np.asarray(value, dtype=np.float64)
            problem = self.wind_intake.offer(wind)
            if problem:
                raise ParameterError(f"parameter 'wind': {problem}")
            self._set_wind(wind)

    def _set_wind(self, wind: np.ndarray) -> None:
        previous = np.zeros(2) if self.wind is None else self.wind
        self.wind = None if not wind.any() else wind
        if (wind != previous).any():
            self._emit("info", f"wind set to ({wind[0]:g}, {wind[1]:g}) N per movable mass from step "
                       f"{self.next_step}", "wind:set")

    def offer_perturbation(self, step: int, values: Sequence[float] | np.ndarray, now: float,
                           names: Sequence[str] | None = None, untrusted: Sequence[str] = (),
                           topic: str = "its topic") -> Rejection | None:
        """A perturbation (2M,) [m] of the state of ``step``: queued if that step is not integrated yet (applied
        exactly there, in both timing modes), else rejected (stale; also untrusted publisher, queue full, beyond
        the run's last step, and the command checks)."""
        channel = self.perturbations
        if untrusted:
            rejection = channel.reject(step, "untrusted_publisher",
                                       f"{topic} has publisher(s) not in perturb_publishers ({', '.join(untrusted)})")
        elif len(channel.pending) >= MAX_PENDING_PERTURBATIONS:
            rejection = channel.reject(step, "queue_full", f"{MAX_PENDING_PERTURBATIONS} perturbations are queued")
        elif self.max_steps and step > self.max_steps:
            rejection = channel.reject(step, "too_far_ahead", f"the run ends at step {self.max_steps}")
        else:
            rejection = channel.offer(step, values, self.next_step, now, list(names) if names else None)
        if rejection is not None:
            self._emit("warning", f"{rejection.message}; not applied", f"reject:perturbation:{rejection.reason}")
        else:
            self._emit("info", f"perturbation queued for step {step}")
        return rejection

    def recorder_ack(self, step: int, untrusted: Sequence[str]) -> None:
        """The recorder acknowledged every per-step message up to ``step`` (ignored while ``untrusted`` publishers
        send acknowledgements too)."""
        if self.recorder is not None and not self.recorder.ack(step, untrusted):
            self._emit("warning", "ignored an acknowledgement on the recorder's topic: it has publishers not in "
                       "recorder_publishers", "reject:recorder_ack")

    # -- stepping ---------------------------------------------------------------------------------------------
    def announce(self, step: int, now: float) -> None:
        """``/clock`` t_``step`` goes out at ``now``: commands for earlier steps are stale from here on."""
        self.clock_sent[step] = now
        self.clock_sent.pop(step - 2 * self.p["qos_depth"], None)
        self.next_step = step

    def missing(self, step: int) -> list[str]:
        """Lockstep: the awaited sources, not silent, due at ``step``, that have no command for it yet."""
        return [s for s in self.wait_sources if not self.silent[s] and self.channels[s].due(step)
                and not self.channels[s].has(step)]

    def silence(self, source: str, why: str) -> None:
        """``source`` stopped sending (``why``): the safe command replaces it until its commands resume."""
        self.silent[source] = True
        self._emit("error", f"brain silent: {why}; the body keeps running with the safe command (trained rest "
                   "lengths, zero force) until commands resume")

    def period(self) -> float:
        """Wall seconds per step: dt / ``rate_scale`` (which can change live)."""
        return self.body.dt / self.p["rate_scale"]

    def watch_realtime(self, source: str, step: int, now: float, started: float, gone: bool, topic: str) -> None:
        """Realtime: ``source`` is silent once it sent nothing for ``command_timeout`` (counted from ``started``
        before its first command) or its publisher is ``gone``; warns when step ``step`` has no usable command."""
        ch, timeout = self.channels[source], self.p["command_timeout"]
        last, started = ch.last_received, max(started, self.resumed_at)  # a pause is no silence
        quiet = last is None or now - max(last, self.resumed_at) > timeout
        if (quiet or gone) and not self.silent[source] and (last is not None or now > started + timeout):
            self.silence(source, f"no publisher left on {topic}" if gone else f"no {source} command for {timeout:g} s")
        if not ch.has(step) and not self.silent[source]:
            self._emit("warning", f"no usable {source} command at step {step}: using the safe command",
                       f"stale:{source}")

    def _command(self, step: int) -> tuple[np.ndarray, np.ndarray | None, bool]:
        """Rest length (E,), external force (M, 2) or None (both numpy arrays of the body's dtype), and whether a safe
        value replaced a command."""
        dtype = self.np_dtype
        safe = False
        rest_cmd = self.channels["rest_length"].take(step)
        if rest_cmd is None:
            rest = self.base_np
            safe = "rest_length" in self.wait_sources
        else:
            rest = rest_cmd.values.astype(dtype, copy=False)
            self.stats.age.append(step - rest_cmd.step)
        force_cmd = self.channels["force"].take(step)
        force: np.ndarray | None = None
        if force_cmd is None:
            safe = safe or "force" in self.wait_sources
        else:
            force = force_cmd.values.astype(dtype, copy=False).reshape(-1, 2)
            self.stats.age.append(step - force_cmd.step)
        if self.wind_synchronised:  # the wind of this step (kept when it is missing: silent source)
            wind_cmd = self.channels["wind"].take(step)
            if wind_cmd is not None:
                self.wind = wind_cmd.values if wind_cmd.values.any() else None
        if self.wind is not None:
            wind = self.wind.astype(dtype)
            force = np.broadcast_to(wind, (self.body.n_movable, 2)).copy() if force is None else force + wind
        return rest, force, safe

    def _advance(self, state: BodyState | None, rest: np.ndarray,
                 force: np.ndarray | None) -> tuple[BodyState, str | None]:
        """The state after ``state`` (None: the initial state) under ``rest`` and ``force``, and why it is diverged
        (None: it is not)."""
        if state is not None and self.live_step is not None:
            new, code = self.live_step(state, rest, force)
            return new, None if code == SOUND else self.divergence_of(new)
        rest_t, force_t = torch.from_numpy(rest), None if force is None else torch.from_numpy(force)
        with torch.no_grad():
            if state is None:
                new = self.body.initial_state(1, rest_length=rest_t, external_force=force_t)
            else:
                new = self.body.step(state, rest_length=rest_t, external_force=force_t)
        return new, self.divergence_of(new)

    def rehearse(self, state: BodyState | None) -> None:
        """Compute the step after ``state`` under the trained rest lengths and throw it away (nothing of the core
        changes): the code and data of a step are then in the CPU's caches when the real one comes (realtime)."""
        if state is not None and self.live_step is not None:
            self.live_step(state, self.base_np, None)

    def divergence_of(self, state: BodyState) -> str | None:
        """Why ``state`` is diverged (non-finite, beyond 1e6 m, or about to be: ``safety.runaway``), or None."""
        try:
            self.body.check_finite(state)
        except SimulationDiverged as err:
            return str(err)
        return runaway(state.v.numpy(), state.a.numpy(), self.body.dt)

    def _reset(self, step: int) -> np.ndarray | None:
        """The accepted reset (displacements (2M,) [m]) that takes effect at ``step``, or None; a ``reset`` call
        (:attr:`control`) is a zero displacement: the layout."""
        if self.control.take_reset():
            self.channels["reset"].take(step)  # a queued body/reset of this step gives way to the call
            return np.zeros(2 * self.body.n_movable)
        if not self.channels["reset"].due(step):
            return None
        cmd = self.channels["reset"].take(step)
        return None if cmd is None else cmd.values

    def integrate(self, state: BodyState | None, step: int) -> StepOutput:
        """Step ``step`` from ``state`` (the state of step − 1; None at step 0): reset or ``MSDN.step`` under the
        commands of ``step``, divergence recovery, then the perturbation of ``step``. Raises SimulationDiverged
        when the run must stop."""
        rest, force, safe = self._command(step)
        reset = self._reset(step)
        if reset is not None:  # released from rest at layout + displacement: the state of step k, not integrated
            with torch.no_grad():
                fresh = self.body.initial_state(
                    1, rest_length=torch.from_numpy(rest), external_force=None if force is None else
                    torch.from_numpy(force), displacement=torch.from_numpy(reset.astype(self.np_dtype)).view(1, -1, 2))
            state, new = None, BodyState(fresh.r, fresh.v, fresh.a, fresh.length, step)
            problem = self.divergence_of(new)
        else:
            if self.channels["reset"].due(step) and "reset" in self.wait_sources:
                safe = True  # an awaited reset that never came: the body runs on, unreset
            new, problem = self._advance(state, rest, force)
        if problem:
            new, rest, force, safe = self._recover(state, step, problem)
        out = StepOutput(new, rest, force)
        kick = self.perturbations.take(step)
        if kick is not None:
            d = torch.from_numpy(kick.values.astype(self.np_dtype)).view(1, -1, 2)
            with torch.no_grad():  # MSDN.displaced: velocities kept, a from the rest length and force of the step
                kicked = self.body.displaced(new, d, out.rest, out.force)
            problem = self.divergence_of(kicked)
            if problem:  # the kick is dropped, not the step: the run goes on unperturbed and says so
                self._emit("error", f"the perturbation at step {step} would diverge ({problem.split(';')[0]}); not "
                           "applied", diagnostic=True)
            else:
                out.state, out.perturbation = kicked, kick.values
                self.perturbation_count += 1
                if len(self.perturbed) < LISTED_PERTURBATIONS:
                    self.perturbed.append(step)
                self._emit("info", f"step {step}: movable masses displaced (largest |d| "
                           f"{np.abs(kick.values).max():.4g} m)")
        if safe:
            self.stats.safe_steps += 1
        for source in self.wait_sources:
            self.silent_steps[source] += self.silent[source]
        self.stats.steps = step
        self.control.stepped(step)
        return out

    def _recover(self, state: BodyState | None, step: int,
                 problem: str) -> tuple[BodyState, np.ndarray, np.ndarray | None, bool]:
        """A diverged step: ``on_divergence`` restores the last good state with the safe command (rest lengths of
        the agent, no brain force; the wind stays), or the run stops (raises SimulationDiverged)."""
        rest = self.base_np
        force = None
        if self.wind is not None:
            force = np.broadcast_to(self.wind.astype(self.np_dtype), (self.body.n_movable, 2)).copy()

        def reset() -> BodyState:
            with torch.no_grad():
                fresh = self.body.initial_state(1, rest_length=self.base)
            return BodyState(fresh.r, fresh.v, fresh.a, fresh.length, step)

        new, action = self.divergence.recover(step, lambda: self._advance(state, rest, force)[0], reset,
                                              self.divergence_of)
        text = f"step {step} diverged ({problem.split(';')[0]}); {action}"
        self._emit("error", text, diagnostic=True)
        if new is None:
            self.diverged_stop = True
            raise SimulationDiverged(text)
        return new, rest, force, True

    # -- counters ---------------------------------------------------------------------------------------------
    def count_published(self, topic: str) -> None:
        """One message published on ``topic`` (counted once stepping began)."""
        if self.counting:
            self.published[topic] = self.published.get(topic, 0) + 1

    def summary(self) -> dict[str, Any]:
        """Run summary: mode, steps, timing statistics and command counts per source."""
        out: dict[str, Any] = {"mode": self.p["mode"], "dt": self.body.dt, "sim_time": self.stats.steps * self.body.dt}
        out.update(self.stats.summary())
        total = 0
        for name, ch in self.channels.items():
            for key, value in ch.counts().items():
                out[f"{name}_{key}"] = value
                if key.startswith("rejected"):
                    total += value
        for key, value in self.wind_intake.counts().items():  # unsynchronised wind; the channel counts the stamped
            out[f"wind_{key}"] = out.get(f"wind_{key}", 0) + value  # wind of a wind_source (one or the other)
            if key.startswith("rejected"):
                total += value
        for key, value in self.perturbations.counts().items():
            out[f"perturbation_{key}"] = value
            if key.startswith("rejected"):
                total += value
        out["perturbation_applied"] = self.perturbation_count
        out["perturbation_steps"] = list(self.perturbed)
        out["perturbation_pending"] = len(self.perturbations.pending)
        out["rejected_total"] = total
        out["silent_brain_steps"] = dict(self.silent_steps)
        out["divergences"] = self.divergence.events
        out["paused"] = self.control.paused
        out["control_calls"] = self.control.count
        out["control_calls_refused"] = self.control.refused
        out["pause_expired"] = self.pause_expired
        if self.recorder is not None:
            r = self.recorder
            out.update(recorder_waits=r.waits, recorder_wait_s=r.wait_s, recorder_acked_step=r.acked,
                       recorder_ack_rejected=r.rejected)
        out.update(self.phases.summary())
        out["published_messages"] = dict(self.published)
        out["rt_priority"] = self.rt_priority
        out["cpus"] = self.cpus
        return out

    def status(self, summary: Mapping[str, Any], error: str = "") -> tuple[str, str, list[tuple[str, str]]]:
        """Level (OK, WARN or ERROR), message and key/value texts of the loop's diagnostic status for ``summary``;
        ``error``: an ERROR status with that message."""
        late = summary["deadline_misses"] or summary["safe_command_steps"] or summary["rejected_total"]
        level = "ERROR" if error else "WARN" if late else "OK"
        values = [(k, f"{v:.6g}" if isinstance(v, float) else str(v)) for k, v in summary.items()]
        return level, error or ("paused: " if self.control.paused else "") + (
            f"{self.p['mode']}: step {summary['steps']}, {summary['deadline_misses']} deadline misses, "
            f"{summary['safe_command_steps']} safe-command steps, {summary['rejected_total']} rejected commands, "
            f"{summary['divergences']} divergences"), values

    def end_text(self, summary: Mapping[str, Any], diverged: bool, stop_reason: str | None) -> str:
        """The log lines at the end of a run: why it ended, after how many steps, and :func:`summary_text`."""
        why = ("stopped: paused for pause_timeout" if self.pause_expired else
               "stopped: the simulation diverged" if diverged else
               f"stopped by {stop_reason}" if stop_reason else "finished")
        return f"{why} after {summary['steps']} steps ({summary['sim_time']:.3f} s sim time)\n" + summary_text(summary)

    def describe(self, source: str, trained: bool) -> str:
        """The startup line: which body, timing mode and length, awaited sources and accepted commands."""
        body, topo, p = self.body, self.body.topology, self.p
        parts = [f"{self.max_steps} steps"] if self.max_steps else []
        if p["mode"] == "realtime" and p["wall_duration"] > 0:
            parts.append(f"{p['wall_duration']:g} s wall time")
        lim, rules = self.limits, self.publisher_rules
        return (f"{'trained' if trained else 'untrained'} body from {source}: {topo.name}, {topo.n_masses} masses "
                f"({body.n_movable} movable), {topo.n_springs} springs, dt {body.dt} s, {p['dtype']}; mode "
                f"{p['mode']}, {' or '.join(parts) or 'until stopped'}, waiting for "
                f"{', '.join(self.wait_sources) or 'no brain'}; accepting rest lengths in "
                f"({lim.min_rest_length:g}, {lim.max_rest_length:g}] m, |force| <= {lim.max_force:g} N, |wind| <= "
                f"{lim.max_wind:g} N, from {', '.join(rules['rest_length'].allowed)} (rest lengths) and "
                f"{', '.join(rules['force'].allowed)} (forces)")
