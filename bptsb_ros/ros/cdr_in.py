"""Incoming loop messages read straight from their CDR bytes: the step of a ``/clock`` tick and the stamp, joint
names and float arrays of a ``sensor_msgs/JointState``, without rclpy's deserializer.

``rclpy.serialization.deserialize_message`` builds a Python object field by field: a ``JointState`` with 48 names
costs about 40 µs, most of it the names. The loop's own nodes publish exact CDR (:mod:`bptsb_ros.ros.raw_out`), whose
name list is the same bytes in every message; :class:`JointStateReader` compares that block with the expected one in
one ``bytes`` comparison and views the arrays with ``numpy.frombuffer``.

Only messages it can read unambiguously take this path: little-endian CDR, the expected names (or none), and nothing
after the last array but alignment padding (at most 3 bytes). Anything else — other names, other padding, a
big-endian or truncated message, trailing bytes — returns None, and the node deserializes the message with rclpy as
before, so every check on a message (names, length, finiteness) sees the same values either way.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
#: the encapsulation header of little-endian plain CDR
CDR_LE = b"\x00\x01"
NS_PER_S = 1_000_000_000


def stamp_ns(data: bytes) -> int | None:
    """The time [ns] of a little-endian CDR message that starts with a ``builtin_interfaces/Time`` (``/clock``) or
    a ``std_msgs/Header`` (every stamped message), or None (not little-endian CDR, or too short)."""
    if len(data) < 12 or data[:2] != CDR_LE:
        return None
    sec, nanosec = _STAMP.unpack_from(data, 4)
    return sec * NS_PER_S + nanosec


def name_block(names: Sequence[str]) -> bytes:
    """The CDR of a ``string[]`` holding ``names`` (count, then each string with its length and NUL, aligned to 4).
    Every byte of it is the same wherever it starts in a message (it starts 4-aligned), padding written as zeros."""
    out = bytearray(_U32.pack(len(names)))
    for name in names:
        raw = name.encode("utf-8") + b"\x00"
        out += _U32.pack(len(raw)) + raw
        out += b"\x00" * (-len(out) % 4)
    return bytes(out)


@dataclass(frozen=True)
class JointStateValues:
    """What a ``JointState`` holds: stamp [ns], whether it carried names (the expected ones; False: none), and the
    three float64 arrays (read-only views of the message bytes)."""

    stamp_ns: int
    named: bool
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


class JointStateReader:
    """Reads ``JointState`` CDR whose names are ``names`` or empty (see the module docstring)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = name_block(names)

    def read(self, data: bytes) -> JointStateValues | None:
        """The values of ``data``, or None when it is not a message this reader reads unambiguously."""
        n = len(data)
        if n < 16 or data[:2] != CDR_LE:
            return None
        try:
            sec, nanosec = _STAMP.unpack_from(data, 4)
            at = 16 + _U32.unpack_from(data, 12)[0]  # past frame_id (its length counts the NUL)
            at += -(at - 4) % 4  # CDR aligns relative to the payload, which starts after the 4-byte header
            count = _U32.unpack_from(data, at)[0]
            if count:
                end = at + len(self.names)
                if data[at:end] != self.names:
                    return None
                at = end
            else:
                at += 4
            arrays = []
            for _ in range(3):
                at += -(at - 4) % 4
                size = _U32.unpack_from(data, at)[0]
                at += 4
                if size:
                    at += -(at - 4) % 8
                    if at + 8 * size > n:
                        return None
                    arrays.append(np.frombuffer(data, dtype="<f8", count=size, offset=at))
                    at += 8 * size
                else:
                    arrays.append(np.zeros(0))
        except struct.error:  # a length that points past the end
            return None
        if at > n or n - at > 3:  # nothing but alignment padding may follow the last array
            return None
        return JointStateValues(sec * NS_PER_S + nanosec, bool(count), *arrays)


class PoseArrayReader:
    """Reads ``geometry_msgs/PoseArray`` CDR (little endian, nothing after the last pose but padding)."""

    def read(self, data: bytes) -> tuple[int, np.ndarray] | None:
        """(stamp [ns], positions (N, 2): the poses' x and y, a read-only view), or None when ``data`` is not a
        message this reader reads unambiguously."""
        n = len(data)
        if n < 16 or data[:2] != CDR_LE:
            return None
        try:
            sec, nanosec = _STAMP.unpack_from(data, 4)
            at = 16 + _U32.unpack_from(data, 12)[0]
            at += -(at - 4) % 4
            count = _U32.unpack_from(data, at)[0]
        except struct.error:
            return None
        at += 4
        if count:
            at += -(at - 4) % 8  # a Pose is 7 float64: position x, y, z and orientation x, y, z, w
            if at + 56 * count > n:
                return None
            xy = np.frombuffer(data, dtype="<f8", count=7 * count, offset=at).reshape(count, 7)[:, :2]
            at += 56 * count
        else:
            xy = np.zeros((0, 2))
        if at > n or n - at > 3:
            return None
        return sec * NS_PER_S + nanosec, xy
