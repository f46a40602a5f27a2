"""Per-step messages of a fixed layout, serialized by writing into a template (no message objects in the step).

A body's per-step messages keep their layout from step to step: the same names, frame, array lengths and marker
colours of the fixed masses; only the stamps and some float arrays change. Building them as rclpy message objects
costs a Python object per pose, point and colour and their conversion in ``publish`` (a PoseArray of 25 masses about
0.3 ms, the body's MarkerArray about 1.1 ms on a 2-core machine). A :class:`CdrTemplate` serializes the message
once, with planted values, and finds where the stamps and the arrays lie in its CDR bytes; each step copies the
bytes and writes the new values there with numpy. ``Publisher.publish`` takes the bytes as a serialized message.

The result decodes to the same message as rclpy's own serialization of the message objects
(``tests/test_cdr_template.py`` compares them; CDR's alignment padding is left as rmw left it in the template). A
template that cannot be laid out (not little-endian CDR, a planted value found more or fewer times than expected)
raises :class:`TemplateError`; ``body_sim`` then builds message objects as before.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np
from rclpy.serialization import serialize_message

#: planted stamp (sec, nanosec): distinct from any stamp of a run that is shorter than 6 years
PLANTED_STAMP = (0x0BADCAFE, 0x1BADF00D)
_STAMP = struct.Struct("<iI")
#: CDR encapsulation of a little-endian payload (the 4-byte header rmw writes first)
CDR_LE = b"\x00\x01"


class TemplateError(ValueError):
    """A message whose layout a template cannot capture; the message says why."""


def planted(shape: tuple[int, ...], seed: int, dtype: type = np.float64) -> np.ndarray:
    """Distinct values in (1, 2) of ``dtype`` to plant in a template (``dtype`` float32: exactly representable)."""
    return (1.0 + np.random.default_rng(seed).random(shape)).astype(dtype)


class CdrTemplate:
    """The serialized bytes of ``msg`` (stamped :data:`PLANTED_STAMP` in ``stamps`` headers), and where each block
    of ``blocks`` (name → the planted array, little-endian float64 or float32, exactly as it lies in the message:
    C order, contiguous) lies in them."""

    def __init__(self, msg: Any, blocks: Mapping[str, np.ndarray], stamps: int = 1) -> None:
        data = serialize_message(msg)
        if data[:2] != CDR_LE:
            raise TemplateError(f"{type(msg).__name__}: serialized as {data[:2].hex()}, not little-endian CDR")
        self.data = data
        self.stamps = self._find(_STAMP.pack(*PLANTED_STAMP), "the planted stamp", stamps)
        self.blocks: dict[str, tuple[int, np.dtype, tuple[int, ...]]] = {}
        for name, values in blocks.items():
            values = np.ascontiguousarray(values)
            little = values.astype(values.dtype.newbyteorder("<"))
            (offset,) = self._find(little.tobytes(), f"block {name}", 1)
            self.blocks[name] = (offset, little.dtype, values.shape)

    def _find(self, pattern: bytes, what: str, count: int) -> list[int]:
        found, at = [], self.data.find(pattern)
        while at >= 0:
            found.append(at)
            at = self.data.find(pattern, at + len(pattern))
        if len(found) != count:
            raise TemplateError(f"{what} occurs {len(found)} times in the serialized message, expected {count}")
        return found

    def render(self, sec: int, nanosec: int, **values: np.ndarray) -> bytes:
        """The serialized message stamped (``sec``, ``nanosec``) with ``values`` (name → array of the block's
        shape) written over the planted blocks; a block not given keeps its planted values."""
        buf = bytearray(self.data)
        for offset in self.stamps:
            _STAMP.pack_into(buf, offset, sec, nanosec)
        for name, value in values.items():
            offset, dtype, shape = self.blocks[name]
            view = np.frombuffer(buf, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
            view[...] = value
        return bytes(buf)
