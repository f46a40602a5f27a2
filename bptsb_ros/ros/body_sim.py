"""``body_sim``: the soft-body simulator node, thin glue over :mod:`bptsb_ros.live` (every step is ``MSDN.step``).

It loads a body (trained agent or fresh shape), publishes ``/clock`` (it is the simulator), the body state, markers
and ``/diagnostics``, and hands each message on its input topics (``TOPICS.md``) to
:class:`~bptsb_ros.live.body_core.BodyCore`, which holds the rules (timing modes ``lockstep``, equal to the offline
simulation, and ``realtime``; bad commands rejected and counted; the safe command for a silent brain; resets,
perturbations, divergence recovery; waiting for the recorder). The node asks the ROS graph who publishes, and
offers the simulator services ``~/pause``, ``~/resume``, ``~/step`` and ``~/reset`` (``std_srvs/srv/Trigger``;
semantics in :mod:`bptsb_ros.live.sim_control`), each call reported on ``/diagnostics``.
"""

from __future__ import annotations

import gc
import math
import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, Vector3Stamped
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from bptsb_ros.interface.topics import RECORDER_ACK, absolute, stamp_to_step
from bptsb_ros.live.agent_source import load_source
from bptsb_ros.live.body_core import BodyCore, Event, StepOutput
from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.body_params import (
    PARAMS,
    PUBLISHED,
    SLOW_OUTPUTS,
    SUBSCRIBED,
    UNKNOWN_NODE,
    parse_wait_for_subscribers,
    set_fifo_priority,
    set_fifo_priority_of_other_threads,
)
from bptsb_ros.live.sim_control import CALLS
from bptsb_ros.live.summary import write_summary
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.cdr_in import JointStateReader
from bptsb_ros.ros.declare_params import declare_parameters
from bptsb_ros.ros.raw_out import RawTemplate, TemplateError
from bptsb_ros.ros.runtime import (
    EXIT_FAILURE,
    EXIT_OK,
    StopFlag,
    Throttle,
    executor_kind,
    log_line,
    make_executor,
    run_node,
    wait_acked,
)

NODE = "body_sim"
#: periods of ``diagnostics_period`` after which the loop status is published whatever the slack
DIAGNOSTICS_OVERDUE = 5
#: (key, message type) of every topic the body publishes
OUTPUTS = (("clock", Clock), ("positions", PoseArray), ("mass_states", JointState), ("spring_lengths", JointState),
           ("rest_length", JointState), ("external_force", JointState), ("markers", MarkerArray),
           ("diagnostics", DiagnosticArray), ("perturbation", JointState))
#: (source, message type, topic key) of every input the body takes
INPUTS = (("rest_length", JointState, "rest_length_cmd"), ("force", JointState, "force_cmd"),
          ("wind", Vector3Stamped, "wind"), ("perturbation", JointState, "perturb_cmd"),
          ("reset", JointState, "reset_cmd"))


