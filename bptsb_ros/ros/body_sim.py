"""``body_sim``: the soft-body simulator node. A thin adapter: every step is ``MSDN.step``.

It loads a body (trained agent or fresh shape), publishes ``/clock`` (it is the simulator), the body
state and RViz/Foxglove markers, and integrates the rest-length and force commands of the brains
(``TOPICS.md`` lists every topic). Two timing modes:

* ``lockstep``: before integrating step k the body publishes ``/clock`` t_k and waits for the
  commands stamped t_k from every source in ``wait_for``; a live run equals the offline simulation
  of the same agent.
* ``realtime``: a wall-clock loop at rate_scale/dt that uses the newest command and reports
  jitter, deadline misses, command age and latency on ``/diagnostics`` and at shutdown.

With ``wait_for_recorder`` (lockstep runs recorded by ``bptsb launch``) the body also waits, before announcing step
k, until the recorder acknowledged on ``recorder/ack`` that it has recorded every per-step topic up to step
k − ``recorder_window``: no more than ``recorder_window`` + 1 messages of a topic are ever unrecorded, fewer than the
``qos_depth`` a reliable publisher keeps for retransmission, so none can be overwritten before the recorder has it.
A slow recorder slows the run; one that makes no progress for ``recorder_timeout`` is left behind (logged; the
recording then counts what it loses). The summary counts the messages published per topic once stepping began
(``published_messages``; empty for a run stopped during startup) so a launcher can compare them with the bag.

With ``reset_every`` = E > 0 (loop ``mnist_drawing``) the body also takes resets on ``body/reset`` at steps k with
k % E == 0 (awaited there with ``reset`` in ``wait_for``): the state of step k is then the body at rest at layout +
the reset's displacement, from which the following steps integrate (``TOPICS.md``, "Resets").

Bad commands (wrong length, NaN/inf, out of physical bounds, stale, stamped beyond the next step, or sent
while a node not in ``command_publishers`` publishes on the topic) are rejected with a log line and counted;
the rules live in ``lockstep`` and ``safety`` (ROS-free). A brain that stops sending (no command within
``command_timeout``, or its publisher gone) is replaced by the safe command — the trained rest lengths and
zero force — and the body says so, and says so again when it resumes. A step that diverges anyway is
handled by ``on_divergence`` (``safety.DivergenceRecovery``): restore the last good state with the safe
command and go on, or stop cleanly; an ERROR diagnostic is published either way.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, Vector3Stamped
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from bptsb_ros.body.msdn import BodyState, SimulationDiverged
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.agent_source import SOURCE_PARAMS, load_source
from bptsb_ros.ros.lockstep import MODES, CommandChannel, TimingStats
from bptsb_ros.ros.params import LOG_LEVEL, Param, ParameterError, ParamValue, declare_parameters
from bptsb_ros.ros.runtime import EXIT_FAILURE, EXIT_OK, StopFlag, Throttle, run_node
from bptsb_ros.ros.safety import (
    DEFAULT_MAX_FORCE,
    DEFAULT_MAX_WIND,
    DEFAULT_PERTURB_PUBLISHERS,
    DIVERGENCE_POLICIES,
    CommandLimits,
    DivergenceRecovery,
    PublisherRule,
    WindIntake,
    rest_length_floor,
    runaway,
)
from bptsb_ros.ros.topics import (
    BODY_INPUTS,
    BODY_OUTPUTS,
    COMMAND_SOURCES,
    DEFAULT_QOS_DEPTH,
    RECORDER_ACK,
    TOPICS,
    absolute,
    dt_to_ns,
    mass_dof_names,
    spring_names,
)
from bptsb_ros.sim.perturbation import perturbation

NODE = "body_sim"
#: furthest ahead [steps] a perturbation may be stamped, and the most that may wait at once
MAX_PERTURB_AHEAD = 10**9
MAX_PENDING_PERTURBATIONS = 1000
#: perturbed steps listed in the run summary (all are counted)
LISTED_PERTURBATIONS = 20
#: what the ROS graph reports as the node name of an endpoint whose node it has not discovered yet
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"
PUBLISHED = BODY_OUTPUTS
SUBSCRIBED = BODY_INPUTS

PARAMS: tuple[Param, ...] = SOURCE_PARAMS + (
    Param("mode", "lockstep", "timing mode: lockstep (deterministic, waits for commands) or realtime "
          "(wall-clock timer at rate_scale/dt)", "str", choices=MODES),
    Param("rate_scale", 1.0, "realtime: sim seconds per wall second (1 = real time); lockstep: pace of steps "
          "integrated with the safe command while a brain is silent", "float", positive=True, dynamic=True),
    Param("duration", 0.0, "sim time to run [s]; the node exits after the last step (0: run until stopped)",
          "float", minimum=0.0),
    Param("wall_duration", 0.0, "realtime: wall seconds to run from the first step, then exit (0: no limit)",
          "float", minimum=0.0),
    Param("max_steps", 0, "steps to run, overrides duration when > 0 (0: use duration)", "int", minimum=0),
    Param("wait_for", [], "command sources whose command for step k must arrive before step k is integrated "
          "in lockstep (realtime: sources watched for silence)", "str_list", choices=tuple(COMMAND_SOURCES)),
    Param("wait_for_subscribers", [], "startup: 'topic:count' entries; the first step waits until each topic "
          "has that many subscribers (e.g. the brains and the recorder)", "str_list"),
    Param("startup_timeout", 30.0, "startup: wall seconds to wait for brains and subscribers before starting "
          "anyway (silent sources get the safe command)", "float", positive=True),
    Param("command_timeout", 2.0, "wall seconds without the awaited command before a source counts as silent "
          "and the safe command is used", "float", positive=True),
    Param("max_command_age", 0.1, "realtime: oldest usable command [sim s]; older ones are stale", "float",
          positive=True),
    Param("wait_for_recorder", False, "lockstep: before announcing step k, wait until the recorder acknowledged on "
          "topics.recorder_ack that it has recorded step k - recorder_window (a lockstep recording then loses "
          "nothing)", "bool"),
    Param("recorder_window", 0, "lockstep with wait_for_recorder: steps the body may run ahead of the recorder's "
          "acknowledgement, below qos_depth; 0: qos_depth / 2", "int", minimum=0),
    Param("recorder_timeout", 30.0, "lockstep with wait_for_recorder: wall seconds without progress of the recorder's "
          "acknowledgement before the body goes on without waiting (logged; the recording counts what it loses)",
          "float", positive=True),
    Param("recorder_publishers", ["recorder"], "node names allowed to acknowledge on topics.recorder_ack; an "
          "acknowledgement is ignored while another node publishes there", "str_list"),
    Param("final_ack_timeout", 5.0, "at exit, wall seconds to wait until reliable subscribers (the recorder) "
          "acknowledged every message", "float", minimum=0.0),
    Param("marker_every", 5, "publish body/markers every this many steps", "int", minimum=1, dynamic=True),
    Param("frame_id", "msdn", "frame of positions and markers (the body plane, metres, y up)", "str"),
    Param("diagnostics_period", 1.0, "wall seconds between /diagnostics messages", "float", positive=True,
          dynamic=True),
    Param("wind", [0.0, 0.0], "constant wind force (x, y) [N] on every movable mass from the next step on, within "
          "max_wind; a message on env/wind replaces it (realtime, or lockstep runs that are not compared offline)",
          "float_list", size=2, dynamic=True),
    LOG_LEVEL,
    Param("summary_path", "", "write the run summary (timing, rejections) as JSON here at exit (empty: don't)",
          "str"),
    Param("qos_depth", DEFAULT_QOS_DEPTH, "history depth of every topic (reliable)", "int", minimum=1),
    Param("max_rest_length", 0.0, "largest accepted rest-length command [m]; 0: 10 x "
          "the diagonal of the body's bounding box", "float", minimum=0.0),
    Param("min_rest_length", 0.0, "rest-length commands must be > this [m]; 0: 0, unless the agent's SWG itself "
          "commands rest lengths <= 0 (amplitude > 1): then its lowest SWG rest length minus one full swing",
          "float"),
    Param("max_force", DEFAULT_MAX_FORCE, "largest accepted |component| of a force command [N]", "float",
          positive=True),
    Param("max_wind", DEFAULT_MAX_WIND, "largest accepted |component| of a wind message [N]", "float",
          positive=True),
    Param("command_publishers", [], "node names ('name' or '/namespace/name') allowed to publish commands; a "
          "command is rejected while any other node publishes on its topic; empty: this package's brains "
          "(swg_brain, feedback_brain: rest lengths; mlp_brain: forces; wind_source: wind; mnist_brain: resets); "
          "'*': any node", "str_list"),
    Param("perturb_at", -1.0, "sim time [s] at which the movable masses are displaced by N(0, perturb_sigma²) per "
          "coordinate (the paper's perturbation; the state of that step is displaced, velocities kept); negative: "
          "none", "float"),
    Param("perturb_sigma", 0.0, "standard deviation of the scheduled perturbation [m]", "float", minimum=0.0),
    Param("perturb_seed", 0, "seed of the scheduled perturbation's standard-normal pattern "
          "(bptsb_ros.sim.perturbation)", "int"),
    Param("perturb_publishers", list(DEFAULT_PERTURB_PUBLISHERS), "node names allowed to publish on body/perturb "
          "('*': any node)", "str_list"),
    Param("reset_every", 0, "resets (body/reset, loop mnist_drawing): the body takes a reset only at steps k with "
          "k % reset_every == 0 (with 'reset' in wait_for it waits for one there, lockstep only); the state of step k "
          "is then the body at rest at layout + displacement; 0: no resets", "int", minimum=0),
    Param("on_divergence", "restore", "when a step diverges: restore (last good state + safe command, go on) or "
          "stop (end the run cleanly); an ERROR diagnostic is published either way", "str",
          choices=DIVERGENCE_POLICIES),
) + tuple(Param(f"topics.{key}", TOPICS[key].name, f"topic name of {TOPICS[key].type}", "str")
          for key in PUBLISHED + SUBSCRIBED + (RECORDER_ACK,))


def perturb_step(at: float, dt: float, max_steps: int) -> int:
    """The step of a perturbation scheduled at sim time ``at`` >= 0 [s]: round(at / dt), at most ``max_steps``
    (the run's last step; 0: no end, then at most MAX_PERTURB_AHEAD). Raises ParameterError naming the limit
    (checked in floats first: ``at`` = 1e307 would overflow the integer conversion)."""
    limit = max_steps or MAX_PERTURB_AHEAD
    steps = at / dt
    if not math.isfinite(steps) or steps >= limit + 0.5:
        end = (f"after the run's last step ({max_steps * dt:g} s)" if max_steps else
               f"more than {MAX_PERTURB_AHEAD:g} steps ({MAX_PERTURB_AHEAD * dt:g} s) ahead")
        raise ParameterError(f"parameter 'perturb_at': {at:g} s is {end}")
    return int(round(steps))


def parse_wait_for_subscribers(entries: list[str]) -> list[tuple[str, int]]:
    """``['topic:count', ...]`` → [(topic, count)]; raises ParameterError naming the bad entry."""
    out = []
    for entry in entries:
        topic, sep, count = entry.rpartition(":")
        if not sep or not topic or not count.isdigit() or int(count) < 1:
            raise ParameterError(f"parameter 'wait_for_subscribers': entry {entry!r} must look like 'topic:count' "
                                 "with count >= 1")
        out.append((topic, int(count)))
    return out


class BodySim(Node):
    """The body simulator node; :meth:`run` integrates until done or stopped and returns the exit code."""

    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE)
        self.stop = stop
        p = declare_parameters(self, PARAMS, on_change=self._on_parameter)
        self.p = p
        self.wait_subscribers = parse_wait_for_subscribers(p["wait_for_subscribers"])
        agent, trained = load_source(p)
        self.agent = agent
        body = agent.body
        self.body = body
        body.warm_up()  # load (or compile) the step kernel now, not in the first timed step
        try:
            self.dt_ns = dt_to_ns(body.dt)
        except ValueError as err:
            raise ParameterError(f"parameter 'dt' (or the agent's time step): {err}") from None
        self.max_steps = p["max_steps"] or (int(round(p["duration"] / body.dt)) if p["duration"] > 0 else 0)
        topo = body.topology
        self.movable = body.movable_index.numpy()
        self.spring_names = spring_names(topo.n_springs)
        self.dof_names = mass_dof_names(self.movable.tolist())
        self.base = body.l.detach().clone()
        self.mass = body.mass.detach().numpy().copy()
        self.springs = np.asarray(topo.springs)
        self.fixed = np.asarray(topo.fixed)
        self.mass_diameter = 0.04 * float(np.ptp(topo.positions, axis=0).max() or 1.0)
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
        self.channels = {
            source: CommandChannel(source, size, names, p["mode"], max_age_steps=max_age,
                                   bounds=lambda values, source=source: self.limits.check(source, values))
            for source, size, names in (("rest_length", topo.n_springs, self.spring_names),
                                        ("force", 2 * body.n_movable, self.dof_names),
                                        # used when "wind" is in wait_for (a wind_source node): the wind of
                                        # step k, stamped and synchronised like a command
                                        ("wind", 2, ["x", "y"]),
                                        # body/reset: displacements (x, y) of the movable masses at steps k with
                                        # k % reset_every == 0 (every=0: resets off)
                                        ("reset", 2 * body.n_movable, self.dof_names))
        }
        self.channels["reset"].every = p["reset_every"]
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
            rejection = self.perturbations.offer(k, disp.reshape(-1), 0, time.monotonic())
            if rejection is not None:
                raise ParameterError(f"parameters perturb_at/perturb_sigma: {rejection.message}")
        self._intruders: dict[str, tuple[int, float, list[str]]] = {}
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
        self.wind: np.ndarray | None = None
        if any(p["wind"]):
            problem = self.limits.check("wind", np.asarray(p["wind"]))
            if problem:
                raise ParameterError(f"parameter 'wind': {problem}")
            self.wind = np.asarray(p["wind"], dtype=np.float64)
        self.next_step = 0
        self.stats = TimingStats()
        self.throttle = Throttle(1.0)
        self.clock_sent: dict[int, float] = {}
        self.callbacks = 0
        self.published: dict[str, int] = {}  # topic name -> messages published since stepping began
        self._counting = False  # stepping began (startup complete or given up on): publications are counted
        self.recorder_window = p["recorder_window"] or max(1, depth // 2)
        if p["recorder_window"] >= depth:
            raise ParameterError(f"parameter 'recorder_window': {p['recorder_window']} must be below qos_depth "
                                 f"({depth}): the recorder must get every message before its publisher forgets it")
        if p["wait_for_recorder"] and p["mode"] != "lockstep":
            raise ParameterError("parameter 'wait_for_recorder': only a lockstep body can wait for the recorder")
        self.recorder_acked = -1  # newest step the recorder acknowledged
        self.recorder_silent = False
        self.recorder_waits = 0
        self.recorder_wait_s = 0.0
        self.recorder_rule = PublisherRule("recorder_ack", tuple(p["recorder_publishers"]))
        self.recorder_ack_rejected = 0

        topic = {key: p[f"topics.{key}"] for key in PUBLISHED + SUBSCRIBED + (RECORDER_ACK,)}
        self.topic_names = topic
        sq = m.state_qos(depth)
        self.pubs: dict[str, Publisher] = {
            "clock": self.create_publisher(Clock, topic["clock"], sq),
            "positions": self.create_publisher(PoseArray, topic["positions"], sq),
            "mass_states": self.create_publisher(JointState, topic["mass_states"], sq),
            "spring_lengths": self.create_publisher(JointState, topic["spring_lengths"], sq),
            "rest_length": self.create_publisher(JointState, topic["rest_length"], sq),
            "external_force": self.create_publisher(JointState, topic["external_force"], sq),
            "markers": self.create_publisher(MarkerArray, topic["markers"], sq),
            "diagnostics": self.create_publisher(DiagnosticArray, topic["diagnostics"], sq),
            "perturbation": self.create_publisher(JointState, topic["perturbation"], sq),
        }
        self.subs = {
            "rest_length": self.create_subscription(JointState, topic["rest_length_cmd"],
                                                    lambda msg: self._on_command("rest_length", msg), sq),
            "force": self.create_subscription(JointState, topic["force_cmd"],
                                              lambda msg: self._on_command("force", msg), sq),
            "wind": self.create_subscription(Vector3Stamped, topic["wind"], self._on_wind, sq),
            "perturbation": self.create_subscription(JointState, topic["perturb_cmd"], self._on_perturb, sq),
            "reset": self.create_subscription(JointState, topic["reset_cmd"],
                                              lambda msg: self._on_command("reset", msg), sq),
        }
        self.ack_sub = None
        if p["wait_for_recorder"]:  # the recorder's latest acknowledgement (transient-local, depth 1)
            self.ack_sub = self.create_subscription(Clock, topic[RECORDER_ACK], self._on_recorder_ack, m.ack_qos())
        self.executor_ = SingleThreadedExecutor(context=self.context)
        self.executor_.add_node(self)
        self.next_diagnostics = time.monotonic() + p["diagnostics_period"]
        source = p["agent"] or p["config"] or f"fresh {agent.task} agent (seed {p['seed']})"
        self.get_logger().info(
            f"{'trained' if trained else 'untrained'} body from {source}: {topo.name}, {topo.n_masses} masses "
            f"({body.n_movable} movable), {topo.n_springs} springs, dt {body.dt} s, {p['dtype']}; mode "
            f"{p['mode']}, {self._length_text()}, waiting for "
            f"{', '.join(self.wait_sources) or 'no brain'}; accepting rest lengths in "
            f"({self.limits.min_rest_length:g}, {self.limits.max_rest_length:g}] m, |force| <= "
            f"{self.limits.max_force:g} N, |wind| <= {self.limits.max_wind:g} N, from "
            f"{', '.join(self.publisher_rules['rest_length'].allowed)} (rest lengths) and "
            f"{', '.join(self.publisher_rules['force'].allowed)} (forces)"
        )

    def _length_text(self) -> str:
        parts = [f"{self.max_steps} steps"] if self.max_steps else []
        if self.p["mode"] == "realtime" and self.p["wall_duration"] > 0:
            parts.append(f"{self.p['wall_duration']:g} s wall time")
        return " or ".join(parts) or "until stopped"

    # -- intake ---------------------------------------------------------------------------------
    def _on_command(self, source: str, msg: JointState) -> None:
        self.callbacks += 1
        step = m.step_of(msg.header.stamp, self.dt_ns)
        values = m.as_array(msg.effort if source == "force" else msg.position)
        now = time.monotonic()
        intruders = self._untrusted_publishers(source, now)
        if intruders:
            rejection = self.channels[source].reject(
                step, "untrusted_publisher", f"{self.subs[source].topic_name} also has publisher(s) not in "
                f"command_publishers ({', '.join(intruders)}); its commands are ignored while they publish")
        else:
            rejection = self.channels[source].offer(step, values, self.next_step, now, list(msg.name))
        if rejection is not None:
            self._warn(f"reject:{source}:{rejection.reason}", f"{rejection.message}; not integrated")
            return
        sent = self.clock_sent.get(step)
        if sent is not None:
            self.stats.latency.append(now - sent)
        if self.silent[source]:
            self.silent[source] = False
            self.get_logger().info(f"{source} commands resumed at step {step}")

    def _untrusted_publishers(self, source: str, now: float) -> list[str]:
        """Publishers on ``source``'s topic that ``command_publishers`` does not allow; the graph is queried
        again when the publisher count changes, and at least every 0.5 s."""
        count = self.subs[source].get_publisher_count()
        cached = self._intruders.get(source)
        if cached is None or cached[0] != count or now - cached[1] > 0.5:
            names = self._publisher_names(source)
            cached = (count, now if UNKNOWN_NODE not in {n for _, n in names} else -math.inf,
                      self.publisher_rules[source].untrusted(names))
            self._intruders[source] = cached
        return cached[2]

    def _publisher_names(self, source: str) -> list[tuple[str, str]]:
        """(namespace, node name) of every publisher on ``source``'s command topic (a name DDS has not
        propagated yet reads ``UNKNOWN_NODE``)."""
        infos = self.get_publishers_info_by_topic(self.subs[source].topic_name)
        return [(info.node_namespace, info.node_name) for info in infos]

    def _on_recorder_ack(self, msg: Clock) -> None:
        """The recorder has every per-step message up to the acknowledged step (used while only the allowed
        recorder publishes acknowledgements)."""
        self.callbacks += 1
        infos = self.get_publishers_info_by_topic(self.ack_sub.topic_name)
        if self.recorder_rule.untrusted([(i.node_namespace, i.node_name) for i in infos]):
            self.recorder_ack_rejected += 1
            self._warn("reject:recorder_ack", f"ignored an acknowledgement on {self.ack_sub.topic_name}: it has "
                       "publishers not in recorder_publishers")
            return
        self.recorder_acked = max(self.recorder_acked, m.step_of(msg.clock, self.dt_ns))

    def _publish(self, key: str, msg: Any) -> None:
        """Publish on the body's topic ``key`` and count it."""
        pub = self.pubs[key]
        pub.publish(msg)
        if self._counting:
            self.published[pub.topic_name] = self.published.get(pub.topic_name, 0) + 1

    def _on_wind(self, msg: Vector3Stamped) -> None:
        if "wind" in self.wait_sources:  # a synchronised wind source: stamped per step, like a command
            self._on_stamped_wind(msg)
            return
        self.callbacks += 1
        wind = np.array([msg.vector.x, msg.vector.y], dtype=np.float64)
        problem = self.wind_intake.offer(wind)
        if problem:
            self._warn("reject:wind", f"{problem}; keeping the previous wind")
            return
        self._set_wind(wind)

    def _set_wind(self, wind: np.ndarray) -> None:
        """Apply an accepted wind (x, y) [N] from the next step on (a message or the ``wind`` parameter)."""
        previous = np.zeros(2) if self.wind is None else self.wind
        self.wind = None if not wind.any() else wind
        if (wind != previous).any():
            emit, held = self.throttle("wind:set")
            if emit:
                self.get_logger().info(f"wind set to ({wind[0]:g}, {wind[1]:g}) N per movable mass from step "
                                       f"{self.next_step}" + (f" ({held} earlier changes not logged)" if held else ""))

    def _on_stamped_wind(self, msg: Vector3Stamped) -> None:
        self.callbacks += 1
        step = m.step_of(msg.header.stamp, self.dt_ns)
        now = time.monotonic()
        intruders = self._untrusted_publishers("wind", now)
        if intruders:
            rejection = self.channels["wind"].reject(
                step, "untrusted_publisher", f"{self.subs['wind'].topic_name} also has publisher(s) not in "
                f"command_publishers ({', '.join(intruders)}); its wind is ignored while they publish")
        else:
            rejection = self.channels["wind"].offer(step, [msg.vector.x, msg.vector.y], self.next_step, now)
        if rejection is not None:
            self._warn(f"reject:wind:{rejection.reason}", f"{rejection.message}; not applied")
    def _on_perturb(self, msg: JointState) -> None:
        """A perturbation for the step of its stamp: queued if that step is not integrated yet (then it is applied
        exactly there, in both timing modes), else rejected as stale."""
        self.callbacks += 1
        step = m.step_of(msg.header.stamp, self.dt_ns)
        channel = self.perturbations
        intruders = self._untrusted_publishers("perturbation", time.monotonic())
        if intruders:
            rejection = channel.reject(step, "untrusted_publisher", f"{self.subs['perturbation'].topic_name} has "
                                       f"publisher(s) not in perturb_publishers ({', '.join(intruders)})")
        elif len(channel.pending) >= MAX_PENDING_PERTURBATIONS:
            rejection = channel.reject(step, "queue_full", f"{MAX_PENDING_PERTURBATIONS} perturbations are queued")
        elif self.max_steps and step > self.max_steps:
            rejection = channel.reject(step, "too_far_ahead", f"the run ends at step {self.max_steps}")
        else:
            rejection = channel.offer(step, m.as_array(msg.position), self.next_step, time.monotonic(),
                                      list(msg.name))
        if rejection is not None:
            self._warn(f"reject:perturbation:{rejection.reason}", f"{rejection.message}; not applied")
        else:
            self.get_logger().info(f"perturbation queued for step {step}")

    def _perturb(self, state: BodyState, disp: np.ndarray, rest: torch.Tensor,
                 force: torch.Tensor | None) -> BodyState:
        """``state`` with the movable masses displaced by ``disp`` (2·M,) [m] (``MSDN.displaced``: velocities kept,
        accelerations from the rest length and force in force at that step)."""
        d = torch.from_numpy(disp).to(rest.dtype).view(1, -1, 2)
        with torch.no_grad():
            return self.body.displaced(state, d, rest, force)

    def _report_perturbation(self, step: int, disp: np.ndarray) -> None:
        """An applied perturbation: published on body/perturbation (the bag holds it), logged and counted."""
        self.perturbation_count += 1
        if len(self.perturbed) < LISTED_PERTURBATIONS:
            self.perturbed.append(step)
        self._publish("perturbation", m.joint_state(step, self.dt_ns, self.dof_names, position=disp,
                                                        frame_id=self.p["frame_id"]))
        self.get_logger().info(f"step {step}: movable masses displaced (largest |d| {np.abs(disp).max():.4g} m)")

    def _on_parameter(self, name: str, value: ParamValue) -> None:
        """A live parameter change (validated by its spec); raises ParameterError to refuse it. ``rate_scale``,
        ``marker_every``, ``diagnostics_period`` and ``log_level`` are read where they are used."""
        if name == "wind":
            wind = np.asarray(value, dtype=np.float64)
            problem = self.wind_intake.offer(wind)
            if problem:
                raise ParameterError(f"parameter 'wind': {problem}")
            self._set_wind(wind)

    def _warn(self, key: str, text: str) -> None:
        emit, held = self.throttle(key)
        if emit:
            self.get_logger().warning(text + (f" ({held} similar suppressed)" if held else ""))

    # -- helpers ----------------------------------------------------------------------------------
    def _spin_for(self, seconds: float) -> None:
        """Process callbacks for ``seconds`` (at least the ready ones), polling the stop flag."""
        end = time.monotonic() + seconds
        self._drain()
        while not self.stop:
            remaining = end - time.monotonic()
            if remaining <= 0:
                return
            self.executor_.spin_once(timeout_sec=min(remaining, 0.05))

    def _drain(self) -> None:
        """Run every callback that is ready now."""
        while True:
            before = self.callbacks
            self.executor_.spin_once(timeout_sec=0.0)
            if self.callbacks == before:
                return

    def _subscriber_count(self, topic: str) -> int:
        for key, pub in self.pubs.items():
            if absolute(self.topic_names[key], self.get_namespace()) == absolute(topic, self.get_namespace()):
                return pub.get_subscription_count()
        return self.count_subscribers(topic)

    def _publish_clock(self, step: int) -> None:
        self.clock_sent[step] = time.monotonic()
        self.clock_sent.pop(step - 2 * self.p["qos_depth"], None)
        self.next_step = step
        self._publish("clock", m.clock_msg(step, self.dt_ns))

    def _command(self, step: int) -> tuple[torch.Tensor, torch.Tensor | None, bool]:
        """Rest length (E,), external force (M, 2) or None, and whether a safe value replaced a command."""
        dtype = self.base.dtype
        safe = False
        rest_cmd = self.channels["rest_length"].take(step)
        if rest_cmd is None:
            rest = self.base
            safe = "rest_length" in self.wait_sources
        else:
            rest = torch.from_numpy(rest_cmd.values).to(dtype)
            self.stats.age.append(step - rest_cmd.step)
        force_cmd = self.channels["force"].take(step)
        force: torch.Tensor | None = None
        if force_cmd is None:
            safe = safe or "force" in self.wait_sources
        else:
            force = torch.from_numpy(force_cmd.values).to(dtype).view(-1, 2)
            self.stats.age.append(step - force_cmd.step)
        if "wind" in self.wait_sources:  # the wind of this step (kept when it is missing: silent source)
            wind_cmd = self.channels["wind"].take(step)
            if wind_cmd is not None:
                self.wind = wind_cmd.values if wind_cmd.values.any() else None
        if self.wind is not None:
            wind = torch.from_numpy(self.wind).to(dtype)
            force = wind.expand(self.body.n_movable, 2) if force is None else force + wind
        return rest, force, safe

    def _publish_state(self, state: BodyState, rest: torch.Tensor, force: torch.Tensor | None) -> None:
        k, ns, body = state.step, self.dt_ns, self.body
        r = state.r[0].numpy()
        full = body.full_positions(state.r)[0].numpy()
        length = state.length[0].numpy()
        rest_np = rest.reshape(-1).numpy()
        frame = self.p["frame_id"]
        self._publish("positions", m.pose_array(k, ns, full, frame))
        self._publish("mass_states", m.joint_state(
            k, ns, self.dof_names, position=r.reshape(-1), velocity=state.v[0].numpy().reshape(-1),
            effort=m.effort_from_acceleration(state.a[0].numpy(), self.mass), frame_id=frame))
        self._publish("spring_lengths", m.joint_state(k, ns, self.spring_names, position=length))
        self._publish("rest_length", m.joint_state(k, ns, self.spring_names, position=rest_np))
        f = np.zeros(2 * body.n_movable) if force is None else force.reshape(-1).numpy()
        self._publish("external_force", m.joint_state(k, ns, self.dof_names, effort=f, frame_id=frame))
        if k % self.p["marker_every"] == 0:
            strain = length / np.maximum(rest_np, 1e-12) - 1.0
            self._publish("markers", m.body_markers(k, ns, full, self.springs, self.fixed,
                                                        body.topology.cmp_index, strain, frame, self.mass_diameter))

    def _maybe_diagnostics(self, force: bool = False, error: str = "") -> None:
        """Publish the loop status every ``diagnostics_period`` (or now when ``force``); ``error``: an ERROR status
        with that message (a divergence)."""
        now = time.monotonic()
        if not force and not error and now < self.next_diagnostics:
            return
        self.next_diagnostics = now + self.p["diagnostics_period"]
        summary = self.summary()
        status = DiagnosticStatus()
        late = summary["deadline_misses"] or summary["safe_command_steps"] or summary["rejected_total"]
        status.level = DiagnosticStatus.ERROR if error else DiagnosticStatus.WARN if late else DiagnosticStatus.OK
        status.name = f"{self.get_name()}: loop"
        status.hardware_id = self.body.topology.name
        status.message = error or (
            f"{self.p['mode']}: step {summary['steps']}, {summary['deadline_misses']} deadline misses, "
            f"{summary['safe_command_steps']} safe-command steps, {summary['rejected_total']} rejected commands, "
            f"{summary['divergences']} divergences")
        status.values = [KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v))
                         for k, v in summary.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = m.stamp(self.stats.steps, self.dt_ns)
        self._publish("diagnostics", msg)

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
        out["divergences"] = self.divergence.events
        if self.p["wait_for_recorder"]:
            out.update(recorder_waits=self.recorder_waits, recorder_wait_s=self.recorder_wait_s,
                       recorder_acked_step=self.recorder_acked, recorder_ack_rejected=self.recorder_ack_rejected)
        out["published_messages"] = dict(self.published)
        return out

    # -- run --------------------------------------------------------------------------------------
    def _wait_startup(self) -> None:
        """Wait until every awaited brain publishes and every listed topic has its subscribers."""
        deadline = time.monotonic() + self.p["startup_timeout"]
        while not self.stop:
            missing = [f"a publisher on {self.subs[s].topic_name}" for s in self.wait_sources
                       if self.subs[s].get_publisher_count() < 1]
            missing += [f"the node names of the publishers on {self.subs[s].topic_name}" for s in self.wait_sources
                        if any(name == UNKNOWN_NODE for _, name in self._publisher_names(s))]
            missing += [f"{n} subscriber(s) on {t} (have {have})" for t, n in self.wait_subscribers
                        if (have := self._subscriber_count(t)) < n]
            if self.ack_sub is not None and self.ack_sub.get_publisher_count() < 1:
                missing.append(f"the recorder's acknowledgements on {self.ack_sub.topic_name}")
            if not missing:
                self.get_logger().info("startup complete: brains and subscribers present; running")
                return
            if time.monotonic() > deadline:
                self.get_logger().warning(f"startup: still missing {'; '.join(missing)} after "
                                          f"{self.p['startup_timeout']:g} s; starting anyway")
                return
            self._spin_for(0.05)

    def _await(self, step: int) -> None:
        """Lockstep: process callbacks until every non-silent awaited source has its command for ``step``."""
        deadline = time.monotonic() + self.p["command_timeout"]
        while not self.stop:
            self._drain()
            missing = [s for s in self.wait_sources if not self.silent[s] and self.channels[s].due(step)
                       and not self.channels[s].has(step)]
            if not missing:
                return
            now = time.monotonic()
            for s in missing:
                gone = self.subs[s].get_publisher_count() == 0
                if gone or now >= deadline:
                    self.silent[s] = True
                    why = (f"no publisher left on {self.subs[s].topic_name}" if gone else
                           f"no {s} command for step {step} within {self.p['command_timeout']:g} s")
                    self.get_logger().error(
                        f"brain silent: {why}; the body keeps running with the safe command (trained rest "
                        "lengths, zero force) until commands resume")
            if now >= deadline or all(self.silent[s] for s in missing):
                return
            self.executor_.spin_once(timeout_sec=min(0.05, deadline - now))

    def _await_recorder(self, step: int) -> None:
        """``wait_for_recorder``: process callbacks until the recorder acknowledged step − ``recorder_window``; go
        on without it once its acknowledgement made no progress for ``recorder_timeout`` (it is then silent until
        it acknowledges again)."""
        if self.ack_sub is None:
            return
        need = step - self.recorder_window
        if self.recorder_acked >= need:
            if self.recorder_silent:
                self.recorder_silent = False
                self.get_logger().info(f"the recorder caught up (acknowledged step {self.recorder_acked}); waiting "
                                       "for it again")
            return
        if self.recorder_silent:
            self._drain()
            return
        self.recorder_waits += 1
        started = progress = time.monotonic()
        seen = self.recorder_acked
        while not self.stop and self.recorder_acked < need:
            self.executor_.spin_once(timeout_sec=0.05)
            now = time.monotonic()
            if self.recorder_acked > seen:
                seen, progress = self.recorder_acked, now
            elif now - progress > self.p["recorder_timeout"]:
                self.recorder_silent = True
                self.get_logger().error(
                    f"recorder silent: no acknowledgement progress for {self.p['recorder_timeout']:g} s (it has step "
                    f"{self.recorder_acked}, step {step} needs {need}); the body goes on without waiting, and the "
                    "recording counts the messages it loses")
                break
        self.recorder_wait_s += time.monotonic() - started

    def _advance(self, state: BodyState | None, rest: torch.Tensor, force: torch.Tensor | None) -> BodyState:
        with torch.no_grad():
            if state is None:
                return self.body.initial_state(1, rest_length=rest, external_force=force)
            return self.body.step(state, rest_length=rest, external_force=force)

    def _divergence(self, state: BodyState) -> str | None:
        """Why ``state`` is diverged (non-finite, beyond 1e6 m, or about to be: ``safety.runaway``), or None."""
        try:
            self.body.check_finite(state)
        except SimulationDiverged as err:
            return str(err)
        return runaway(state.v.numpy(), state.a.numpy(), self.body.dt)

    def _integrate(self, state: BodyState | None, step: int) -> BodyState:
        rest, force, safe = self._command(step)
        reset = self._reset(step)
        if reset is not None:  # released from rest at layout + displacement: the state of step k, not integrated
            with torch.no_grad():
                fresh = self.body.initial_state(1, rest_length=rest, external_force=force,
                                                displacement=reset.to(rest.dtype).view(1, -1, 2))
            state, new = None, BodyState(fresh.r, fresh.v, fresh.a, fresh.length, step)
        elif self.channels["reset"].due(step) and "reset" in self.wait_sources:
            safe = True  # an awaited reset that never came: the body runs on, unreset
            new = self._advance(state, rest, force)
        else:
            new = self._advance(state, rest, force)
        problem = self._divergence(new)
        if problem:
            new, rest, force, safe = self._recover(state, step, problem)
        kick = self.perturbations.take(step)
        if kick is not None:
            kicked = self._perturb(new, kick.values, rest, force)
            problem = self._divergence(kicked)
            if problem:  # the kick is dropped, not the step: the run goes on unperturbed and says so
                text = f"the perturbation at step {step} would diverge ({problem.split(';')[0]}); not applied"
                self.get_logger().error(text)
                self._maybe_diagnostics(error=text)
            else:
                new = kicked
                self._report_perturbation(step, kick.values)
        if safe:
            self.stats.safe_steps += 1
        self._publish_state(new, rest, force)
        self.stats.steps = step
        return new

    def _reset(self, step: int) -> torch.Tensor | None:
        """The accepted reset (displacements (2M,) [m]) that takes effect at ``step``, or None."""
        if not self.channels["reset"].due(step):
            return None
        cmd = self.channels["reset"].take(step)
        return None if cmd is None else torch.from_numpy(cmd.values)

    def _recover(self, state: BodyState | None, step: int,
                 problem: str) -> tuple[BodyState, torch.Tensor, torch.Tensor | None, bool]:
        """A diverged step: ``on_divergence`` restores the last good state with the safe command (rest lengths of
        the agent, no brain force; the wind stays), or the run stops (raises SimulationDiverged)."""
        rest = self.base
        force = None
        if self.wind is not None:
            force = torch.from_numpy(self.wind).to(rest.dtype).expand(self.body.n_movable, 2)

        def reset() -> BodyState:
            with torch.no_grad():
                fresh = self.body.initial_state(1, rest_length=rest)
            return BodyState(fresh.r, fresh.v, fresh.a, fresh.length, step)

        new, action = self.divergence.recover(step, lambda: self._advance(state, rest, force), reset,
                                              self._divergence)
        text = f"step {step} diverged ({problem.split(';')[0]}); {action}"
        self.get_logger().error(text)
        self._maybe_diagnostics(error=text)
        if new is None:
            self.diverged_stop = True
            raise SimulationDiverged(text)
        return new, rest, force, True

    def _period(self) -> float:
        """Wall seconds per step: dt / rate_scale (``rate_scale`` can change live)."""
        return self.body.dt / self.p["rate_scale"]

    def _run_lockstep(self) -> None:
        state: BodyState | None = None
        step = 0
        last = time.monotonic()
        while not self.stop and (self.max_steps == 0 or step <= self.max_steps):
            self._await_recorder(step)
            if self.stop:
                break
            self._publish_clock(step)
            self._await(step)
            if self.stop:
                break
            if any(self.silent[s] for s in self.wait_sources):  # pace silent running at rate_scale
                self._spin_for(max(0.0, last + self._period() - time.monotonic()))
            last = time.monotonic()
            state = self._integrate(state, step)
            self.stats.compute.append(time.monotonic() - last)
            self._maybe_diagnostics()
            step += 1

    def _run_realtime(self) -> None:
        period = self._period()
        state: BodyState | None = None
        self._publish_clock(0)
        start = time.monotonic() + period
        wall_end = start + self.p["wall_duration"] if self.p["wall_duration"] > 0 else math.inf
        step = 0
        while not self.stop and (self.max_steps == 0 or step <= self.max_steps):
            if self._period() != period:  # rate_scale changed live: keep this step's due time, new pace after it
                start, period = start + step * (period - self._period()), self._period()
            due = start + step * period
            if due > wall_end:
                break
            self._spin_for(due - time.monotonic())
            if self.stop:
                break
            began = time.monotonic()
            self.stats.jitter.append(began - due)
            for s in self.wait_sources:
                self._watch_realtime(s, step, began)
            state = self._integrate(state, step)
            if (self.max_steps == 0 or step < self.max_steps) and start + (step + 1) * period <= wall_end:
                self._publish_clock(step + 1)
            done = time.monotonic()
            self.stats.compute.append(done - began)
            if done > due + period:
                self.stats.deadline_misses += 1
            self._maybe_diagnostics()
            step += 1

    def _watch_realtime(self, source: str, step: int, now: float) -> None:
        ch = self.channels[source]
        last = ch.last_received
        quiet = last is None or now - last > self.p["command_timeout"]
        gone = self.subs[source].get_publisher_count() == 0
        if (quiet or gone) and not self.silent[source] and (last is not None or now > self._started
                                                               + self.p["command_timeout"]):
            self.silent[source] = True
            why = f"no publisher left on {self.subs[source].topic_name}" if gone else (
                f"no {source} command for {self.p['command_timeout']:g} s")
            self.get_logger().error(f"brain silent: {why}; the body keeps running with the safe command "
                                    "(trained rest lengths, zero force) until commands resume")
        if not ch.has(step) and not self.silent[source]:
            self._warn(f"stale:{source}", f"no usable {source} command at step {step}: using the safe command")

    def _wait_acked(self, timeout: float) -> None:
        """Wait (up to ``timeout`` in all) until reliable subscribers acknowledged every message.

        The publishers are polled in turn, 10 ms each, until all are acknowledged or the time is up, so one dead
        subscriber (a killed brain's ``/clock`` reader) cannot use up the time of the others. DDS acknowledges
        on the writer's heartbeat (Fast DDS: every 3 s), so this can take that long. ``timeout`` 0: no wait.
        """
        if timeout <= 0:
            return
        started = time.monotonic()
        end = started + timeout
        poll = Duration(nanoseconds=10_000_000)
        pending = [pub for pub in self.pubs.values() if pub.get_subscription_count() > 0]
        while pending and time.monotonic() < end:
            pending = [pub for pub in pending if not pub.wait_for_all_acked(poll)]
        if pending:
            self.get_logger().warning(
                f"subscribers of {', '.join(pub.topic_name for pub in pending)} did not acknowledge every message "
                f"within {time.monotonic() - started:.2f} s (final_ack_timeout {timeout:g} s)")

    def run(self) -> int:
        p = self.p
        self._wait_startup()
        self._started = time.monotonic()  # start of stepping: realtime silence is counted from here
        self._counting = not self.stop  # a run stopped during startup published nothing a recorder had to get
        code = EXIT_OK
        try:
            if p["mode"] == "lockstep":
                self._run_lockstep()
            else:
                self._run_realtime()
        except SimulationDiverged as err:
            if not self.diverged_stop:
                self.get_logger().error(str(err))
            code = EXIT_FAILURE
        self._finish("stopped: the simulation diverged" if code else
                     f"stopped by {self.stop.reason}" if self.stop else "finished")
        return code

    def _finish(self, why: str) -> None:
        summary = self.summary()
        self.get_logger().info(f"{why} after {summary['steps']} steps ({summary['sim_time']:.3f} s sim time)\n"
                               + summary_text(summary))
        self._maybe_diagnostics(force=True)
        summary["published_messages"] = dict(self.published)  # the final diagnostics included
        self._wait_acked(timeout=self.p["final_ack_timeout"])
        if self.p["summary_path"]:
            path = Path(self.p["summary_path"])
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(summary, indent=2) + "\n")


