"""The body's per-step messages (positions, mass states, spring lengths, rest lengths, external force, and markers
every ``marker_every`` steps) for ``body_sim`` to publish: serialized through :class:`~bptsb_ros.ros.cdr_template.
CdrTemplate` (no message objects in the step), or, where a template cannot be laid out, as message objects. Both
decode to the same messages (``tests/test_cdr_template.py``)."""

from __future__ import annotations

from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import ColorRGBA

from bptsb_ros.live.body_core import StepOutput
from bptsb_ros.ros import messages as m
from bptsb_ros.ros.cdr_template import PLANTED_STAMP, CdrTemplate, TemplateError, planted
from bptsb_ros.ros.topics import step_to_stamp


def _stamped(msg: Any) -> Any:
    """``msg`` (and each marker of a MarkerArray) stamped :data:`PLANTED_STAMP`."""
    for header in [mk.header for mk in msg.markers] if hasattr(msg, "markers") else [msg.header]:
        header.stamp = Time(sec=PLANTED_STAMP[0], nanosec=PLANTED_STAMP[1])
    return msg


class StepMessages:
    """The per-step messages of one body. Args: ``body`` (the MSDN), ``dof_names`` (2M,) and ``spring_names`` (E,)
    (the JointState names), ``mass`` (M,) [kg], ``frame_id``, ``dt_ns``, ``mass_diameter`` [m] (the marker size);
    ``templates``: False builds message objects every step (the reference the templates are checked against)."""

    def __init__(self, body: Any, dof_names: list[str], spring_names: list[str], mass: np.ndarray, frame_id: str,
                 dt_ns: int, mass_diameter: float, templates: bool = True) -> None:
        topo = body.topology
        self.body, self.dof_names, self.spring_names, self.mass = body, dof_names, spring_names, mass
        self.frame_id, self.dt_ns, self.mass_diameter = frame_id, dt_ns, mass_diameter
        self.springs, self.fixed, self.cmp_index = np.asarray(topo.springs), np.asarray(topo.fixed), topo.cmp_index
        self.ends = self.springs.reshape(-1)
        self.templates: dict[str, CdrTemplate] | None = None
        self.why_objects = "" if templates else "templates off"
        if templates:
            try:
                self.templates = self._templates(topo.n_masses, 2 * body.n_movable, topo.n_springs)
            except TemplateError as err:
                self.why_objects = str(err)
        n = topo.n_masses
        self._poses = np.zeros((n, 7))
        self._poses[:, 6] = 1.0  # identity orientation
        self._points = np.zeros((n, 3))

    def _templates(self, n: int, dof: int, e: int) -> dict[str, CdrTemplate]:
        names, springs, frame, ns = self.dof_names, self.spring_names, self.frame_id, self.dt_ns
        xy = planted((n, 2), 1)
        poses = np.zeros((n, 7))
        poses[:, :2], poses[:, 6] = xy, 1.0
        r, v, f, length, rest, force = (planted((size,), seed) for seed, size in
                                        ((2, dof), (3, dof), (4, dof), (5, e), (6, e), (7, dof)))
        points = np.column_stack([xy, np.zeros(n)])
        colors = planted((2 * e, 4), 8, np.float32)
        markers = m.body_markers(0, ns, xy, self.springs, self.fixed, self.cmp_index, np.zeros(e), frame,
                                 self.mass_diameter)
        markers.markers[1].colors = [ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
                                     for c in colors]
        return {
            "positions": CdrTemplate(_stamped(m.pose_array(0, ns, xy, frame)), {"poses": poses}),
            "mass_states": CdrTemplate(_stamped(m.joint_state(0, ns, names, position=r, velocity=v, effort=f,
                                                              frame_id=frame)),
                                       {"position": r, "velocity": v, "effort": f}),
            "spring_lengths": CdrTemplate(_stamped(m.joint_state(0, ns, springs, position=length)),
                                          {"position": length}),
            "rest_length": CdrTemplate(_stamped(m.joint_state(0, ns, springs, position=rest)), {"position": rest}),
            "external_force": CdrTemplate(_stamped(m.joint_state(0, ns, names, effort=force, frame_id=frame)),
                                          {"effort": force}),
            "markers": CdrTemplate(_stamped(markers), {"masses": points, "lines": points[self.ends],
                                                       "colors": colors}, stamps=2),
        }

    def messages(self, out: StepOutput, markers: bool) -> list[tuple[str, Any]]:
        """(topic key, message or serialized bytes) of the step ``out`` in publishing order; ``markers``: with the
        body's markers."""
        state, k = out.state, out.state.step
        full = self.body.full_positions(state.r)[0].numpy()
        r, v = state.r[0].numpy().reshape(-1), state.v[0].numpy().reshape(-1)
        effort = m.effort_from_acceleration(state.a[0].numpy(), self.mass)
        length, rest = state.length[0].numpy(), out.rest.reshape(-1).numpy()
        force = np.zeros(len(self.dof_names)) if out.force is None else out.force.reshape(-1).numpy()
        strain = length / np.maximum(rest, 1e-12) - 1.0 if markers else None
        t = self.templates
        if t is None:
            ns, frame, names = self.dt_ns, self.frame_id, self.dof_names
            msgs: list[tuple[str, Any]] = [
                ("positions", m.pose_array(k, ns, full, frame)),
                ("mass_states", m.joint_state(k, ns, names, position=r, velocity=v, effort=effort, frame_id=frame)),
                ("spring_lengths", m.joint_state(k, ns, self.spring_names, position=length)),
                ("rest_length", m.joint_state(k, ns, self.spring_names, position=rest)),
                ("external_force", m.joint_state(k, ns, names, effort=force, frame_id=frame))]
            if markers:
                msgs.append(("markers", m.body_markers(k, ns, full, self.springs, self.fixed, self.cmp_index, strain,
                                                       frame, self.mass_diameter)))
            return msgs
        sec, nanosec = step_to_stamp(k, self.dt_ns)
        self._poses[:, :2] = full
        msgs = [("positions", t["positions"].render(sec, nanosec, poses=self._poses)),
                ("mass_states", t["mass_states"].render(sec, nanosec, position=r, velocity=v, effort=effort)),
                ("spring_lengths", t["spring_lengths"].render(sec, nanosec, position=length)),
                ("rest_length", t["rest_length"].render(sec, nanosec, position=rest)),
                ("external_force", t["external_force"].render(sec, nanosec, effort=force))]
        if markers:
            self._points[:, :2] = full
            colors = np.repeat(m.strain_colors(strain), 2, axis=0)
            msgs.append(("markers", t["markers"].render(sec, nanosec, masses=self._points,
                                                        lines=self._points[self.ends], colors=colors)))
        return msgs
