"""ROS-free logic of the recorder node: its parameters, which topics to record and with which QoS, what it lost,
and how far it has recorded a lockstep run.

The node (:mod:`bptsb_ros.ros.recorder`) is a thin rclpy adapter over this module and
:class:`bptsb_ros.bags.writer.BagWriter`, so everything here is testable without a ROS graph.

**Losses** (:class:`LossCount`). DDS numbers the messages of each publisher (writer) 1, 2, 3, ...; a recorded
message whose sequence number jumps past the previous one of the same publisher means the messages in between
were published and never recorded (overwritten in the publisher's or the recorder's history). The middleware also
reports messages it knows it lost (``message_lost`` events: a reliable publisher gave up on them). A topic's drop
count is the larger of the two (they see the same losses from two sides), plus the messages still arriving when
the stop timeout cut the final drain short (unknown: at least one). The totals go into the bag (``custom_data``
``dropped_messages`` and ``dropped_by_topic``, JSON) and decide the recorder's exit status.

**Acknowledgements** (:class:`StepAck`, lockstep). The recorder publishes on ``ack_topic`` the sim time t_j up to
which it has taken a message of every ``ack_topics`` topic (the loop's per-step topics, whose first field is a
header stamp or a Clock): ``body_sim`` waits for it before announcing a step too far ahead (``recorder_window``),
so no message of the run is ever overwritten before the recorder has it.
"""

from __future__ import annotations

import json
import struct
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from bptsb_ros.bags.qos import QosProfile
from bptsb_ros.bags.writer import COMPRESSIONS, DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_PERIOD_S
from bptsb_ros.interface.params import LOG_LEVEL, Param, ParameterError

#: default ``batch_wait`` [s]: at 1,000 steps/s about 200 messages (20 steps) per round instead of one wake-up each
DEFAULT_BATCH_WAIT_S = 0.02

RECORDER_PARAMS: tuple[Param, ...] = (
    Param("bag_path", "", "Output bag directory (created; must not exist or be empty). Required.", "str"),
    Param("topics", [], "Topics to record (relative names resolve in the recorder's namespace); an empty list "
          "records every topic discovered.", "str_list"),
    Param("exclude_topics", [], "Topics never recorded, also when recording all topics.", "str_list"),
    Param("include_hidden_topics", False, "When recording all topics, also record hidden ones (a name part "
          "starting with '_').", "bool"),
    Param("discovery_period", 0.1, "Seconds between two looks at the ROS graph for new topics.", "float",
          positive=True),
    Param("chunk_size", DEFAULT_CHUNK_SIZE, "MCAP chunk size in bytes (uncompressed) at which a chunk is closed.",
          "int", minimum=1024),
    Param("compression", "zstd", "MCAP chunk compression.", "str", choices=tuple(COMPRESSIONS)),
    Param("flush_period", DEFAULT_FLUSH_PERIOD_S, "Seconds after which the open chunk is closed and written "
          "even if not full: at most this much is lost if the recorder is killed outright.", "float",
          positive=True),
    Param("queue_depth", 0, "History depth of each subscription (messages); 0 keeps all, so that a burst the "
          "executor has not taken yet is never overwritten.", "int", minimum=0),
    Param("drain_quiet", 0.2, "On SIGINT/SIGTERM, keep taking in-flight messages until a wait of this many "
          "seconds brings none (bounded by stop_timeout).", "float", positive=True),
    Param("stop_timeout", 8.0, "Longest time in seconds spent taking in-flight messages after SIGINT/SIGTERM "
          "before the bag is closed (below the launcher's default --grace of 10 s).", "float", positive=True),
    Param("custom_data", [], "'key=value' strings stored in custom_data of metadata.yaml (the recorder adds "
          "log_time: sim or system, and dropped_messages / dropped_by_topic).", "str_list"),
    Param("allow_loss", False, "exit 0 even when messages were lost (counted in the bag either way); false: exit 1 "
          "when any was", "bool"),
    Param("batch_wait", DEFAULT_BATCH_WAIT_S, "Seconds between two rounds of taking messages while they arrive: each "
          "round takes everything waiting, then the recorder sleeps out the rest of this time, so that it wakes "
          "once per batch instead of once per message (0: take each message as it comes). Nothing is lost by it: "
          "the subscriptions keep every message meanwhile.", "float", minimum=0.0, maximum=0.1),
    Param("ack_topic", "", "lockstep: publish on this topic (rosgraph_msgs/Clock, reliable, transient-local, depth 1) "
          "the sim time up to which every ack_topics topic is recorded, for body_sim's wait_for_recorder; empty: "
          "no acknowledgements", "str"),
    Param("ack_topics", [], "the per-step topics whose recording ack_topic acknowledges (messages stamped by a "
          "header or a Clock; relative names resolve in the recorder's namespace)", "str_list"),
    LOG_LEVEL,
)


