"""Pre-serialized outgoing messages: the CDR bytes of a message whose layout is the same every step, with its stamps
and float arrays rewritten in place (no message objects built or converted per step).

``rclpy`` converts a Python message field by field before it serializes it: a ``PoseArray`` of 33 poses costs
hundreds of microseconds per step, a ``MarkerArray`` milliseconds. A :class:`RawTemplate` is made once from the
same builder function the node would call every step (:mod:`bptsb_ros.ros.messages`): it serializes the builder's
message for *sentinel* values, finds where each stamp and each value lies in the bytes, and from then on writes a
step's stamp and values into those places of one buffer; ``Publisher.publish`` sends the bytes as they are.

The bytes are exact CDR (:func:`exact_cdr`): made by the strict serializer of ``rosbags`` from the builder's message,
with zeros in the alignment padding and nothing after the last field, so every reader accepts them (``rosbags``'
``deserialize_cdr`` refuses a message with more than 3 bytes after its content, and ``rclpy.serialize_message``
leaves up to 8 unwritten bytes after a ``JointState`` with empty arrays: bags of bptsb_ros 0.2.0 and older carry
them on their ``JointState`` topics). The template checks at construction that its bytes for a second, random set of
values are the exact CDR of the builder's message for those values, byte for byte, and that rclpy reads them as
that message; it refuses itself (:class:`TemplateError`) when they are not, and the node then publishes message
objects as before.
"""

from __future__ import annotations

import array
import functools
import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

#: a step whose stamp (sec, nanosec) the builder's output is searched for; any 10 ms-grid step far from real runs
SENTINEL_STEP = 987_654_321


class TemplateError(ValueError):
    """The message cannot be templated: a sentinel was not found, or a check render differed."""


def _sentinels(shape: tuple[int, ...], dtype: np.dtype, salt: int) -> np.ndarray:
    """Distinct values of ``dtype`` whose bytes are unlikely anywhere else in a message (tiny subnormal-free floats
    with a per-field ``salt``)."""
    n = int(np.prod(shape))
    base = (1.0e-200 if dtype == np.float64 else 1.0e-30) * 2.0 ** (salt + 1)
    return (base * (1.0 + np.arange(n, dtype=np.float64) * 1e-5)).astype(dtype).reshape(shape)


def _find_each(data: bytes, values: np.ndarray) -> np.ndarray:
    """Byte offset of every element of ``values`` in ``data``: its first occurrence (a wrong pick cannot pass
    unnoticed: the check render would then differ)."""
    out = np.empty(values.size, dtype=np.int64)
    for i, value in enumerate(values.reshape(-1)):
        at = data.find(value.tobytes())
        if at < 0:
            raise TemplateError(f"value {i} of a field not found in the bytes")
        out[i] = at
    return out


def ros_type_name(msg: Any) -> str:
    """``pkg/msg/Type`` of an rclpy message object."""
    cls = type(msg)
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


@functools.cache
def _typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _as_rosbags(value: Any, store: Any) -> Any:
    """An rclpy message (or field value) as the ``rosbags`` message of the same type and values."""
    if hasattr(value, "get_fields_and_field_types"):
        cls = store.types[ros_type_name(value)]
        return cls(**{name: _as_rosbags(getattr(value, name), store) for name in value.get_fields_and_field_types()})
    if isinstance(value, array.array):  # a numeric sequence: rosbags wants a numpy array of the element type
        return np.frombuffer(value, dtype=value.typecode).copy() if len(value) else np.zeros(0, value.typecode)
    if isinstance(value, list):
        return [_as_rosbags(item, store) for item in value]
    return value


def exact_cdr(msg: Any) -> bytes:
    """The CDR bytes (little endian, with their 4-byte encapsulation header) of an rclpy message of a ROS 2 Jazzy
    type, as a strict serializer writes them: zero padding, nothing after the last field. Raises TemplateError for a
    type that Jazzy does not define."""
    store = _typestore()
    name = ros_type_name(msg)
    if name not in store.types:
        raise TemplateError(f"{name} is not a ROS 2 Jazzy message type")
    return bytes(store.serialize_cdr(_as_rosbags(msg, store), name))


