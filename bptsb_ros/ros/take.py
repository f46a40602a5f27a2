"""Take serialized messages together with their publisher's GID (what rclpy Jazzy's take leaves out).

rclpy 7 (Jazzy) hands a raw subscription callback the CDR bytes and a message-info dict of source/received
timestamps and sequence numbers, but not ``rmw_message_info_t.publisher_gid``, the identity of the DDS writer that
sent the message. :class:`GidTaker` takes from the subscription's ``rcl_subscription_t`` itself: it calls
``rcl_take_serialized_message`` of ``librcl`` (the library rclpy already loaded) through ctypes, into one reusable
buffer per subscription, and returns the bytes with the whole message info. The struct layouts are Jazzy's
(``rmw/types.h``: ``RMW_GID_STORAGE_SIZE`` = 16; ``rcutils/types/uint8_array.h``). Where ``librcl`` cannot be
found (another ROS build), :func:`gid_take_problem` says why and callers fall back to rclpy's take (no GID).

A GID is 16 bytes; ``get_publishers_info_by_topic`` reports the same bytes as ``endpoint_gid`` of the publisher,
together with its node name and namespace.
"""

from __future__ import annotations

import ctypes
import functools
from typing import Any, NamedTuple

GID_SIZE = 16
RCL_RET_OK = 0
RCL_RET_SUBSCRIPTION_TAKE_FAILED = 401  # nothing to take
INITIAL_CAPACITY = 4096  # bytes of the reusable buffer; rmw grows it for bigger messages


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _Uint8Array(ctypes.Structure):  # rcutils_uint8_array_t = rcl_serialized_message_t
    _fields_ = [("buffer", ctypes.POINTER(ctypes.c_uint8)), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _Gid(ctypes.Structure):  # rmw_gid_t
    _fields_ = [("implementation_identifier", ctypes.c_char_p), ("data", ctypes.c_uint8 * GID_SIZE)]


class _MessageInfo(ctypes.Structure):  # rmw_message_info_t
    _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                ("publication_sequence_number", ctypes.c_uint64), ("reception_sequence_number", ctypes.c_uint64),
                ("publisher_gid", _Gid), ("from_intra_process", ctypes.c_bool)]


class TakenInfo(NamedTuple):
    """Message info of one taken message: times in ns since the epoch (0: not given), the publisher's sequence
    number (0: not given) and GID bytes (b'' when the take could not give it)."""

    source_timestamp: int
    received_timestamp: int
    publication_sequence_number: int
    publisher_gid: bytes


def _loaded_library_path(stem: str) -> str | None:
    """Path of an already loaded shared library ``<stem>.so`` (from /proc/self/maps), or None."""
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
            for line in maps:
                path = line.split(maxsplit=5)[-1].strip()
                if path.rsplit("/", 1)[-1].startswith(f"{stem}.so"):
                    return path
    except OSError:
        return None
    return None


def _library(stem: str) -> ctypes.CDLL:
    try:  # the soname of a library rclpy loaded: dlopen returns that one
        return ctypes.CDLL(f"{stem}.so")
    except OSError:
        path = _loaded_library_path(stem)
        if path is None:
            raise
        return ctypes.CDLL(path)


@functools.cache
def _libraries() -> tuple[Any, Any] | str:
    """(librcl, librcutils) with the signatures used here, or why they are unavailable."""
    import rclpy.impl.implementation_singleton  # noqa: F401 - loads librcl and librcutils into the process

    try:
        rcl, rcutils = _library("librcl"), _library("librcutils")
        take = rcl.rcl_take_serialized_message
        init, fini = rcutils.rcutils_uint8_array_init, rcutils.rcutils_uint8_array_fini
        default_allocator = rcutils.rcutils_get_default_allocator
    except (OSError, AttributeError) as exc:
        return f"librcl/librcutils not usable through ctypes ({exc})"
    take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Uint8Array), ctypes.POINTER(_MessageInfo), ctypes.c_void_p]
    take.restype = ctypes.c_int
    init.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t, ctypes.POINTER(_Allocator)]
    init.restype = ctypes.c_int
    fini.argtypes = [ctypes.POINTER(_Uint8Array)]
    fini.restype = ctypes.c_int
    default_allocator.restype = _Allocator
    return rcl, rcutils


