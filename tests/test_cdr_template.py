"""The body's per-step messages written into CDR templates decode to exactly the messages rclpy serializes from the
message objects (every topic, marker steps included, stamps past the first second, strains on both sides of the
colour scale's saturation; compared decoded, since CDR's alignment padding is left uninitialised by rmw); a layout a
template cannot capture is refused with its reason."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_live_core import core

pytest.importorskip("rclpy")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from bptsb_ros.ros import messages as m  # noqa: E402
from bptsb_ros.ros.cdr_template import CdrTemplate, TemplateError, planted  # noqa: E402
from bptsb_ros.ros.step_messages import StepMessages  # noqa: E402


def builders(c):
    args = (c.body, c.dof_names, c.spring_names, c.mass, "msdn", c.dt_ns, 0.1)
    return StepMessages(*args), StepMessages(*args, templates=False)


def test_templates_equal_the_serialized_objects():
    c = core(mode="realtime")
    fast, objects = builders(c)
    assert fast.templates is not None and objects.templates is None and fast.why_objects == ""
    rng = np.random.default_rng(0)
    state, checked = None, 0
    for k in range(230):
        out = c.integrate(state, k)
        state = out.state
        if k in (0, 1, 5, 101, 229):  # a marker step, a plain one, stamps of 0 and 1 and 2 seconds
            if k == 101:  # strains beyond ±20 % (saturated colours), zero strain, and a force
                out.rest = out.state.length.reshape(-1) * torch.from_numpy(rng.uniform(0.7, 1.3, c.base.numel()))
                out.rest[3] = out.state.length.reshape(-1)[3]
                out.force = torch.from_numpy(rng.normal(size=(c.body.n_movable, 2)))
            for markers in (False, True):
                got, want = fast.messages(out, markers), objects.messages(out, markers)
                assert [key for key, _ in got] == [key for key, _ in want]
                for (key, data), (_, msg) in zip(got, want, strict=True):
                    assert isinstance(data, bytes) and len(data) == len(serialize_message(msg))
                    kind = type(msg)
                    assert deserialize_message(data, kind) == deserialize_message(serialize_message(msg), kind), \
                        f"step {k}: {key}"
                checked += 1
    assert checked == 10


def test_strain_colors_equal_the_per_spring_colours():
    strain = np.array([-0.5, -0.2, -0.07, -0.0, 0.0, 0.013, 0.2, 0.9])
    got = m.strain_colors(strain)
    want = [m._strain_color(float(s)) for s in strain]
    np.testing.assert_array_equal(got, np.array([[c.r, c.g, c.b, c.a] for c in want], dtype=np.float32))


def test_a_layout_the_template_cannot_capture_is_refused():
    values = planted((4,), 1)
    msg = m.joint_state(0, 10_000_000, ["a", "b", "c", "d"], position=values)
    with pytest.raises(TemplateError, match="planted stamp occurs 0 times"):  # never stamped with the planted stamp
        CdrTemplate(msg, {"position": values})
    twice = np.concatenate([values, values])
    msg = JointState(position=m.f64(twice))
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0x0BADCAFE, 0x1BADF00D
    with pytest.raises(TemplateError, match="block position occurs 2 times"):
        CdrTemplate(msg, {"position": values})
    template = CdrTemplate(msg, {"position": twice})
    again = JointState(position=m.f64(twice[::-1]))
    again.header.stamp.sec, again.header.stamp.nanosec = 7, 8
    assert deserialize_message(template.render(7, 8, position=twice[::-1]), JointState) == again