@dataclass(frozen=True)
class RecorderConfig:
    """Validated recorder parameters (see :data:`RECORDER_PARAMS`; times in s, sizes in bytes)."""

    bag_path: str
    topics: tuple[str, ...]
    exclude_topics: frozenset[str]
    include_hidden_topics: bool
    discovery_period: float
    chunk_size: int
    compression: str
    flush_period: float
    queue_depth: int
    drain_quiet: float
    stop_timeout: float
    custom_data: dict[str, str]
    allow_loss: bool = False
    ack_topic: str = ""
    ack_topics: tuple[str, ...] = ()
    batch_wait: float = 0.0

    @classmethod
    def from_values(cls, values: dict[str, Any], namespace: str = "/") -> RecorderConfig:
        """Build from validated parameter values (relative topic names resolve in ``namespace``, the node's);
        raise :class:`ParameterError` for a bad value."""
        bag_path = str(values["bag_path"]).strip()
        if not bag_path:
            raise ParameterError("parameter 'bag_path' is required (e.g. -p bag_path:=bags/run1)")
        if values["ack_topic"] and not values["ack_topics"]:
            raise ParameterError("parameter 'ack_topic' needs 'ack_topics': the per-step topics it acknowledges")
        return cls(
            bag_path=bag_path,
            topics=tuple(dict.fromkeys(absolute_topic(t, "topics", namespace) for t in values["topics"])),
            exclude_topics=frozenset(absolute_topic(t, "exclude_topics", namespace) for t in values["exclude_topics"]),
            include_hidden_topics=bool(values["include_hidden_topics"]),
            discovery_period=float(values["discovery_period"]),
            chunk_size=int(values["chunk_size"]),
            compression=str(values["compression"]),
            flush_period=float(values["flush_period"]),
            queue_depth=int(values["queue_depth"]),
            drain_quiet=float(values["drain_quiet"]),
            stop_timeout=float(values["stop_timeout"]),
            custom_data=parse_custom_data(values["custom_data"]),
            allow_loss=bool(values["allow_loss"]),
            ack_topic=absolute_topic(values["ack_topic"], "ack_topic", namespace) if values["ack_topic"] else "",
            ack_topics=tuple(dict.fromkeys(absolute_topic(t, "ack_topics", namespace) for t in values["ack_topics"])),
            batch_wait=float(values["batch_wait"]),
        )


def absolute_topic(name: str, param: str = "topics", namespace: str = "/") -> str:
    """``name`` as an absolute topic name (a relative name resolves in ``namespace``); raise for a bad name."""
    name = name.strip()
    if not name or name == "/" or any(c.isspace() for c in name) or "//" in name or name.endswith("/"):
        raise ParameterError(f"parameter '{param}': {name!r} is not a valid topic name")
    if name.startswith("/"):
        return name
    return namespace.rstrip("/") + "/" + name