def summary_text(summary: dict[str, Any]) -> str:
    """The run summary as a few readable lines: one per group of :data:`SUMMARY_GROUPS` (timing series, commands
    by source, wind), the rest on a first "run" line; floats with 4 significant digits. Rejection counters that are
    0 are left out (``rejected=0`` when all of a group are; the JSON summary keeps every counter); every other
    key appears exactly once."""
    def fmt(value: Any) -> str:
        if isinstance(value, dict):
            return "{" + ", ".join(f"{k} {v}" for k, v in value.items()) + "}"
        return f"{value:.4g}" if isinstance(value, float) else str(value)

    lines: dict[str, list[str]] = {"run": []}
    quiet: set[str] = set()
    for key, value in summary.items():
        prefix = next((pre for pre in SUMMARY_GROUPS if key.startswith(pre)), "")
        label = SUMMARY_GROUPS[prefix] if prefix else "run"
        item = key[len(prefix):]
        lines.setdefault(label, [])
        if prefix and item.startswith("rejected_") and value == 0:
            quiet.add(label)
            continue
        lines[label].append(f"{item}={fmt(value)}")
    for label in quiet:
        if not any(item.startswith("rejected_") for item in lines[label]):
            lines[label].append("rejected=0")
    width = max(map(len, lines))
    return "\n".join(f"  {label:<{width}}  {', '.join(items)}" for label, items in lines.items() if items)


#: summary key prefix -> line label of :func:`summary_text`
SUMMARY_GROUPS = {"jitter_ms_": "jitter [ms]", "compute_ms_": "compute [ms]",
                  "command_latency_ms_": "command latency [ms]", "command_age_steps_": "command age [steps]",
                  "rest_length_": "rest-length commands", "force_": "force commands", "wind_": "wind",
                  "perturbation_": "perturbations", "reset_": "resets"}


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p mode:=realtime ...``), default sys.argv."""
    return run_node(NODE, BodySim, args, params=PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
