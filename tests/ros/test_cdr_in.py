"""Reading loop messages from their CDR bytes (:mod:`bptsb_ros.ros.cdr_in`): the values rclpy's deserializer gives,
for every layout the nodes publish; and every message it cannot read unambiguously is handed back (None), so the node
deserializes it as before. Also the quick bounds test of the body's command intake, both sides."""

from __future__ import annotations

import struct

import numpy as np
import pytest

rclpy_serialization = pytest.importorskip("rclpy.serialization")

DT_NS = 10_000_000
NAMES = [f"spring_{e}" for e in range(48)]


def _exact(msg) -> bytes:
    from bptsb_ros.ros.raw_out import exact_cdr

    return exact_cdr(msg)


def test_joint_states_of_every_layout_read_as_rclpy_reads_them():
    from sensor_msgs.msg import JointState

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.cdr_in import JointStateReader

    reader = JointStateReader(NAMES)
    rng = np.random.default_rng(0)
    for trial in range(60):
        fields = {f: rng.standard_normal(48) for f in ("position", "velocity", "effort") if rng.random() < 0.6}
        frame = "x" * (trial % 7)  # every alignment of what follows the frame id
        names = NAMES if trial % 3 else []
        msg = m.joint_state(int(rng.integers(0, 10**6)), DT_NS, names, frame_id=frame, **fields)
        data = _exact(msg)
        got, want = reader.read(data), rclpy_serialization.deserialize_message(data, JointState)
        assert got is not None and got.named == bool(names)
        assert got.stamp_ns == want.header.stamp.sec * 1_000_000_000 + want.header.stamp.nanosec
        for f in ("position", "velocity", "effort"):
            assert np.array_equal(getattr(got, f), np.asarray(getattr(want, f)))


def test_anything_unusual_goes_back_to_the_deserializer():
    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.cdr_in import JointStateReader

    reader = JointStateReader(NAMES)
    good = _exact(m.joint_state(7, DT_NS, NAMES, position=np.arange(48.0)))
    assert reader.read(good) is not None
    other_names = _exact(m.joint_state(7, DT_NS, [f"spring_{e}" for e in range(1, 49)], position=np.arange(48.0)))
    big_endian = b"\x00\x00" + good[2:]
    trailing = good + b"\x00" * 8  # what rclpy's own serializer leaves after a message with empty arrays
    padding_only = good + b"\x00" * 3
    assert reader.read(other_names) is None and reader.read(big_endian) is None and reader.read(trailing) is None
    assert reader.read(padding_only) is not None
    for cut in (3, 15, 40, len(good) - 1):
        assert reader.read(good[:cut]) is None
    huge = bytearray(good)  # a position count pointing past the end of the message
    start = good.find(np.arange(48.0).tobytes())  # the doubles; their count is 4 or 8 bytes before (alignment)
    at = next(a for a in (start - 4, start - 8) if good[a:a + 4] == struct.pack("<I", 48))
    huge[at:at + 4] = struct.pack("<I", 10**6)
    assert reader.read(bytes(huge)) is None


def test_positions_and_clock_ticks():
    from geometry_msgs.msg import PoseArray

    from bptsb_ros.ros import messages as m
    from bptsb_ros.ros.cdr_in import PoseArrayReader, stamp_ns

    xy = np.random.default_rng(1).uniform(-2, 2, (25, 2))
    for frame in ("msdn", "robot1/msdn", ""):
        data = _exact(m.pose_array(417, DT_NS, xy, frame))
        ns, got = PoseArrayReader().read(data)
        assert ns == 417 * DT_NS and np.array_equal(got, xy)
        assert np.array_equal(got, m.pose_array_positions(rclpy_serialization.deserialize_message(data, PoseArray)))
        assert PoseArrayReader().read(data + b"\x00" * 4) is None
    assert stamp_ns(_exact(m.clock_msg(123_456, DT_NS))) == 123_456 * DT_NS
    assert stamp_ns(b"\x00\x00" + _exact(m.clock_msg(1, DT_NS))[2:]) is None  # big endian: deserialized instead


def test_the_quick_bounds_test_only_passes_what_the_full_checks_pass():
    from bptsb_ros.live.safety import CommandLimits

    limits = CommandLimits(max_rest_length=3.0, max_force=10.0, max_wind=2.0, min_rest_length=0.5)
    ok = {"rest_length": [0.5 + 1e-9, 3.0], "force": [-10.0, 10.0], "wind": [-2.0, 2.0]}
    bad = {"rest_length": [0.5, 3.0 + 1e-9], "force": [-10.000001, 10.5], "wind": [2.1, -2.5]}
    for source in ok:
        assert limits.surely_within(source, np.array(ok[source]))
        assert limits.check(source, np.array(ok[source])) is None
        for value in bad[source]:
            vals = np.array([ok[source][0], value])
            assert not limits.surely_within(source, vals) and limits.check(source, vals) is not None
        for value in (np.nan, np.inf, -np.inf):
            assert not limits.surely_within(source, np.array([ok[source][0], value]))
    assert not limits.surely_within("reset", np.zeros(4))  # resets are always checked in full
