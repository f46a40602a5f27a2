"""What ``body_sim`` publishes: the per-step state topics (pre-serialized where the message layout allows,
:mod:`bptsb_ros.ros.raw_out`), the slower state topics spread over the steps, the markers, and the loop status on
``diagnostics``. A part of :class:`bptsb_ros.ros.body_sim.BodySim` (its methods, on the node's publishers, core
and parameters).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseArray

from bptsb_ros.body.msdn import BodyState
from bptsb_ros.live.body_core import StepOutput
from bptsb_ros.live.body_params import SLOW_OUTPUTS
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.raw_out import RawTemplate, TemplateError

#: periods of ``diagnostics_period`` after which the loop status is published whatever the slack
DIAGNOSTICS_OVERDUE = 5
#: the hidden topic (nothing subscribes to it, recorders skip it) on which a realtime body rehearses publishing
WARM_UP_TOPIC = "~/_warm_up"


class BodyOutputs:
    """The output side of ``body_sim`` (mixed into :class:`~bptsb_ros.ros.body_sim.BodySim`)."""

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

    def rehearse(self, state: BodyState | None) -> None:
        """The step after ``state`` computed and thrown away, ``body/positions`` and ``/clock`` rendered and the
        positions sent on a hidden topic of this node that nothing subscribes to (rclpy's and the middleware's
        publishing code, without a subscriber to deliver to), so that the next real step finds them in the caches."""
        self.core.rehearse(state)
        if self._warm is None:
            self._warm = self.create_publisher(PoseArray, WARM_UP_TOPIC, 1)
        positions, clock = self.raw.get("positions"), self.raw.get("clock")
        step = state.step if state is not None else 0
        if clock is not None:
            clock.render(step)
        self._warm.publish(positions.render(step, self.layout) if positions is not None else
                           m.pose_array(step, self.dt_ns, self.layout, self.p["frame_id"]))

    def announce(self, step: int) -> None:
        self._out("clock", step, lambda k: m.clock_msg(k, self.dt_ns))

    def publish(self, out: StepOutput, views: bool = True) -> None:
        """The state of one step on the body's topics (and its perturbation, if any, first): ``body/positions``
        every step, the topics that say it again (:data:`~bptsb_ros.live.body_params.SLOW_OUTPUTS`) every
        ``state_every`` steps (:meth:`_slow_due`) or, those in ``every_step``, every step; markers every
        ``marker_every`` steps. ``views`` False: only what the loop's nodes read (the perturbation, the positions,
        the ``every_step`` topics); :meth:`publish_views` sends the rest."""
        k, ns, frame, core = out.state.step, self.dt_ns, self.p["frame_id"], self.core
        if out.perturbation is not None:
            self._publish("perturbation", m.joint_state(k, ns, core.dof_names, position=out.perturbation,
                                                        frame_id=frame))
        r = out.arrays()[0]
        full = self.layout.copy()
        full[self.movable] = r
        self._out("positions", k, lambda k, r: m.pose_array(k, ns, r, frame), full)
        self._state_topics(out, full, read=True, views=views)

    def publish_views(self, out: StepOutput) -> None:
        """What :meth:`publish` with ``views`` False left out of ``out``'s step: the thinned state topics that no
        node of the loop reads, and the markers (for viewers and the bag)."""
        full = self.layout.copy()
        full[self.movable] = out.arrays()[0]
        self._state_topics(out, full, read=False, views=True)

    def _state_topics(self, out: StepOutput, full: np.ndarray, read: bool, views: bool) -> None:
        """The slower state topics due at ``out``'s step (``read``: those of ``every_step``, which nodes of the loop
        read; ``views``: the others) and, with ``views``, the markers; ``full``: the positions of all masses (N, 2)."""
        k, ns, frame, core, p = out.state.step, self.dt_ns, self.p["frame_id"], self.core, self.p
        r, v, a, length, rest, force = out.arrays()
        every = p["every_step"]
        due = {key: on and (views if key not in every else read) for key, on in self._slow_due(k).items()}
        markers = views and k % p["marker_every"] == 0
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
        """The per-step housekeeping after each step: the loop status when it is due (:meth:`_loop_status`), then
        :meth:`after_step`."""
        self._loop_status(force, error, slack)
        self.after_step()

    def _loop_status(self, force: bool, error: str, slack: float) -> None:
        """Publish the loop status every ``diagnostics_period`` (or now when ``force`` or ``error``).

        The work (the summary with its percentiles, then the message) takes a good fraction of a millisecond, more
        than a 1 kHz realtime body has to spare after a step: with ``slack`` (seconds until the next step is due)
        it is done in two parts, each in a turn whose slack exceeds twice what that part took lately (a slowly
        decaying maximum), and in any case once it is ``DIAGNOSTICS_OVERDUE`` periods late."""
        self._refresh_graph(slack)
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

    def after_step(self) -> None:
        """What runs after each step's :meth:`diagnostics`: nothing, or a recorder hosted in this process taking what
        is waiting once its ``batch_wait`` has passed (composed: a body that never waits still records as it goes)."""

    def _status(self, level: str, message: str, values: list[tuple[str, str]], name: str = "loop") -> None:
        """Publish one DiagnosticStatus ``<node>: <name>`` stamped with the sim time of the last step."""
        status = DiagnosticStatus(level=getattr(DiagnosticStatus, level), name=f"{self.get_name()}: {name}",
                                  hardware_id=self.body.topology.name, message=message,
                                  values=[KeyValue(key=k, value=v) for k, v in values])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = m.stamp(self.core.stats.steps, self.dt_ns)
        self._publish("diagnostics", msg)