class RawTemplate:
    """The serialized message of ``build(step, *arrays)`` for any step and arrays of the given ``shapes``.

    Args:
        build: the message builder (e.g. ``lambda k, r: messages.pose_array(k, dt_ns, r, frame)``); called at
            construction only.
        shapes: the shape of each array argument (a float64 array each; ``float32`` fields of the message, such as
            colours, are given as ``(shape, "float32")``).
        deserialize: ``rclpy.serialization.deserialize_message`` (the construction check reads the bytes with it).
        dt_ns: the time step [ns] (stamps are k·dt).
        serialize: the serializer whose layout the template takes (default :func:`exact_cdr`).

    Raises TemplateError when the message cannot be templated (then publish message objects instead).
    """

    def __init__(self, build: Callable[..., Any], shapes: Sequence[tuple[int, ...] | tuple[tuple[int, ...], str]],
                 deserialize: Callable[[bytes, type], Any], dt_ns: int,
                 serialize: Callable[[Any], bytes] = exact_cdr) -> None:
        self.dt_ns = dt_ns
        self.specs = [(tuple(s[0]), np.dtype(s[1])) if s and isinstance(s[0], tuple) else (tuple(s), np.dtype("f8"))
                      for s in shapes]
        sentinels = [_sentinels(shape, dtype, i) for i, (shape, dtype) in enumerate(self.specs)]
        data = serialize(build(SENTINEL_STEP, *sentinels))
        self.buffer = bytearray(data)
        stamp = self._stamp_bytes(SENTINEL_STEP)
        self.stamp_at: list[int] = []
        at = data.find(stamp)
        while at >= 0:
            self.stamp_at.append(at)
            at = data.find(stamp, at + 1)
        if not self.stamp_at:
            raise TemplateError("the message has no stamp of the step it was built for")
        self.views: list[tuple[np.ndarray, np.ndarray | slice]] = []  # (flat view of the buffer, where its values go)
        for (_, dtype), values in zip(self.specs, sentinels, strict=True):
            offsets = _find_each(data, values)
            size = dtype.itemsize
            phase = int(offsets[0] % size) if offsets.size else 0
            if offsets.size and np.any(offsets % size != phase):
                raise TemplateError("the values of a field are not equally aligned in the bytes")
            count = (len(data) - phase) // size
            view = np.frombuffer(self.buffer, dtype=dtype.newbyteorder("<"), count=count, offset=phase)
            index = (offsets - phase) // size
            if index.size and np.array_equal(index, np.arange(index[0], index[0] + index.size)):
                self.views.append((view, slice(int(index[0]), int(index[0]) + index.size)))  # one block
            else:
                self.views.append((view, index))
        self._check(build, serialize, deserialize)

    def _stamp_bytes(self, step: int) -> bytes:
        t = step * self.dt_ns
        return struct.pack("<iI", t // 1_000_000_000, t % 1_000_000_000)

    def _check(self, build: Callable[..., Any], serialize: Callable[[Any], bytes],
               deserialize: Callable[[bytes, type], Any]) -> None:
        """A render is the serialized builder's message, byte for byte, and rclpy reads it as the message the
        builder's serialization gives (float32 fields hold the serializer's rounding on both sides)."""
        rng = np.random.default_rng(7)
        arrays = [rng.standard_normal(shape).astype(dtype) for shape, dtype in self.specs]
        want = build(12_345, *arrays)
        kind, data, exact = type(want), self.render(12_345, *arrays), serialize(want)
        if data != exact:
            raise TemplateError("a check render is not the serialized message of the builder")
        if deserialize(data, kind) != deserialize(exact, kind):
            raise TemplateError("a check render does not deserialize to the builder's message")

    def render(self, step: int, *arrays: np.ndarray) -> bytes:
        """The serialized message of step ``step`` with ``arrays`` (shapes as given; converted to the field type)."""
        buf = self.buffer
        stamp = self._stamp_bytes(step)
        for at in self.stamp_at:
            buf[at:at + 8] = stamp
        for (view, index), values in zip(self.views, arrays, strict=True):
            view[index] = np.reshape(values, -1)
        return bytes(buf)