class BodySim(Node):
    """The body simulator node; :meth:`run` integrates until done or stopped and returns the exit code."""

    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE)
        self.stop = stop
        self.p = p = declare_parameters(self, PARAMS, on_change=lambda name, value: self.core.on_parameter(name, value))
        self.wait_subscribers = parse_wait_for_subscribers(p["wait_for_subscribers"])
        agent, trained = load_source(p)
        self.throttle = Throttle(1.0)
        self.core = core = BodyCore(agent, p, sink=self._on_event)
        self.body, self.dt_ns, topo = core.body, core.dt_ns, core.body.topology
        self.springs, self.fixed = np.asarray(topo.springs), np.asarray(topo.fixed)
        self.mass_diameter = 0.04 * float(np.ptp(topo.positions, axis=0).max() or 1.0)
        self.layout = self.body.positions0.detach().numpy().astype(np.float64)  # (N, 2): fixed masses stay there
        self.movable = self.body.movable_index.numpy()
        self.callbacks, self._intruders = 0, {}  # _intruders: source -> (publisher count, when, untrusted names)
        topic = {key: p[f"topics.{key}"] for key in PUBLISHED + SUBSCRIBED + (RECORDER_ACK,)}
        sq = m.state_qos(p["qos_depth"])
        self.pubs = {key: self.create_publisher(kind, topic[key], sq) for key, kind in OUTPUTS}
        self._own = {absolute(pub.topic_name, self.get_namespace()): pub for pub in self.pubs.values()}
        self.topic_names = {key: pub.topic_name for key, pub in self.pubs.items()}  # a property call costs µs
        # JointState inputs arrive as their bytes (ros.cdr_in reads the loop's own; others are deserialized)
        self.readers = {src: JointStateReader(core.spring_names if src == "rest_length" else core.dof_names)
                        for src, kind, _ in INPUTS if kind is JointState}
        self.subs = {src: self.create_subscription(kind, topic[key], lambda msg, src=src: self._on_input(src, msg), sq,
                                                   raw=src in self.readers)
                     for src, kind, key in INPUTS}
        self.sub_topics = {src: sub.topic_name for src, sub in self.subs.items()}
        self.ack_sub = self.create_subscription(Clock, topic[RECORDER_ACK], self._on_recorder_ack, m.ack_qos()) \
            if p["wait_for_recorder"] else None  # the recorder's latest acknowledgement (transient-local, depth 1)
        self.control_services = [self.create_service(Trigger, f"~/{name}", lambda _, res, name=name:
                                                     self._on_call(name, res)) for name in CALLS]
        self.executor_ = make_executor(p["executor"], self.context)
        self.executor_name = executor_kind(self.executor_)  # the one this rclpy gave (events may fall back)
        self.executor_.add_node(self)
        self.next_diagnostics = time.monotonic() + p["diagnostics_period"]
        self._pending_status: tuple[str, str, list[tuple[str, str]]] | None = None  # summed up, not yet published
        self._diagnostics_cost = [0.001, 0.001]  # seconds the two parts of the diagnostics took (with a margin)
        self.loop = BodyLoop(core, self)
        self.raw = self._templates() if p["raw_outputs"] else {}
        self.get_logger().info(core.describe(p["agent"] or p["config"] or f"fresh {agent.task} agent (seed "
                                             f"{p['seed']})", trained))

    def _on_event(self, event: Event) -> None:
        """Log a line of the core (warnings and keyed lines throttled); a divergence is also an ERROR diagnostic."""
        emit, held = self.throttle(event.key) if event.key else (True, 0)
        if emit:
            self.log(event.level, event.text + (f" ({held} similar suppressed)" if held else ""))
        if event.diagnostic:
            self.diagnostics(error=event.text)
        if event.control:
            self._status("OK" if event.control.ok else "WARN", event.text, event.control.values(), "control")

    def _on_call(self, name: str, res: Trigger.Response) -> Trigger.Response:
        """A call of ``~/<name>`` (``~/step``: ``step_count`` steps) to the core's controls, with the nodes that have
        a client of the service (the callers, held to ``control_callers``)."""
        self.callbacks += 1
        callers = self._service_clients(name)
        untrusted = self.core.control_rule.untrusted(callers)
        res.success, res.message = self.core.control.call(name, self.p["step_count"],
                                                          tuple(f"{ns.rstrip('/')}/{n}" for ns, n in callers),
                                                          tuple(untrusted))
        return res

    def _service_clients(self, name: str, wait: float = 1.0) -> list[tuple[str, str]]:
        """(namespace, node name) of every client of ``~/<name>``: the writers of its request topic (DDS name
        ``rq<service>Request``), waiting up to ``wait`` seconds while the graph has not named one yet (a client that
        stays unnamed is reported as such, and so not allowed)."""
        service = next(s for s in self.control_services if s.service_name.endswith(f"/{name}"))
        topic = f"rq{service.service_name}Request"
        deadline = time.monotonic() + wait
        while True:
            clients = [(i.node_namespace, i.node_name)
                       for i in self.get_publishers_info_by_topic(topic, no_mangle=True)]
            if all(n != UNKNOWN_NODE for _, n in clients) or time.monotonic() > deadline:
                return clients
            time.sleep(0.02)

    # -- intake: messages -> core ------------------------------------------------------------------------------
    def _on_input(self, source: str, msg: bytes | Vector3Stamped) -> None:
        """A message on ``source``'s topic, as values stamped with a step, to the core (with the graph's verdict on
        its topic's publishers); an unsynchronised wind holds from the next step on."""
        self.callbacks += 1
        now, topic = time.monotonic(), self.sub_topics[source]
        if isinstance(msg, bytes):  # a JointState: read from its bytes, or deserialized when they are not the usual
            read = self.readers[source].read(msg)
            if read is None:
                msg = deserialize_message(msg, JointState)
            else:
                step = stamp_to_step(0, read.stamp_ns, self.dt_ns)
                values, names = read.effort if source == "force" else read.position, None  # names: checked
        if not isinstance(msg, bytes):
            step = m.step_of(msg.header.stamp, self.dt_ns)
            if source == "wind":
                values, names = [msg.vector.x, msg.vector.y], None
                if not self.core.wind_synchronised:
                    self.core.offer_wind(values, self._untrusted(source, now), topic)
                    return
            else:
                values, names = m.as_array(msg.effort if source == "force" else msg.position), list(msg.name)
        if source == "perturbation":
            self.core.offer_perturbation(step, values, now, names, self._untrusted(source, now), topic)
        else:
            self.core.offer_command(source, step, values, now, names, self._untrusted(source, now), topic)

    def _on_recorder_ack(self, msg: Clock) -> None:
        self.callbacks += 1
        self.core.recorder_ack(m.step_of(msg.clock, self.dt_ns),
                               self.core.recorder.rule.untrusted(self._publisher_names(self.ack_sub.topic_name)))

    def _untrusted(self, source: str, now: float) -> list[str]:
        """Publishers on ``source``'s topic that its publisher rule does not allow; the graph is queried again when
        the publisher count changes, and at least every 0.5 s (at once while a node name is still unknown)."""
        count = self.subs[source].get_publisher_count()
        cached = self._intruders.get(source)
        if cached is None or cached[0] != count or now - cached[1] > 0.5:
            names = self._publisher_names(self.subs[source].topic_name)
            cached = (count, now if UNKNOWN_NODE not in {n for _, n in names} else -math.inf,
                      self.core.publisher_rules[source].untrusted(names))
            self._intruders[source] = cached
        return cached[2]

    def _publisher_names(self, topic: str) -> list[tuple[str, str]]:
        """(namespace, node name) of every publisher on ``topic`` (``UNKNOWN_NODE`` while DDS has not named it)."""
        return [(i.node_namespace, i.node_name) for i in self.get_publishers_info_by_topic(topic)]

    # -- BodyPort: what the loop needs ------------------------------------------------------------------------
    def stopped(self) -> bool:
        return bool(self.stop)

    def now(self) -> float:
        return time.monotonic()

    def spin_once(self, timeout: float) -> None:
        self.executor_.spin_once(timeout_sec=timeout)

    def drain(self) -> None:
        before = -1
        while self.callbacks != before:  # until a spin handled nothing
            before = self.callbacks
            self.executor_.spin_once(timeout_sec=0.0)

    def publisher_gone(self, source: str) -> bool:
        return self.subs[source].get_publisher_count() == 0

    def topic(self, source: str) -> str:
        return self.sub_topics[source]

    def log(self, level: str, text: str) -> None:
        log_line(self.get_logger(), level, text)

    def _templates(self) -> dict[str, RawTemplate]:
        """Pre-serialized messages of the per-step outputs (:mod:`bptsb_ros.ros.raw_out`): the builders' layouts
        with stamps and values rewritten each step; an output that cannot be templated keeps message objects."""
        from rclpy.serialization import deserialize_message

        ns, frame, core, n = self.dt_ns, self.p["frame_id"], self.core, self.body.topology.n_masses
        e, dof = len(core.spring_names), len(core.dof_names)
        colors = m.mass_colors(self.fixed, self.body.topology.cmp_index)
        builders = {
            "clock": (lambda k: m.clock_msg(k, ns), []),
            "positions": (lambda k, r: m.pose_array(k, ns, r, frame), [(n, 2)]),
            "mass_states": (lambda k, r, v, f: m.joint_state(k, ns, core.dof_names, position=r, velocity=v,
                                                             effort=f, frame_id=frame), [(dof,)] * 3),
            "spring_lengths": (lambda k, x: m.joint_state(k, ns, core.spring_names, position=x), [(e,)]),
            "rest_length": (lambda k, x: m.joint_state(k, ns, core.spring_names, position=x), [(e,)]),
            "external_force": (lambda k, f: m.joint_state(k, ns, core.dof_names, effort=f, frame_id=frame), [(dof,)]),
            "markers": (lambda k, r, ends, rgba: m.markers_of(k, ns, r, ends, rgba, colors, frame, self.mass_diameter),
                        [(n, 2), (2 * e, 2), ((2 * e, 4), "float32")]),
        }
        out = {}
        for key, (build, shapes) in builders.items():
            try:
                out[key] = RawTemplate(build, shapes, deserialize_message, ns)
            except TemplateError as err:
                self.get_logger().warning(f"{key}: publishing message objects ({err})")
        return out

    def _publish(self, key: str, msg: Any) -> None:
        self.pubs[key].publish(msg)
        self.core.count_published(self.topic_names[key])

    def _out(self, key: str, step: int, build: Any, *arrays: np.ndarray) -> None:
        """Publish output ``key`` of ``step``: its template's bytes, else ``build(step, *arrays)``."""
        raw = self.raw.get(key)
        self._publish(key, raw.render(step, *arrays) if raw is not None else build(step, *arrays))

    def announce(self, step: int) -> None:
        self._out("clock", step, lambda k: m.clock_msg(k, self.dt_ns))

    def publish(self, out: StepOutput) -> None:
        """The state of one step on the body's topics (and its perturbation, if any, first): ``body/positions``
        every step, the topics that say it again (:data:`~bptsb_ros.live.body_params.SLOW_OUTPUTS`) every
        ``state_every`` steps (:meth:`_slow_due`) or, those in ``every_step``, every step; markers every
        ``marker_every`` steps."""
        k, ns, frame, core, p = out.state.step, self.dt_ns, self.p["frame_id"], self.core, self.p
        if out.perturbation is not None:
            self._publish("perturbation", m.joint_state(k, ns, core.dof_names, position=out.perturbation,
                                                        frame_id=frame))
        r, v, a, length, rest, force = out.arrays()
        full = self.layout.copy()
        full[self.movable] = r
        self._out("positions", k, lambda k, r: m.pose_array(k, ns, r, frame), full)
        due = self._slow_due(k)
        markers = k % p["marker_every"] == 0
        if due["mass_states"]:
            self._out("mass_states", k, lambda k, r, v, f: m.joint_state(k, ns, core.dof_names, position=r,
                                                                         velocity=v, effort=f, frame_id=frame),
                      r.reshape(-1), v.reshape(-1), m.effort_from_acceleration(a, core.mass))
        if due["spring_lengths"]:
            self._out("spring_lengths", k, lambda k, x: m.joint_state(k, ns, core.spring_names, position=x), length)
        if due["rest_length"]:
            self._out("rest_length", k, lambda k, x: m.joint_state(k, ns, core.spring_names, position=x), rest)
        if due["external_force"]:
            f = np.zeros(2 * self.body.n_movable) if force is None else force.reshape(-1)
            self._out("external_force", k, lambda k, f: m.joint_state(k, ns, core.dof_names, effort=f,
                                                                      frame_id=frame), f)
        if markers:
            strain = length / np.maximum(rest, 1e-12) - 1.0
            if "markers" in self.raw:
                rgba = np.repeat(m.strain_colors(strain), 2, axis=0)
                self._out("markers", k, None, full, full[self.springs.reshape(-1)], rgba)
            else:
                self._publish("markers", m.body_markers(k, ns, full, self.springs, self.fixed,
                                                        self.body.topology.cmp_index, strain, frame,
                                                        self.mass_diameter))

    def _slow_due(self, step: int) -> dict[str, bool]:
        """Which of the slower state topics go out at ``step``: those in ``every_step``, and each of the others once
        every ``state_every`` steps, at steps 2, 4, 6, 8 (mod ``state_every``) in the order of
        :data:`~bptsb_ros.live.body_params.SLOW_OUTPUTS` — spread out, and beside the markers (steps 0 and 5 mod
        ``marker_every`` = 5), so that no step sends more than one message beyond its state and ``/clock``."""
        n, every = self.p["state_every"], self.p["every_step"]
        return {key: key in every or step % n == (2 * i + 2) % n for i, key in enumerate(SLOW_OUTPUTS)}

    def diagnostics(self, force: bool = False, error: str = "", slack: float = math.inf) -> None:
        """Publish the loop status every ``diagnostics_period`` (or now when ``force`` or ``error``).

        The work (the summary with its percentiles, then the message) takes a good fraction of a millisecond, more
        than a 1 kHz realtime body has to spare after a step: with ``slack`` (seconds until the next step is due)
        it is done in two parts, each in a turn whose slack exceeds twice what that part took lately (a slowly
        decaying maximum), and in any case once it is ``DIAGNOSTICS_OVERDUE`` periods late."""
        now = time.monotonic()
        if not force and not error:
            if now < self.next_diagnostics:
                return
            overdue = now - self.next_diagnostics > DIAGNOSTICS_OVERDUE * self.p["diagnostics_period"]
            if self._pending_status is None:
                if slack < self._diagnostics_cost[0] and not overdue:
                    return
                began = time.monotonic()
                self._pending_status = self.core.status(self.core.summary())
                self._diagnostics_cost[0] = max(0.9 * self._diagnostics_cost[0], 2 * (time.monotonic() - began))
                now = time.monotonic()
                slack -= now - began
            if slack < self._diagnostics_cost[1] and not overdue:
                return
            began = now
            self._status(*self._pending_status)
            self._diagnostics_cost[1] = max(0.9 * self._diagnostics_cost[1], 2 * (time.monotonic() - began))
        else:
            self._status(*self.core.status(self.core.summary(), error))
        self._pending_status = None
        self.next_diagnostics = now + self.p["diagnostics_period"]

    def _status(self, level: str, message: str, values: list[tuple[str, str]], name: str = "loop") -> None:
        """Publish one DiagnosticStatus ``<node>: <name>`` stamped with the sim time of the last step."""
        status = DiagnosticStatus(level=getattr(DiagnosticStatus, level), name=f"{self.get_name()}: {name}",
                                  hardware_id=self.body.topology.name, message=message,
                                  values=[KeyValue(key=k, value=v) for k, v in values])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = m.stamp(self.core.stats.steps, self.dt_ns)
        self._publish("diagnostics", msg)

    # -- run ---------------------------------------------------------------------------------------------------
    def _startup_missing(self) -> list[str]:
        """What the first step still waits for: a publisher (with its node name known) on every awaited source's
        topic, the listed subscribers, the recorder's acknowledgements."""
        waited = [self.subs[s] for s in self.core.wait_sources]
        missing = [f"a publisher on {s.topic_name}" for s in waited if s.get_publisher_count() < 1]
        missing += [f"the node names of the publishers on {s.topic_name}" for s in waited
                    if any(name == UNKNOWN_NODE for _, name in self._publisher_names(s.topic_name))]
        missing += [f"{n} subscriber(s) on {t} (have {have})" for t, n in self.wait_subscribers
                    if (have := self._subscriber_count(t)) < n]
        if self.ack_sub is not None and self.ack_sub.get_publisher_count() < 1:
            missing.append(f"the recorder's acknowledgements on {self.ack_sub.topic_name}")
        return missing

    def _subscriber_count(self, topic: str) -> int:
        pub = self._own.get(absolute(topic, self.get_namespace()))  # our own publisher's count, if it is ours
        return pub.get_subscription_count() if pub else self.count_subscribers(topic)

    def run(self) -> int:
        self.loop.wait_startup(self._startup_missing)
        # everything built so far (torch, numba, the agent, the middleware's objects) lives to the end: out of the
        # garbage collector's sight, a full collection during the run does not walk it (several ms a time)
        gc.collect()
        gc.freeze()
        if self.p["rt_priority"] and self.p["mode"] == "realtime":
            problem = set_fifo_priority(self.p["rt_priority"])
            below = max(1, self.p["rt_priority"] - 1)
            others = 0 if problem else set_fifo_priority_of_other_threads(below)
            self.log("warning" if problem else "info", problem + "; stepping under the normal scheduler" if problem
                     else f"stepping under SCHED_FIFO priority {self.p['rt_priority']} ({others} middleware "
                     f"thread(s) of this process at {below})")
            self.core.rt_priority = 0 if problem else self.p["rt_priority"]
        diverged = self.loop.run()
        summary = self.core.summary()
        self.get_logger().info(self.core.end_text(summary, diverged, self.stop.reason))
        self.diagnostics(force=True)
        summary["published_messages"] = dict(self.core.published)  # the final diagnostics included
        wait_acked(self.get_logger(), list(self.pubs.values()), self.p["final_ack_timeout"])
        if self.p["summary_path"]:
            write_summary(self.p["summary_path"], summary)
        if self.core.step_times is not None:
            self.core.step_times.save(self.p["timing_path"], self.core.period(), {"executor": self.executor_name})
        return EXIT_FAILURE if diverged else EXIT_OK


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p mode:=realtime ...``), default sys.argv."""
    return run_node(NODE, BodySim, args, params=PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
