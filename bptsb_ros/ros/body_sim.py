"""``body_sim``: the soft-body simulator node, thin glue over :mod:`bptsb_ros.live` (every step is ``MSDN.step``).

It loads a body (trained agent or fresh shape), publishes ``/clock`` (it is the simulator), the body state and
RViz/Foxglove markers, and hands the brains' commands to :class:`~bptsb_ros.live.body_core.BodyCore` (``TOPICS.md``
lists every topic). :class:`~bptsb_ros.live.body_loop.BodyLoop` runs the steps in either timing mode:

* ``lockstep``: before integrating step k the body publishes ``/clock`` t_k and waits for the commands stamped t_k
  from every source in ``wait_for``; a live run equals the offline simulation of the same agent.
* ``realtime``: a wall-clock loop at rate_scale/dt that uses the newest command and reports jitter, deadline
  misses, command age and latency on ``/diagnostics`` and at shutdown.

With ``wait_for_recorder`` the body also waits, before announcing step k, until the recorder acknowledged on
``recorder/ack`` every per-step topic up to step k − ``recorder_window`` (below the ``qos_depth`` a reliable
publisher keeps, so nothing is overwritten before the recorder has it). The summary counts the messages published
per topic once stepping began (``published_messages``) so a launcher can compare them with the bag.

With ``reset_every`` = E > 0 (loop ``mnist_drawing``) the body takes resets on ``body/reset`` at steps k with
k % E == 0: the state of step k is then the body at rest at layout + the reset's displacement.

Bad commands (wrong length, NaN/inf, out of physical bounds, stale, stamped beyond the next step, or sent while a
node not in ``command_publishers`` publishes on the topic) are rejected with a log line and counted; a brain that
stops sending is replaced by the safe command (trained rest lengths, zero force); a step that diverges is handled
by ``on_divergence``. The rules live in ``bptsb_ros.live`` (ROS-free); this node asks the ROS graph who publishes.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray, Vector3Stamped
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from bptsb_ros.live.body_core import BodyCore, Event, StepOutput, summary_text, write_summary
from bptsb_ros.live.body_loop import BodyLoop
from bptsb_ros.live.body_params import PARAMS, PUBLISHED, SUBSCRIBED, UNKNOWN_NODE, parse_wait_for_subscribers
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.agent_source import load_source
from bptsb_ros.ros.params import declare_parameters
from bptsb_ros.ros.runtime import EXIT_FAILURE, EXIT_OK, StopFlag, Throttle, run_node
from bptsb_ros.ros.topics import RECORDER_ACK, absolute

NODE = "body_sim"
#: (key, message type) of every topic the body publishes
OUTPUTS = (("clock", Clock), ("positions", PoseArray), ("mass_states", JointState), ("spring_lengths", JointState),
           ("rest_length", JointState), ("external_force", JointState), ("markers", MarkerArray),
           ("diagnostics", DiagnosticArray), ("perturbation", JointState))


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
        self.body, self.dt_ns = core.body, core.dt_ns
        topo = core.body.topology
        self.springs, self.fixed = np.asarray(topo.springs), np.asarray(topo.fixed)
        self.mass_diameter = 0.04 * float(np.ptp(topo.positions, axis=0).max() or 1.0)
        self.callbacks = 0
        self._intruders: dict[str, tuple[int, float, list[str]]] = {}
        self.topic_names = topic = {key: p[f"topics.{key}"] for key in PUBLISHED + SUBSCRIBED + (RECORDER_ACK,)}
        sq = m.state_qos(p["qos_depth"])
        self.pubs = {key: self.create_publisher(kind, topic[key], sq) for key, kind in OUTPUTS}
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
        self.loop = BodyLoop(core, self)
        self.get_logger().info(core.describe(p["agent"] or p["config"] or f"fresh {agent.task} agent (seed "
                                             f"{p['seed']})", trained))

    def _on_event(self, event: Event) -> None:
        """Log a line of the core (warnings and keyed lines throttled); a divergence is also an ERROR diagnostic."""
        emit, held = self.throttle(event.key) if event.key else (True, 0)
        if emit:
            self.log(event.level, event.text + (f" ({held} similar suppressed)" if held else ""))
        if event.diagnostic:
            self.diagnostics(error=event.text)

    # -- intake: messages -> core ------------------------------------------------------------------------------
    def _on_command(self, source: str, msg: JointState) -> None:
        self.callbacks += 1
        now = time.monotonic()
        self.core.offer_command(source, m.step_of(msg.header.stamp, self.dt_ns),
                                m.as_array(msg.effort if source == "force" else msg.position), now, list(msg.name),
                                self._untrusted(source, now), self.subs[source].topic_name)

    def _on_wind(self, msg: Vector3Stamped) -> None:
        self.callbacks += 1
        xy = [msg.vector.x, msg.vector.y]
        if not self.core.wind_synchronised:
            self.core.offer_wind(xy)
            return
        now = time.monotonic()
        self.core.offer_command("wind", m.step_of(msg.header.stamp, self.dt_ns), xy, now, None,
                                self._untrusted("wind", now), self.subs["wind"].topic_name)

    def _on_perturb(self, msg: JointState) -> None:
        self.callbacks += 1
        now = time.monotonic()
        self.core.offer_perturbation(m.step_of(msg.header.stamp, self.dt_ns), m.as_array(msg.position), now,
                                     list(msg.name), self._untrusted("perturbation", now),
                                     self.subs["perturbation"].topic_name)

    def _on_recorder_ack(self, msg: Clock) -> None:
        self.callbacks += 1
        gate = self.core.recorder
        self.core.recorder_ack(m.step_of(msg.clock, self.dt_ns),
                               gate.rule.untrusted(self._publisher_names(self.ack_sub.topic_name)))

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
        while True:
            before = self.callbacks
            self.executor_.spin_once(timeout_sec=0.0)
            if self.callbacks == before:
                return

    def publisher_gone(self, source: str) -> bool:
        return self.subs[source].get_publisher_count() == 0

    def topic(self, source: str) -> str:
        return self.subs[source].topic_name

    def log(self, level: str, text: str) -> None:
        logger = self.get_logger()  # one call site per severity: rclpy refuses a site whose severity changes
        if level == "error":
            logger.error(text)
        elif level == "warning":
            logger.warning(text)
        else:
            logger.info(text)

    def _publish(self, key: str, msg: Any) -> None:
        pub = self.pubs[key]
        pub.publish(msg)
        self.core.count_published(pub.topic_name)

    def announce(self, step: int) -> None:
        self._publish("clock", m.clock_msg(step, self.dt_ns))

    def publish(self, out: StepOutput) -> None:
        """The state of one step on the body's topics (and its perturbation, if any, first)."""
        state, k, ns, frame, core = out.state, out.state.step, self.dt_ns, self.p["frame_id"], self.core
        if out.perturbation is not None:
            self._publish("perturbation", m.joint_state(k, ns, core.dof_names, position=out.perturbation,
                                                        frame_id=frame))
        full = self.body.full_positions(state.r)[0].numpy()
        length, rest = state.length[0].numpy(), out.rest.reshape(-1).numpy()
        self._publish("positions", m.pose_array(k, ns, full, frame))
        self._publish("mass_states", m.joint_state(
            k, ns, core.dof_names, position=state.r[0].numpy().reshape(-1), velocity=state.v[0].numpy().reshape(-1),
            effort=m.effort_from_acceleration(state.a[0].numpy(), core.mass), frame_id=frame))
        self._publish("spring_lengths", m.joint_state(k, ns, core.spring_names, position=length))
        self._publish("rest_length", m.joint_state(k, ns, core.spring_names, position=rest))
        f = np.zeros(2 * self.body.n_movable) if out.force is None else out.force.reshape(-1).numpy()
        self._publish("external_force", m.joint_state(k, ns, core.dof_names, effort=f, frame_id=frame))
        if k % self.p["marker_every"] == 0:
            strain = length / np.maximum(rest, 1e-12) - 1.0
            self._publish("markers", m.body_markers(k, ns, full, self.springs, self.fixed,
                                                    self.body.topology.cmp_index, strain, frame, self.mass_diameter))

    def diagnostics(self, force: bool = False, error: str = "") -> None:
        """Publish the loop status every ``diagnostics_period`` (or now when ``force`` or ``error``)."""
        now = time.monotonic()
        if not force and not error and now < self.next_diagnostics:
            return
        self.next_diagnostics = now + self.p["diagnostics_period"]
        summary = self.core.summary()
        level, message = self.core.status(summary, error)
        status = DiagnosticStatus(level=getattr(DiagnosticStatus, level), name=f"{self.get_name()}: loop",
                                  hardware_id=self.body.topology.name, message=message)
        status.values = [KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v))
                         for k, v in summary.items()]
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = m.stamp(self.core.stats.steps, self.dt_ns)
        self._publish("diagnostics", msg)

    # -- run ---------------------------------------------------------------------------------------------------
    def _wait_startup(self) -> None:
        """Wait until every awaited brain publishes (with its node name known) and every listed topic has its
        subscribers, or ``startup_timeout`` passed."""
        deadline = time.monotonic() + self.p["startup_timeout"]
        waited = [self.subs[s] for s in self.core.wait_sources]
        while not self.stop:
            missing = [f"a publisher on {s.topic_name}" for s in waited if s.get_publisher_count() < 1]
            missing += [f"the node names of the publishers on {s.topic_name}" for s in waited
                        if any(name == UNKNOWN_NODE for _, name in self._publisher_names(s.topic_name))]
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
            self.loop.spin_for(0.05)

    def _subscriber_count(self, topic: str) -> int:
        ns = self.get_namespace()
        for key, pub in self.pubs.items():
            if absolute(self.topic_names[key], ns) == absolute(topic, ns):
                return pub.get_subscription_count()
        return self.count_subscribers(topic)

    def _wait_acked(self, timeout: float) -> None:
        """Wait (up to ``timeout`` in all; 0: not at all) until reliable subscribers acknowledged every message,
        polling the publishers in turn, 10 ms each, so one dead subscriber cannot use up the time of the others."""
        started = time.monotonic()
        poll = Duration(nanoseconds=10_000_000)
        pending = [pub for pub in self.pubs.values() if pub.get_subscription_count() > 0] if timeout > 0 else []
        while pending and time.monotonic() < started + timeout:
            pending = [pub for pub in pending if not pub.wait_for_all_acked(poll)]
        if pending:
            self.get_logger().warning(
                f"subscribers of {', '.join(pub.topic_name for pub in pending)} did not acknowledge every message "
                f"within {time.monotonic() - started:.2f} s (final_ack_timeout {timeout:g} s)")

    def run(self) -> int:
        self._wait_startup()
        diverged = self.loop.run()
        why = ("stopped: the simulation diverged" if diverged else
               f"stopped by {self.stop.reason}" if self.stop else "finished")
        summary = self.core.summary()
        self.get_logger().info(f"{why} after {summary['steps']} steps ({summary['sim_time']:.3f} s sim time)\n"
                               + summary_text(summary))
        self.diagnostics(force=True)
        summary["published_messages"] = dict(self.core.published)  # the final diagnostics included
        self._wait_acked(timeout=self.p["final_ack_timeout"])
        if self.p["summary_path"]:
            write_summary(self.p["summary_path"], summary)
        return EXIT_FAILURE if diverged else EXIT_OK


def main(args: list[str] | None = None) -> int:
    """Run the node; ``args`` are ROS arguments (``--ros-args -p mode:=realtime ...``), default sys.argv."""
    return run_node(NODE, BodySim, args, params=PARAMS, summary=__doc__ or "")


if __name__ == "__main__":
    sys.exit(main())