def parse_custom_data(items: Iterable[str]) -> dict[str, str]:
    """Parse ``key=value`` strings; raise :class:`ParameterError` for an item without ``=`` or an empty key."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"parameter 'custom_data': {item!r} is not of the form key=value")
        out[key.strip()] = value
    return out


def is_hidden(topic: str) -> bool:
    """ROS hides topics with a name part that starts with an underscore."""
    return any(part.startswith("_") for part in topic.split("/"))


def select_topics(
    discovered: Iterable[tuple[str, list[str]]], config: RecorderConfig
) -> dict[str, list[str]]:
    """The discovered ``(topic, types)`` pairs that ``config`` asks to record, as ``{topic: types}``."""
    selected = {}
    for topic, types in discovered:
        if topic in config.exclude_topics or not types:
            continue
        if config.topics:
            if topic not in config.topics:
                continue
        elif is_hidden(topic) and not config.include_hidden_topics:
            continue
        selected[topic] = list(types)
    return selected


def subscription_policies(offered: list[QosProfile]) -> tuple[str, str]:
    """``(reliability, durability)`` to request so that every publisher is matched (rosbag2's rule).

    Reliable only if every publisher offers reliable, transient-local only if every one offers it.
    """
    if not offered:
        return "reliable", "volatile"
    reliability = "reliable" if all(p.reliability == "reliable" for p in offered) else "best_effort"
    durability = "transient_local" if all(p.durability == "transient_local" for p in offered) else "volatile"
    return reliability, durability


def incompatible_offers(offered: list[QosProfile], requested: tuple[str, str]) -> list[QosProfile]:
    """The offered profiles a subscription with ``requested = (reliability, durability)`` cannot match."""
    reliability, durability = requested
    return [
        p for p in offered
        if (reliability == "reliable" and p.reliability == "best_effort")
        or (durability == "transient_local" and p.durability == "volatile")
    ]


#: MCAP metadata record of the recorder's loss entries (the same as in ``custom_data``)
RECORDING_RECORD = "bptsb_ros.recording"
#: rmw's "sequence numbers unsupported" value
SEQUENCE_UNSUPPORTED = 2**64 - 1


@dataclass
class LossCount:
    """Messages a recording lost, per topic (see the module docstring). Sequence numbers are per publisher GID."""

    gaps: Counter = field(default_factory=Counter)
    lost_events: Counter = field(default_factory=Counter)
    cut_short: bool = False
    _last: dict[tuple[str, str], int] = field(default_factory=dict)

    def see(self, topic: str, publisher: str, sequence: int) -> int:
        """Count a recorded message with ``sequence`` (0 or unsupported: not numbered) from ``publisher``; return
        how many messages before it were skipped."""
        if sequence <= 0 or sequence == SEQUENCE_UNSUPPORTED:
            return 0
        key = (topic, publisher)
        last = self._last.get(key)
        self._last[key] = sequence if last is None else max(last, sequence)
        if last is None or sequence <= last + 1:
            return 0
        self.gaps[topic] += sequence - last - 1
        return sequence - last - 1

    def lost(self, topic: str, count: int) -> None:
        """``count`` more messages the middleware reports lost on ``topic``."""
        if count > 0:
            self.lost_events[topic] += count

    def by_topic(self) -> dict[str, int]:
        """Messages lost per topic: the larger of sequence gaps and middleware reports."""
        return {t: max(self.gaps[t], self.lost_events[t]) for t in sorted(set(self.gaps) | set(self.lost_events))
                if max(self.gaps[t], self.lost_events[t]) > 0}

    @property
    def total(self) -> int:
        return sum(self.by_topic().values())

    @property
    def any(self) -> bool:
        """Whether anything was lost (a drain cut short counts, the number being unknown)."""
        return self.total > 0 or self.cut_short

    def custom_data(self) -> dict[str, str]:
        """The ``custom_data`` entries of the bag: ``dropped_messages`` (total), ``dropped_by_topic`` (JSON) and
        ``recording_complete`` (``false`` when the final drain was cut short)."""
        return {"dropped_messages": str(self.total), "dropped_by_topic": json.dumps(self.by_topic()),
                "recording_complete": "false" if self.cut_short else "true"}


def recorded_loss(custom_data: dict[str, str]) -> tuple[int | None, dict[str, int], bool]:
    """(total, per topic, complete) from a bag's ``custom_data`` (total None: the recorder did not count)."""
    if "dropped_messages" not in custom_data:
        return None, {}, True
    try:
        total = int(custom_data["dropped_messages"])
        raw = json.loads(custom_data.get("dropped_by_topic") or "{}")
        per_topic = {str(k)[:256]: int(v) for k, v in raw.items()} if isinstance(raw, dict) else {}
    except (ValueError, TypeError):
        return None, {}, True
    return total, per_topic, custom_data.get("recording_complete", "true") != "false"


#: types whose serialized form starts with a stamp: a Clock, or a std_msgs/Header as first field
STAMPED_TYPES = frozenset({
    "rosgraph_msgs/msg/Clock", "geometry_msgs/msg/PoseArray", "sensor_msgs/msg/JointState",
    "geometry_msgs/msg/Vector3Stamped", "geometry_msgs/msg/PointStamped", "geometry_msgs/msg/PoseStamped",
    "diagnostic_msgs/msg/DiagnosticArray", "sensor_msgs/msg/Image", "std_msgs/msg/Header",
})


def cdr_stamp_ns(data: bytes) -> int:
    """The stamp [ns] at the start of a CDR message of a :data:`STAMPED_TYPES` type: after the 4-byte encapsulation
    header (byte 1: 1 little-endian, 0 big-endian) an int32 sec and a uint32 nanosec. Raises ValueError for a
    message too short to hold one."""
    if len(data) < 12:
        raise ValueError(f"a {len(data)}-byte message holds no stamp")
    sec, nanosec = struct.unpack_from("<iI" if data[1] & 1 else ">iI", data, 4)
    return sec * 1_000_000_000 + nanosec


class StepAck:
    """How far a lockstep run is recorded: the smallest, over ``topics``, of the newest stamp taken on it [ns]
    (None until every topic has a message). Topics of other types than :data:`STAMPED_TYPES` cannot be
    acknowledged (``refuse`` them)."""

    def __init__(self, topics: Iterable[str]) -> None:
        self.newest: dict[str, int | None] = dict.fromkeys(topics)
        self.published: int | None = None

    def refuse(self, topic: str) -> None:
        """Leave ``topic`` out (its type carries no stamp)."""
        self.newest.pop(topic, None)

    def see(self, topic: str, data: bytes) -> None:
        if topic in self.newest:
            stamp = cdr_stamp_ns(data)
            old = self.newest[topic]
            self.newest[topic] = stamp if old is None else max(old, stamp)

    def value(self) -> int | None:
        if not self.newest or any(v is None for v in self.newest.values()):
            return None
        return min(v for v in self.newest.values() if v is not None)

    def due(self) -> int | None:
        """The acknowledgement to publish now (it advanced since the last one), or None; marks it published."""
        value = self.value()
        if value is None or (self.published is not None and value <= self.published):
            return None
        self.published = value
        return value


def take_round(spin_once: Callable[[float], None], taken: Callable[[], int], clock: Callable[[], float],
               sleep: Callable[[float], None], batch_wait: float, timeout: float = 0.05,
               take_ready: Callable[[], object] | None = None) -> int:
    """One round of the recorder's loop: wait up to ``timeout`` [s] for a message (``spin_once``), then take every
    message waiting on the recorded topics at once (``take_ready``, when given: without an executor call per
    topic), then handle whatever else is ready until a call handles no message (``taken``: messages handled so
    far), then sleep until ``batch_wait`` [s] after the round began (no sleep when the round took longer, or
    ``batch_wait`` is 0, or the wait timed out with nothing taken). A wait ended early by something else (a timer,
    the ``/clock`` of sim time) counts as activity too: the round goes on, so that it cannot end a round per step.
    Returns the messages the round handled."""
    first = taken()
    began = clock()
    spin_once(timeout)
    if taken() == first and clock() - began >= timeout:
        return 0
    if take_ready is not None:
        take_ready()
    before = -1
    while taken() != before:
        before = taken()
        spin_once(0.0)
    rest = began + batch_wait - clock()
    if rest > 0:
        sleep(rest)
    return taken() - first
