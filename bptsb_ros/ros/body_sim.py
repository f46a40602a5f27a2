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
import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, Vector3Stamped
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from bptsb_ros.interface.topics import RECORDER_ACK, absolute, stamp_to_step
from bptsb_ros.live.agent_source import load_source
from bptsb_ros.live.body_core import BodyCore, Event
from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.body_params import PARAMS, PUBLISHED, SUBSCRIBED, parse_wait_for_subscribers
from bptsb_ros.live.scheduling import (
    cpus_text,
    parse_cpus,
    pin_threads,
    set_fifo_priority_of_process,
)
from bptsb_ros.live.sim_control import CALLS
from bptsb_ros.live.summary import write_summary
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.body_graph import BodyGraph
from bptsb_ros.ros.body_outputs import WARM_UP_TOPIC, BodyOutputs
from bptsb_ros.ros.cdr_in import JointStateReader
from bptsb_ros.ros.declare_params import declare_parameters
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
#: (key, message type) of every topic the body publishes
OUTPUTS = (("clock", Clock), ("positions", PoseArray), ("mass_states", JointState), ("spring_lengths", JointState),
           ("rest_length", JointState), ("external_force", JointState), ("markers", MarkerArray),
           ("diagnostics", DiagnosticArray), ("perturbation", JointState))
#: (source, message type, topic key) of every input the body takes
INPUTS = (("rest_length", JointState, "rest_length_cmd"), ("force", JointState, "force_cmd"),
          ("wind", Vector3Stamped, "wind"), ("perturbation", JointState, "perturb_cmd"),
          ("reset", JointState, "reset_cmd"))


class BodySim(BodyOutputs, BodyGraph, Node):
    """The body simulator node; :meth:`run` integrates until done or stopped and returns the exit code."""

    def __init__(self, stop: StopFlag) -> None:
        super().__init__(NODE)
        self.stop = stop
        self.p = p = declare_parameters(self, PARAMS, on_change=lambda name, value: self.core.on_parameter(name, value))
        self.wait_subscribers = parse_wait_for_subscribers(p["wait_for_subscribers"])
        self.cpus = parse_cpus(p["cpus"])
        agent, trained = load_source(p)
        self.throttle = Throttle(1.0)
        self.core = core = BodyCore(agent, p, sink=self._on_event)
        self.body, self.dt_ns, topo = core.body, core.dt_ns, core.body.topology
        self.springs, self.fixed = np.asarray(topo.springs), np.asarray(topo.fixed)
        self.mass_diameter = 0.04 * float(np.ptp(topo.positions, axis=0).max() or 1.0)
        self.layout = self.body.positions0.detach().numpy().astype(np.float64)  # (N, 2): fixed masses stay there
        self.movable = self.body.movable_index.numpy()
        self.callbacks, self._intruders = 0, {}  # _intruders: source -> (publisher count, when, untrusted names)
        self._graph_due: set[str] = set()  # sources whose periodic graph query waits for slack (realtime)
        self._graph_cost = 0.001  # seconds a graph query took lately (with a margin)
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
        self._warm: Any = None  # the publisher of rehearse(), made on first use
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

    # -- BodyPort: what the loop needs ------------------------------------------------------------------------
    def stopped(self) -> bool:
        return bool(self.stop)

    def now(self) -> float:
        return time.monotonic()

    def spin_once(self, timeout: float) -> None:
        if timeout > 0:
            self.before_wait()
        self.executor_.spin_once(timeout_sec=timeout)
        self.after_spin()

    def drain(self) -> None:
        before = -1
        while self.callbacks != before:  # until a spin handled nothing
            before = self.callbacks
            self.executor_.spin_once(timeout_sec=0.0)
            self.after_spin()

    def after_spin(self) -> None:
        """What runs after each spin: nothing, or the brains' answers where they share this executor (composed)."""

    def before_wait(self) -> None:
        """What runs before a spin that may block (waiting for a message): nothing, or a recorder hosted in this
        process taking what is waiting (composed), in time the body would otherwise sleep."""

    def publisher_gone(self, source: str) -> bool:
        return self.subs[source].get_publisher_count() == 0

    def topic(self, source: str) -> str:
        return self.sub_topics[source]

    def log(self, level: str, text: str) -> None:
        log_line(self.get_logger(), level, text)

    # -- run ---------------------------------------------------------------------------------------------------
    def run(self) -> int:
        self.loop.wait_startup(self._startup_missing)
        for source in self.subs:  # the first command of each source then finds its publishers looked up
            self._untrusted(source, time.monotonic())
        # everything built so far (torch, numba, the agent, the middleware's objects) lives to the end: out of the
        # garbage collector's sight, a full collection during the run does not walk it (several ms a time)
        gc.collect()
        gc.freeze()
        if self.cpus:
            problem = pin_threads(self.cpus)
            self.log("warning" if problem else "info", f"{problem}; running on the CPUs it was started on" if problem
                     else f"running on CPU(s) {cpus_text(self.cpus)}")
            self.core.cpus = "any" if problem else cpus_text(self.cpus)
        if self.p["rt_priority"] and self.p["mode"] == "realtime":
            problem, others = set_fifo_priority_of_process(self.p["rt_priority"])
            self.log("warning" if problem else "info", problem + "; stepping under the normal scheduler" if problem
                     else f"stepping under SCHED_FIFO priority {self.p['rt_priority']} ({others} middleware "
                     f"thread(s) of this process at {max(1, self.p['rt_priority'] - 1)})")
            self.core.rt_priority = 0 if problem else self.p["rt_priority"]
            if self.core.rt_priority and self.p["busy_wait"] > 0:
                self._warm = self.create_publisher(PoseArray, WARM_UP_TOPIC, 1)  # made now, not in the first wait
        diverged = self.loop.run()
        summary = self.core.summary()
        self.get_logger().info(self.core.end_text(summary, diverged, self.stop.reason))
        self.diagnostics(force=True)
        summary["published_messages"] = dict(self.core.published)  # the final diagnostics included
        wait_acked(self.get_logger(), list(self.pubs.values()), self.p["final_ack_timeout"], "final_ack_timeout")
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