def gid_take_problem() -> str:
    """'' when :class:`GidTaker` works here, else why not (then messages are taken without their GID)."""
    libs = _libraries()
    return libs if isinstance(libs, str) else ""


class GidTaker:
    """Takes the serialized messages of one rclpy subscription with their :class:`TakenInfo`.

    Call :meth:`take` only while holding the subscription's handle (``with sub.handle:``), from the thread that
    spins it; :meth:`close` frees the buffer.
    """

    def __init__(self, subscription: Any) -> None:
        libs = _libraries()
        if isinstance(libs, str):
            raise RuntimeError(libs)
        self._rcl, self._rcutils = libs
        self._subscription = subscription
        self._buffer = _Uint8Array()
        self._info = _MessageInfo()
        allocator = self._rcutils.rcutils_get_default_allocator()
        if self._rcutils.rcutils_uint8_array_init(ctypes.byref(self._buffer), INITIAL_CAPACITY,
                                                  ctypes.byref(allocator)) != RCL_RET_OK:
            raise MemoryError("cannot allocate the take buffer")
        self._open = True

    def take(self) -> tuple[bytes, TakenInfo] | None:
        """The next message and its info, or None when none is waiting."""
        ret = self._rcl.rcl_take_serialized_message(self._subscription.handle.pointer, ctypes.byref(self._buffer),
                                                    ctypes.byref(self._info), None)
        if ret == RCL_RET_SUBSCRIPTION_TAKE_FAILED:
            return None
        if ret != RCL_RET_OK:
            raise RuntimeError(f"rcl_take_serialized_message failed with code {ret} on "
                               f"{self._subscription.topic_name}")
        info = self._info
        data = ctypes.string_at(self._buffer.buffer, self._buffer.buffer_length)
        return data, TakenInfo(int(info.source_timestamp), int(info.received_timestamp),
                               int(info.publication_sequence_number), bytes(info.publisher_gid.data))

    def close(self) -> None:
        if self._open:
            self._open = False
            self._rcutils.rcutils_uint8_array_fini(ctypes.byref(self._buffer))


def rclpy_take(subscription: Any) -> tuple[bytes, TakenInfo] | None:
    """The fallback take through rclpy (raw subscription): the message info without the publisher GID."""
    taken = subscription.handle.take_message(subscription.msg_type, True)
    if taken is None:
        return None
    data, info = taken
    return data, TakenInfo(int(info.get("source_timestamp") or 0), int(info.get("received_timestamp") or 0),
                           int(info.get("publication_sequence_number") or 0), b"")


def batch_executor_class() -> type:
    """A ``SingleThreadedExecutor`` that serves a subscription with a ``bptsb_take_batch`` attribute (a function
    returning a list) by calling it and passing the whole list to the subscription's callback: every message
    waiting on that subscription in one executor call, instead of one per call (rclpy's executor overhead per
    call is what limited the recorder to a few hundred messages per second on a loaded machine). Other
    entities are served as usual. Overrides rclpy's ``Executor._take_subscription`` (rclpy 7, Jazzy)."""
    from rclpy.exceptions import InvalidHandle
    from rclpy.executors import SingleThreadedExecutor

    class BatchExecutor(SingleThreadedExecutor):
        def _take_subscription(self, sub: Any) -> Any:
            take_batch = getattr(sub, "bptsb_take_batch", None)
            if take_batch is None:
                return super()._take_subscription(sub)
            try:
                with sub.handle:
                    batch = take_batch()
            except InvalidHandle:  # destroyed meanwhile
                return None
            if not batch:
                return None

            async def _execute() -> None:
                sub.callback(batch)

            return _execute

    return BatchExecutor
